"""Large queries: points evaluated partition by partition, by an executor's workers, into an HDF5 file.

The points come in partitions of :data:`PARTITION` points (arrays of shape (P, d), codebook
coordinate order), whatever evaluates them: each partition is one task of the executor
(:mod:`pgdcli.executors`; on a Dask cluster the codebook is sent to each worker once), and its values
are those of :meth:`pgdcli.Codebook.evaluate` on the partition's arrays, so a cluster writes the
same file, bit for bit, as this process. (``pgd query`` on stdout evaluates each point alone; the
values of a partition agree with it to rounding.)

The file (:func:`write_points`) holds ``coordinates/<name>`` and ``values/<unknown>``, one row per
point in the order given, and is written atomically: a temporary file beside the target, renamed
when every partition is in.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np

from .. import executors

__all__ = ["PARTITION", "PartitionValues", "evaluate_partitions", "write_points", "partitioned"]

#: Points per partition: a task of a few tenths of a second on a 10-coordinate tensor train.
PARTITION = 65536


class PartitionValues:
    """``values(points)``: the selected unknowns at points (P, d), shape (P, unknowns); sent to an
    executor's workers once."""

    def __init__(self, codebook, fields: Sequence[str]):
        self.codebook, self.fields = codebook, list(fields)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        values = self.codebook.evaluate(dict(zip(self.codebook.coordinate_names, points.T)), self.fields)
        return np.stack([values[u] for u in self.fields], axis=1)


def partitioned(chunks: Iterable[np.ndarray], size: int = PARTITION) -> Iterator[np.ndarray]:
    """Chunks of points (any number of rows each, shape (rows, d)) regrouped into partitions of ``size``
    rows (the last one shorter): the partitions do not depend on how the points were read."""
    held: list[np.ndarray] = []
    count = 0
    for chunk in chunks:
        chunk = np.asarray(chunk, dtype=float)
        while len(chunk):
            take = min(size - count, len(chunk))
            held.append(chunk[:take])
            count += take
            chunk = chunk[take:]
            if count == size:
                yield np.concatenate(held)
                held, count = [], 0
    if count:
        yield np.concatenate(held)


def evaluate_partitions(codebook, partitions: Iterable[np.ndarray], fields: Sequence[str] | None = None,
                        executor=None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """``(points, values)`` of every partition, in order, evaluated by ``executor`` (default: the one in effect)."""
    runner = executors.current() if executor is None else executors.as_executor(executor)
    fields = codebook.unknown_names if fields is None else list(fields)
    held: list = []

    def kept(items):  # the points of the partitions handed out, for the caller
        for item in items:
            held.append(item)
            yield item

    for values in runner.map(PartitionValues(codebook, fields), kept(partitions)):
        yield held.pop(0), values


def write_points(path: str | os.PathLike, codebook, partitions: Iterable[np.ndarray],
                 fields: Sequence[str] | None = None, executor=None, progress=None) -> int:
    """Evaluate the partitions and write the points and values to the HDF5 file ``path``, atomically.

    Parameters
    ----------
    path : path-like
    codebook : pgdcli.Codebook
    partitions : iterable of ndarray (P, d)
        Points in codebook coordinate order (:func:`partitioned`).
    fields : sequence of str, optional
        Unknowns (default all).
    executor : optional
        Where the partitions are evaluated (:func:`pgdcli.executors.as_executor`).
    progress : callable, optional
        Told the number of points written so far.

    Returns
    -------
    int
        Points written.
    """
    import tempfile

    import h5py

    path = Path(path)
    fields = codebook.unknown_names if fields is None else list(fields)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    written = 0
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs["codebook"] = codebook.name
            columns = {}
            for group, names in (("coordinates", codebook.coordinate_names), ("values", fields)):
                for name in names:
                    columns[group, name] = f.create_dataset(f"{group}/{name}", shape=(0,), maxshape=(None,),
                                                            dtype="f8", chunks=(min(PARTITION, 65536),))
            for points, values in evaluate_partitions(codebook, partitions, fields, executor):
                rows = slice(written, written + len(points))
                written += len(points)
                for k, name in enumerate(codebook.coordinate_names):
                    _append(columns["coordinates", name], rows, points[:, k])
                for k, name in enumerate(fields):
                    _append(columns["values", name], rows, values[:, k])
                if progress is not None:
                    progress(written)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return written


def _append(dataset, rows: slice, column: np.ndarray) -> None:
    dataset.resize((rows.stop,))
    dataset[rows] = column
