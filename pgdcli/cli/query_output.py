"""``pgd query ... --output FILE.h5``: many points evaluated in partitions (on a cluster with
``--scheduler``/``--workers``) and written to an HDF5 file (:mod:`pgdcli.codebook.partitions`).

The points come from ``--points`` (a CSV file as for stdout, or an HDF5 file with one 1-D dataset per
coordinate, at its root or in a group ``coordinates``) or from the ``--NAME VALUE`` grid. Every point
is checked as for stdout (finite, inside its coordinate's domain), each error naming the file, the
coordinate and the row.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..codebook.partitions import partitioned, write_points
from ..errors import QueryError
from . import query

__all__ = ["H5_SUFFIXES", "point_partitions", "write_query"]

H5_SUFFIXES = (".h5", ".hdf5")
#: Rows of an HDF5 points file read at a time.
READ_ROWS = 1 << 20


def point_partitions(cb, points: str | None, rest: list[str]):
    """Chunks of points, arrays (rows, d) in codebook order, and a handle to close (or None)."""
    if points is not None and points != "-" and Path(points).suffix.lower() in H5_SUFFIXES:
        return _h5_points(cb, points), None
    chunks, handle = query.point_chunks(cb, points, rest)
    return (np.array(chunk, dtype=float).reshape(-1, len(cb.coordinates)) for chunk in chunks), handle


def _h5_points(cb, path: str):
    """The points of an HDF5 file, :data:`READ_ROWS` rows at a time, checked."""
    import h5py

    try:
        f = h5py.File(path, "r")
    except FileNotFoundError:
        raise QueryError(f"--points {path}: no such file") from None
    except OSError as exc:
        raise QueryError(f"--points {path}: not a readable HDF5 file ({' '.join(str(exc).split())})") from None
    with f:
        group = f["coordinates"] if isinstance(f.get("coordinates"), h5py.Group) else f
        columns = []
        for c in cb.coordinates:
            data = group.get(c.name)
            if not isinstance(data, h5py.Dataset) or data.ndim != 1 or data.dtype.kind not in "fiu":
                raise QueryError(f"--points {path}: expected a 1-D numeric dataset {c.name!r} (at the root or in "
                                 f"'coordinates') for every coordinate: {', '.join(cb.coordinate_names)}")
            columns.append(data)
        lengths = {len(d) for d in columns}
        if len(lengths) > 1:
            raise QueryError(f"--points {path}: the coordinates' datasets differ in length: {sorted(lengths)}")
        total = lengths.pop() if lengths else 0
        for start in range(0, total, READ_ROWS):
            block = np.stack([np.asarray(d[start:start + READ_ROWS], dtype=float) for d in columns], axis=1)
            _check_block(cb, block, path, start)
            yield block


def _check_block(cb, block: np.ndarray, source: str, start: int) -> None:
    for k, c in enumerate(cb.coordinates):
        column = block[:, k]
        bad = ~np.isfinite(column) | (column < c.domain[0]) | (column > c.domain[1])
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            what = ("is not a finite number" if not np.isfinite(column[row]) else
                    f"is outside the domain [{c.domain[0]:g}, {c.domain[1]:g}]")
            raise QueryError(f"--points {source}: row {start + row + 1}: coordinate {c.name!r}: {column[row]!r} {what}")


def write_query(cb, chunks, output: Path, selected: list[str], executor, console) -> int:
    """Evaluate the points in partitions and write them to ``output``; the count on stderr."""
    if console is None:
        return write_points(output, cb, partitioned(chunks), selected, executor)
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(SpinnerColumn(), TextColumn("[bold]{task.description}"), TextColumn("{task.fields[status]}"),
                  TimeElapsedColumn(), console=console, transient=True) as progress:
        task = progress.add_task(f"evaluating {cb.name}", status="")
        written = write_points(output, cb, partitioned(chunks), selected, executor,
                               lambda n: progress.update(task, status=f"{n:,} points"))
    console.print(f"wrote {written:,} points to {output}")
    return written
