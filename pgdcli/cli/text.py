"""Small text formatters shared by the commands' tables (``pgd solve``, ``pgd info``)."""

from __future__ import annotations

__all__ = ["nodes_chosen_text", "short_where", "human_size"]


def nodes_chosen_text(chosen: dict) -> str:
    """``"t: 33 -> 33; p: 9 -> 17"``: the nodes of each automatic coordinate, solve by solve."""
    return "; ".join(f"{c}: " + " -> ".join(str(r["nodes"][c]) for r in chosen["rounds"]) for c in chosen["automatic"])


def short_where(where: str) -> str:
    """``"t=0.34776852054, a=0"`` with 6 significant digits (the report keeps them all)."""
    try:
        return ", ".join(f"{k}={float(v):.6g}" for k, v in (kv.split("=") for kv in where.split(", ")))
    except ValueError:
        return where


def human_size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n} B"
