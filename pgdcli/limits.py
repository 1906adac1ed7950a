"""The documented limits on what pgdcli reads and computes, each with its environment override.

A limit bounds the work or memory that an input can ask for before that work starts: a crafted
codebook that declares a huge array, a spec that asks for a billion time slabs. Each is read
from its environment variable when it is used (so a test or a wrapper script can set it), and a
malformed override is one error naming the variable. Standard library only (the query path).

=============================  ===============================  ==========================================
variable                       default                          bounds
=============================  ===============================  ==========================================
``PGD_MAX_CODEBOOK_BYTES``     2 GiB                            a codebook file, and the arrays it declares
``PGD_MAX_WORK_BYTES``         half the machine's memory        one array a solve or check allocates
``PGD_MAX_TIME_NODES``         100000                           time nodes of a codebook (slabs x nodes)
``PGD_MAX_PERIODS``            10000                            periods of the fastest oscillation over t
``PGD_MAX_STATE_SIZE``         8192                             unknowns x time nodes of the enrichment
``PGD_QUERY_MAX_POINTS``       10000000                         points of a query, rows of fit data
=============================  ===============================  ==========================================
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from .errors import PgdError

__all__ = ["Limit", "LIMITS", "limit", "MAX_COORDINATES", "MAX_UNKNOWNS", "DEFAULT_CHECK_SECONDS", "MAX_LINE_BYTES",
           "physical_memory"]

#: Coordinates of a problem at most: the exported evaluators report a clamped coordinate by one
#: bit of a C ``int`` (and the cross march's cost grows with every coordinate).
MAX_COORDINATES = 30
#: Unknowns of a problem at most (after second-order equations are written as first-order ones).
MAX_UNKNOWNS = 256
#: Longest line of a points file or of fit data (bytes).
MAX_LINE_BYTES = 65536
#: Seconds the reference integrations of ``pgd verify`` and ``pgd plot`` may take (``--max-seconds``).
DEFAULT_CHECK_SECONDS = 300.0


def physical_memory() -> int:
    """Bytes of physical memory (8 GiB where the platform does not say)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 8 * 2**30


@dataclass(frozen=True)
class Limit:
    """One documented limit: its environment variable, default and what it bounds."""

    variable: str
    default: object  # int, or a callable giving the default
    what: str

    def value(self) -> int:
        text = os.environ.get(self.variable, "").strip()
        if not text:
            return int(self.default() if callable(self.default) else self.default)
        try:
            number = float(text)
        except ValueError:
            number = float("nan")
        if not (number >= 1 and number < 2**62):
            raise PgdError(f"environment variable {self.variable}: expected a positive number "
                           f"({self.what}), got {text[:40]!r}")
        return int(number)


LIMITS = {
    "codebook_bytes": Limit("PGD_MAX_CODEBOOK_BYTES", 2 * 2**30, "bytes of a codebook file and its arrays"),
    "work_bytes": Limit("PGD_MAX_WORK_BYTES", lambda: physical_memory() // 2,
                        "bytes of one array a solve or a check allocates"),
    "time_nodes": Limit("PGD_MAX_TIME_NODES", 100_000, "time nodes of a codebook"),
    "periods": Limit("PGD_MAX_PERIODS", 10_000, "periods of the fastest oscillation over the time domain"),
    "query_points": Limit("PGD_QUERY_MAX_POINTS", 10_000_000, "points of a query, rows of fit data"),
    "state_size": Limit("PGD_MAX_STATE_SIZE", 8192, "unknowns x time nodes of the enrichment's dense state"),
}


def limit(name: str) -> int:
    """The current value of limit ``name`` (a key of :data:`LIMITS`), its override applied."""
    return LIMITS[name].value()
