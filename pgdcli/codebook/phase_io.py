"""The phases of a codebook in its file (format 1.3): ``/phases`` (docs/codebook-format.md).

A codebook whose event acts (:class:`~pgdcli.codebook.phases.PhasedCodebook`) keeps phase 0 where
every codebook keeps its fields, and each later phase ``k`` as a whole codebook file of its own,
its bytes the dataset ``/phases/<k>`` (checksummed and digested as every array of the file). Reading
a phase reads that file with every check a codebook file gets, named ``phase k``. The group's
attributes name the acting event and its action. The unknowns of phase 0 are marked ``phased:`` in
their representation, so that a pgdcli without phases refuses the file instead of evaluating phase
0 beyond its event. numpy and h5py only (the query path).
"""

from __future__ import annotations

import io

import numpy as np

from ..errors import CodebookError

__all__ = ["write_phases", "read_phases", "PHASED", "ACTIONS", "MAX_PHASES"]

ACTIONS = ("reset", "terminal")
#: Most phases a codebook stores (events that pile up faster, a Zeno motion, are refused).
MAX_PHASES = 24

#: The prefix of phase 0's representations in a file with phases.
PHASED = "phased:"


def write_phases(f, cb, to_bytes, array) -> None:
    """Write ``cb``'s phases (nothing for a codebook without them); ``array(group, name, values)``."""
    phases = getattr(cb, "phases", None)
    if phases is None:
        return
    g = f.create_group("phases")
    g.attrs["acting"] = cb.acting
    g.attrs["action"] = cb.action
    g.attrs["count"] = len(phases)
    for k, phase in enumerate(phases, start=1):
        array(g, str(k), np.frombuffer(to_bytes(phase), dtype=np.uint8))


def _text(value) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return value if isinstance(value, str) else ""


def read_phases(found, read_bytes, read_nested) -> dict:
    """``{acting, action, phases}`` of a surveyed file with ``/phases`` (``{}`` without).

    ``read_bytes(where, size)`` reads a dataset of bytes (its digest checked); ``read_nested(file, name)``
    reads the constructor arguments of the codebook in an open HDF5 file.
    """
    p = found.source
    if "phases" not in found.attrs:
        return {}
    acting, action = _text(found.attr("phases", "acting", "")), _text(found.attr("phases", "action", ""))
    if action not in ACTIONS or not acting:
        raise CodebookError(f"{p}: corrupt codebook: phases: no acting event, or action {action!r} is not one of "
                            f"{', '.join(ACTIONS)}")
    try:
        count = int(np.asarray(found.attr("phases", "count", -1)).reshape(-1)[0])
    except (TypeError, ValueError, OverflowError, IndexError):
        count = -1
    if not 0 <= count < MAX_PHASES or (action == "terminal" and count):
        raise CodebookError(f"{p}: corrupt codebook: phases: count {count} (at most {MAX_PHASES - 1}, none after a "
                            f"terminal event)")
    stray = [w for w in found.datasets if w.startswith("phases/") and w not in {f"phases/{k}" for k in
                                                                                 range(1, count + 1)}]
    if stray:
        raise CodebookError(f"{p}: corrupt codebook: phases: unexpected {stray[0]!r}")
    phases = []
    for k in range(1, count + 1):
        where = f"phases/{k}"
        shape = found.datasets.get(where, ((),))[0]
        if len(shape) != 1:
            raise CodebookError(f"{p}: corrupt codebook: phase {k} is missing or not a byte string")
        data = read_bytes(where, shape)
        phases.append(_nested(data, f"{p}: phase {k}", read_nested))
    return {"acting": acting, "action": action, "phases": phases}


def _nested(data: np.ndarray, name: str, read_nested) -> dict:
    import h5py

    if data.dtype != np.uint8:
        raise CodebookError(f"{name}: corrupt codebook: not a byte string")
    try:
        with h5py.File(io.BytesIO(data.tobytes()), "r") as f:
            parts = read_nested(f, name)
    except CodebookError:
        raise
    except (OSError, ValueError, KeyError, TypeError, RuntimeError) as exc:
        raise CodebookError(f"{name}: corrupt codebook ({' '.join(str(exc).split())})") from None
    if "phases" in parts:
        raise CodebookError(f"{name}: corrupt codebook: a phase has phases of its own")
    return parts
