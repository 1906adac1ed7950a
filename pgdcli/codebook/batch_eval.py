"""Batches of points through tensor-train codebooks: one matrix product per core for all points.

A tensor train ``u(x) = G_1[x_1] G_2[x_2] ... G_d[x_d]`` at ``P`` points is contracted
core by core, each core (shape ``(r0, n, r1)``) one of two ways, both ``n r0 r1``
multiply-adds per point in BLAS-sized products, whichever keeps the smaller intermediate:

- rows first (``r0 < n``): the cardinal rows ``W`` of the points (shape ``(P, n)``) times
  the core unfolded as ``(n, r0 r1)`` -- one product for the block of points and every
  unknown at once (their unfolded cores side by side) -- then each point's running row
  vector ``v`` (shape ``(r0,)``) times its own ``(r0, r1)`` slice (a batched product);
- running vector first (``r0 >= n``, the wide middle cores of a 7-D train): the running
  vectors ``V`` (shape ``(P, r0)``) times the core unfolded as ``(r0, n r1)``, then each
  point's cardinal row (shape ``(n,)``) times its ``(n, r1)`` block.

Every intermediate is written into a scratch buffer that lives as long as the batch (one
set per thread): a fresh array per block and core, freed right after, could make glibc hand
the memory back to the system and fault it in again at every block, which slows a whole batch
down in the processes where it happens. The cardinal rows are stored points last (``(n, P)``,
handed on as transposed views) wherever BLAS takes them as a matrix: elementwise work then runs
along the points, not along the few nodes of a window; the rows a batched product takes point
by point stay points first.

The first core of the train (the time coordinate of the march's codebooks) is split
into windows: the slabs of a piecewise Chebyshev coordinate, the elements of a linear
one. A point's cardinal row vanishes outside its window, so the points are grouped by
window (a stable sort) and each group uses only its window's nodes. When the window is
narrower than the first bond, the first two cores are merged per window beforehand
into a table of ``(w n_2, r_2)``: per point ``w n_2 r_2`` multiply-adds instead of
``w r_1 + r_1 n_2 r_2`` and one product less. A later coordinate of several windows (a
parameter given slabs by the automatic discretization, or linear elements) is grouped by too
when the multiply-adds saved outweigh the blocks added (a cost model): its core then costs a
point ``r0 w r1``, not ``r0 n r1``, which pays most for coordinates of many linear elements.

The values equal those of the core-by-core row-wise contraction
(:func:`pgdcli.codebook.evaluate.contract_tt`) to rounding: the same sums in another order.
Measurements: ``benchmarks/query_speed_tt.py`` (batch rows).
"""

from __future__ import annotations

import math
from typing import Callable, Mapping, Sequence

import numpy as np

from ..discretization.basis import barycentric_columns
from ..tuning import BLOCK_BYTES, MAX_BLOCK, MAX_PAIR_VALUES, MIN_BLOCK, SECONDS_PER_BLOCK, SECONDS_PER_MADD

__all__ = ["TTBatch"]

# Slabs up to this many interior breakpoints are found by counting (see _window_of).
COUNT_BREAKPOINTS = 32


def _windows(basis) -> tuple[np.ndarray, int]:
    """First node of each window of ``basis`` and the window width (one window: the whole basis)."""
    n = basis.nodes.size
    slab = int(getattr(basis, "slab_size", 0) or 0)
    if slab:
        return np.arange(0, n - 1, slab - 1), slab
    if basis.kind == "linear":
        return np.arange(n - 1), 2
    return np.zeros(1, dtype=int), n


def _window_of(basis, x: np.ndarray) -> np.ndarray:
    """Window index of each point: the slab or element whose nodes carry its cardinal row.

    The rules of the bases' own interpolation rows (a breakpoint belongs to the slab on its
    right, the upper end to the last slab or element).
    """
    if int(getattr(basis, "slab_size", 0) or 0):
        interior = basis.breakpoints[1:-1]
        if len(interior) > COUNT_BREAKPOINTS:
            return basis.slab_of(x)
        # the interior breakpoints at or below x, counted: x is in the domain, so this is the
        # clipped search, without searchsorted's unpredictable branches (far faster for a few slabs)
        window, above = np.zeros(x.shape, np.uint8), np.empty(x.shape, bool)
        for b in interior:
            np.add(window, np.greater_equal(x, b, out=above), out=window)
        return window
    if basis.kind == "linear":
        n = basis.nodes.size
        return np.clip(np.searchsorted(basis.nodes, x, side="right") - 1, 0, n - 2)
    return np.zeros(x.size, dtype=int)


def _rows_points_last(basis, x: np.ndarray, lo: int, width: int, out: np.ndarray, work: np.ndarray) -> np.ndarray:
    """Cardinal rows of ``x`` (shape (P,), all in the window starting at node ``lo``) on that
    window's nodes only, points last: shape (width, P), written into ``out`` (``work``: scratch
    of the same shape; either may be the transposed view of a points-first buffer). The
    arithmetic of the basis's own interpolation rows (a point on a node gets the unit row); the
    layout lets the first two cores' Khatri-Rao product broadcast along the points (about twice
    as fast as along the values).
    """
    nodes = basis.nodes[lo:lo + width]
    if basis.kind == "linear" and width == 2:
        theta = np.divide(np.subtract(x, nodes[0], out=out[1]), nodes[1] - nodes[0], out=out[1])
        np.subtract(1.0, theta, out=out[0])
        return out
    if getattr(basis, "bary", np.empty(0)).size != width:  # a whole linear or piecewise basis
        basis.interpolation_rows(x, out.T, work.T)
        return out
    return barycentric_columns(x, nodes, basis.bary, out, work)


class _Train:
    """Unknowns that share a core order: their cores unfolded and stacked for block products."""

    def __init__(self, names: list[str], fields: Mapping, bases: Sequence):
        self.names = names
        first = fields[names[0]]
        self.order = tuple(first.mode_order)
        cores = [[np.asarray(fields[u].cores[k], dtype=float) for u in names] for k in range(len(self.order))]
        self.starts, self.width = _windows(bases[self.order[0]])
        # first core: (n, sum_u r1_u), rows = nodes
        self.first = np.hstack([c[0] for c in cores[0]])
        self.first_ranks = [c.shape[2] for c in cores[0]]
        r1 = max(self.first_ranks)
        self.pair = None
        if len(cores) > 1 and self.width < r1:
            n2 = cores[1][0].shape[1]
            total = sum(c.shape[2] for c in cores[1])
            if self.starts.size * self.width * n2 * total <= MAX_PAIR_VALUES:
                self.pair = [self._pair_table(cores[0], cores[1], lo) for lo in self.starts]
                self.pair_ranks = [c.shape[2] for c in cores[1]]
        rest = cores[2:] if self.pair is not None else cores[1:]
        # later cores, each contracted one of two ways (see contract), both n r0 r1 multiply-adds per
        # point, whichever has the smaller intermediate per point: 'rows first' (r0 < n) for all the
        # unknowns at once, as (n, sum_u r0_u r1_u) with each unknown's block its core transposed to
        # (n, r0, r1); or 'running vector first' (r0 >= n) per unknown, as (r0, n r1), then each
        # point's cardinal row (n,) times its (n, r1) block. On a wide middle core (r0 >> n) the
        # running vector first is several times faster than rows first, and faster than the
        # row-wise Khatri-Rao product of v and the rows times the core as (r0 n, r1), a third of
        # whose time goes to forming the Khatri-Rao block (benchmarks/query_speed_tt.py's batch rows)
        self.rest = []
        widest = [self.first.shape[1]] + ([self.pair[0].shape[0]] if self.pair is not None else [])
        for k, group in enumerate(rest, start=len(cores) - len(rest)):
            n = group[0].shape[1]
            if max(c.shape[0] for c in group) >= n:
                unfolded = [np.ascontiguousarray(c.reshape(c.shape[0], -1)) for c in group]
                self.rest.append((self.order[k], False, unfolded, [(n, c.shape[2]) for c in group], None))
                widest.append(max(g.shape[1] for g in unfolded))
                continue
            table = np.hstack([c.transpose(1, 0, 2).reshape(n, -1) for c in group])
            shapes = [(c.shape[0], c.shape[2]) for c in group]
            offsets = np.cumsum([0] + [a * b for a, b in shapes])
            self.rest.append((self.order[k], True, np.ascontiguousarray(table), shapes, offsets))
            widest.append(table.shape[1])
        self.block = int(min(MAX_BLOCK, max(MIN_BLOCK, BLOCK_BYTES // (8 * max(widest)))))
        # later coordinates of several windows (slabs, linear elements; the pair's second one too): a
        # block of points within one window of such a coordinate takes only that window's part of
        # its core or of the pair table (TTBatch.evaluate)
        # and the multiply-adds a point costs in each of those cores (or the pair table), all unknowns
        later = {j: sum(g.size for g in table) if not rows_first else table.size
                 for j, rows_first, table, *_ in self.rest}
        if self.pair is not None:
            later[self.order[1]] = self.pair[0].size
        windows = {j: _windows(bases[j]) for j in later}
        self.later_windows = {j: w for j, w in windows.items() if w[0].size > 1}
        self.later_madds = {j: later[j] for j in self.later_windows}
        # coordinates whose rows come points last (see rows): all but those of vector-first cores
        self.points_last = {self.order[0]} | ({self.order[1]} if self.pair is not None else set()) | {
            j for j, rows_first, *_ in self.rest if rows_first}

    def _pair_table(self, first: list[np.ndarray], second: list[np.ndarray], lo: int) -> np.ndarray:
        """(n2 w, sum_u r2_u): ``G1[0, lo + a, :] G2[:, b, :]`` for every unknown, rows ``b w + a``
        (the second coordinate's node major: a window of its nodes is a run of rows)."""
        w = self.width
        parts = [np.einsum("ar,rbs->bas", g1[0, lo:lo + w], g2).reshape(g2.shape[1] * w, g2.shape[2])
                 for g1, g2 in zip(first, second)]
        return np.ascontiguousarray(np.hstack(parts))

    def rows(self, bases: Sequence, flat: Sequence[np.ndarray], idx: np.ndarray, windows: dict,
             scratch: "_Scratch") -> list[np.ndarray]:
        """Cardinal rows of the points ``flat[j][idx]`` (a block), as :meth:`contract` takes them.

        ``windows`` maps the first coordinate, and the later ones the block is grouped by, to the
        window all its points lie in.

        Returns
        -------
        list of ndarray
            Per coordinate, shape (P, n_j); for a coordinate in ``windows`` only its window's
            columns, shape (P, w_j). Points last in memory (transposed views) except for the
            coordinates whose core takes each point's row in a batched product (vector first).
        """
        rows = []
        for j, (basis, x) in enumerate(zip(bases, flat)):
            x = np.take(x, idx, out=scratch.get(("x", j), idx.shape))
            lo, width = self._window(j, windows) if j in windows else (0, basis.size)
            if j in self.points_last:
                shape = (width, idx.size)
                rows.append(_rows_points_last(basis, x, lo, width, scratch.get(("rows", j), shape),
                                              scratch.get("rows work", shape)).T)
            else:  # points first: the same arithmetic on transposed views
                out, work = scratch.get(("rows", j), (idx.size, width)), scratch.get("rows work", (idx.size, width))
                _rows_points_last(basis, x, lo, width, out.T, work.T)
                rows.append(out)
        return rows

    def _window(self, j: int, windows: dict) -> tuple[int, int]:
        """First node and width of coordinate ``j``'s window ``windows[j]``."""
        starts, width = (self.starts, self.width) if j == self.order[0] else self.later_windows[j]
        return int(starts[windows[j]]), width

    def contract(self, rows: list[np.ndarray], windows: dict, scratch: "_Scratch") -> list[np.ndarray]:
        """Values of every unknown at a block of points, all in the same ``windows``.

        Parameters
        ----------
        rows : list of ndarray
            Per coordinate (codebook order), the cardinal rows of the block (see :meth:`rows`).
        windows : dict
            Coordinate -> the window of the block's points: the first coordinate, and the later
            ones the block is grouped by.
        scratch : _Scratch
            The calling thread's buffers for the intermediates.

        Returns
        -------
        list of ndarray, each shape (P,): views of ``scratch``, valid until its next block
        """
        window = windows[self.order[0]]
        lo = int(self.starts[window])
        local = rows[self.order[0]]  # (P, w): the row vanishes outside the window
        p = local.shape[0]
        if self.pair is not None:
            # points last (rows given as transposed views): the Khatri-Rao block (w n2, P) is one
            # broadcast along the points, and its transpose goes to BLAS as is
            second = rows[self.order[1]]  # (P, n2), or its window's columns
            kr = scratch.get("kr", (second.shape[1], local.shape[1], p))  # (n2, w, P)
            np.multiply(second.T[:, None, :], local.T[None, :, :], out=kr)
            table, ranks = self.pair[window], self.pair_ranks
            if self.order[1] in windows:  # the rows of the second coordinate's window
                start, width = self._window(self.order[1], windows)
                table = table[start * self.width:(start + width) * self.width]
            running = np.matmul(kr.reshape(-1, p).T, table, out=scratch.get("first", (p, table.shape[1])))
        else:
            table, ranks = self.first[lo:lo + self.width], self.first_ranks
            running = np.matmul(local, table, out=scratch.get("first", (p, table.shape[1])))
        bounds = np.cumsum([0] + ranks)
        vs = [running[:, a:b] for a, b in zip(bounds[:-1], bounds[1:])]
        for k, (j, rows_first, table, shapes, offsets) in enumerate(self.rest):
            w = rows[j]
            # two sets of outputs in turn: this core reads the last one's (a small footprint in the cache)
            outs = [scratch.get((k % 2, u), (p, 1, r1)) for u, (_, r1) in enumerate(shapes)]
            start, width = self._window(j, windows) if j in windows else (0, None)
            if rows_first:  # (P, n) @ (n, r0 r1) for all unknowns, then each point's (r0,) @ (r0, r1)
                if width is not None:  # the window's rows of the table
                    table = table[start:start + width]
                sliced = np.matmul(w, table, out=scratch.get("sliced", (p, table.shape[1])))
                for v, (r0, r1), a, out in zip(vs, shapes, offsets, outs):
                    np.matmul(v[:, None, :], sliced[:, a:a + r0 * r1].reshape(p, r0, r1), out=out)
            else:  # (P, r0) @ (r0, n r1) per unknown, then each point's (n,) @ (n, r1)
                for v, g, (n, r1), out in zip(vs, table, shapes, outs):
                    if width is not None:  # the window's columns of the unfolded core
                        g, n = g[:, start * r1:(start + width) * r1], width
                    product = np.matmul(v, g, out=scratch.get("product", (p, n * r1)))
                    np.matmul(w[:, None, :], product.reshape(p, n, r1), out=out)
            vs = [out[:, 0, :] for out in outs]
        return [v[:, 0] for v in vs]


class _Scratch:
    """One thread's buffers for a batch's intermediates, each reused at every block.

    ``get(key, shape)`` returns a C-contiguous array of ``shape`` over the buffer named ``key``,
    grown when a block needs more than it holds (the first full block of a train); the views are
    kept, since most blocks have the same shape and a rigid-body block asks for ~40 of them.
    """

    def __init__(self):
        self._buffers: dict = {}
        self._views: dict = {}

    def get(self, key, shape: tuple[int, ...]) -> np.ndarray:
        view = self._views.get((key, shape))
        if view is None:
            size = math.prod(shape)
            buffer = self._buffers.get(key)
            if buffer is None or buffer.size < size:
                buffer = self._buffers[key] = np.empty(size)
            view = self._views[key, shape] = buffer[:size].reshape(shape)
        return view


def _blocks(window: np.ndarray, block: int) -> list[tuple[int, int]]:
    """Bounds ``(lo, hi)`` of blocks of at most ``block`` points, each within one window
    (``window``: the sorted window index of every point)."""
    edges = np.flatnonzero(np.diff(window)) + 1
    bounds = []
    for lo, hi in zip(np.concatenate([[0], edges]), np.concatenate([edges, [window.size]])):
        bounds.extend((int(a), int(min(a + block, hi))) for a in range(int(lo), int(hi), block))
    return bounds


class TTBatch:
    """The tensor-train unknowns of a codebook, prepared for batches of points.

    Parameters
    ----------
    fields : mapping
        Unknown name -> field with ``cores`` (each (r0, n, r1)) and ``mode_order``
        (coordinate index per core); only these unknowns are prepared.
    bases : sequence
        Per coordinate (codebook order), its basis (``interpolation_matrix``, ``nodes``, ``kind``).
    """

    def __init__(self, fields: Mapping, bases: Sequence):
        self.bases = list(bases)
        groups: dict = {}
        for u, f in fields.items():
            groups.setdefault(tuple(f.mode_order), []).append(u)
        self.trains = [_Train(names, fields, self.bases) for names in groups.values()]

    def _group_key(self, train: _Train, flat: Sequence[np.ndarray]) -> tuple[np.ndarray, list]:
        """Each point's group: its window of the train's first coordinate and of the later
        coordinates worth grouping by, as one mixed-radix integer.

        A later coordinate of several windows is grouped by (the largest saving first) when the
        multiply-adds it saves (its core then costs a point ``w / n`` of them) outweigh the blocks
        its windows add, by the cost model of SECONDS_PER_MADD and SECONDS_PER_BLOCK.

        Returns
        -------
        key : ndarray of unsigned int, shape (P,)
            The smallest type: numpy's stable sort of <= 16-bit integers is a radix sort, a few
            times faster than the merge sort of int64 keys.
        radices : list of (coordinate, window count)
            The later coordinates in the key, most significant first after the first coordinate.
        """
        size = flat[0].size
        first = train.order[0]
        key = _window_of(self.bases[first], flat[first]).astype(np.int64)
        groups, radices = train.starts.size, []
        saved = {j: train.later_madds[j] * (1.0 - width / self.bases[j].size) * size * SECONDS_PER_MADD
                 for j, (_, width) in train.later_windows.items()}
        for j in sorted(saved, key=saved.get, reverse=True):
            starts = train.later_windows[j][0]
            if saved[j] <= groups * (starts.size - 1) * SECONDS_PER_BLOCK:
                continue
            key = key * starts.size + _window_of(self.bases[j], flat[j])
            groups *= starts.size
            radices.append((j, starts.size))
        return key.astype(np.min_scalar_type(groups - 1)), radices

    def evaluate(self, flat: Sequence[np.ndarray], selected: Sequence[str],
                 run_chunks: Callable | None = None) -> dict[str, np.ndarray]:
        """Values of the ``selected`` unknowns at the points ``flat[j][i]``.

        Parameters
        ----------
        flat : sequence of ndarray
            Per coordinate, the points' values (checked and clipped to the domain), shape (P,).
        selected : sequence of str
        run_chunks : callable, optional
            ``run_chunks(run, bounds)`` calls ``run(iterator of (lo, hi))`` over ``bounds``
            (the caller's BLAS and thread policy); default: in this thread.

        Returns
        -------
        dict
            Unknown name -> ndarray, shape (P,).
        """
        size = flat[0].size
        out = {u: np.empty(size) for u in selected}
        wanted = set(selected)
        for train in self.trains:
            if size == 0 or not wanted.intersection(train.names):
                continue
            first = train.order[0]
            key, radices = self._group_key(train, flat)
            order = np.argsort(key, kind="stable")
            key = key[order]
            bounds = _blocks(key, train.block)
            targets = [out.get(u) for u in train.names]

            def run(todo, train=train, order=order, key=key, radices=radices, targets=targets, first=first):
                scratch = _Scratch()
                for lo, hi in todo:
                    idx = order[lo:hi]
                    k, windows = int(key[lo]), {}
                    for j, count in reversed(radices):
                        k, windows[j] = divmod(k, count)
                    windows[first] = k
                    rows = train.rows(self.bases, flat, idx, windows, scratch)
                    for target, values in zip(targets, train.contract(rows, windows, scratch)):
                        if target is not None:
                            target[idx] = values

            (run_chunks or (lambda f, b: f(iter(b))))(run, bounds)
        return out
