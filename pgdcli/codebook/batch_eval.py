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

Blocks of points are sized so that the intermediates stay in the second-level cache.

The first core of the train (the time coordinate of the march's codebooks) is split
into windows: the slabs of a piecewise Chebyshev coordinate, the elements of a linear
one. A point's cardinal row vanishes outside its window, so the points are grouped by
window (a stable sort) and each group uses only its window's nodes. When the window is
narrower than the first bond, the first two cores are merged per window beforehand
into a table of ``(w n_2, r_2)``: per point ``w n_2 r_2`` multiply-adds instead of
``w r_1 + r_1 n_2 r_2`` and one product less.

The values equal those of the core-by-core row-wise contraction
(:func:`pgdcli.codebook.evaluate.contract_tt`) to rounding: the same sums in another order.
Measurements: ``benchmarks/query_speed_tt.py`` and benchmarks/README.md.
"""

from __future__ import annotations

from typing import Callable, Mapping, Sequence

import numpy as np

from ..discretization.basis import barycentric_rows

__all__ = ["TTBatch"]

# Points per block: the block's widest intermediate (points x values per point) takes 3/4 MiB of
# the second-level cache (1 MiB per core here), the other intermediates the rest. Measured, one
# thread, 1e5 points, block sizes interleaved in one process (medians of 7, load ~3): coupled
# (widest 160 values) 162 / 158 / 172-286 ms at 409 / 614 / 819 points; logistic (widest 192)
# 62 / 60 / 57 ms at 341 / 512 / 682; the rigid body (widest 520) 1.68 / 1.62 / 1.58 s at 126 /
# 189 / 252 and 2.1 s at 512.
BLOCK_BYTES = 3 << 18
MIN_BLOCK, MAX_BLOCK = 32, 1024
# Merged first-two-core tables are kept up to this many values (all windows, all unknowns).
MAX_PAIR_VALUES = 1 << 22


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
        return basis.slab_of(x)
    if basis.kind == "linear":
        n = basis.nodes.size
        return np.clip(np.searchsorted(basis.nodes, x, side="right") - 1, 0, n - 2)
    return np.zeros(x.size, dtype=int)


def _local_rows(basis, x: np.ndarray, lo: int, width: int) -> np.ndarray:
    """Cardinal rows of ``x`` (shape (P,), all in the window starting at node ``lo``) on that
    window's nodes only, shape (P, width): the arithmetic of the basis's own interpolation rows.
    """
    if width == basis.nodes.size:
        return basis.interpolation_matrix(x)
    nodes = basis.nodes[lo:lo + width]
    if basis.kind == "linear":
        theta = (x - nodes[0]) / (nodes[1] - nodes[0])
        return np.column_stack([1.0 - theta, theta])
    return barycentric_rows(x, nodes, basis.bary)


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
        # point's cardinal row (n,) times its (n, r1) block. Measured on the rigid body's (72, 8, 65)
        # core, 512 points, one thread: rows first 6.8 us per point and unknown, vector first 1.4 us,
        # the row-wise Khatri-Rao product of v and the rows times the core as (r0 n, r1) (the path
        # before) 2.0 us, a third of it forming the Khatri-Rao block
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

    def _pair_table(self, first: list[np.ndarray], second: list[np.ndarray], lo: int) -> np.ndarray:
        """(w n2, sum_u r2_u): ``G1[0, lo + a, :] G2[:, b, :]`` for every unknown, rows ``a n2 + b``."""
        w = self.width
        parts = [np.einsum("ar,rbs->abs", g1[0, lo:lo + w], g2).reshape(w * g2.shape[1], g2.shape[2])
                 for g1, g2 in zip(first, second)]
        return np.ascontiguousarray(np.hstack(parts))

    def contract(self, rows: list[np.ndarray], window: int) -> list[np.ndarray]:
        """Values of every unknown at a block of points, all in ``window`` of the first coordinate.

        Parameters
        ----------
        rows : list of ndarray
            Per coordinate (codebook order), the cardinal rows of the block, shape (P, n_j);
            for the train's first coordinate only their window's columns, shape (P, w).
        window : int

        Returns
        -------
        list of ndarray, each shape (P,)
        """
        lo = int(self.starts[window])
        local = rows[self.order[0]]  # (P, w): the row vanishes outside the window
        p = local.shape[0]
        if self.pair is not None:
            second = rows[self.order[1]]
            kr = (local[:, :, None] * second[:, None, :]).reshape(p, -1)  # (P, w n2)
            running = kr @ self.pair[window]
            ranks = self.pair_ranks
        else:
            running = local @ self.first[lo:lo + self.width]  # (P, sum_u r1_u)
            ranks = self.first_ranks
        bounds = np.cumsum([0] + ranks)
        vs = [running[:, a:b] for a, b in zip(bounds[:-1], bounds[1:])]
        for j, rows_first, table, shapes, offsets in self.rest:
            w = rows[j]
            if rows_first:  # (P, n) @ (n, r0 r1) for all unknowns, then each point's (r0,) @ (r0, r1)
                sliced = w @ table
                vs = [np.matmul(v[:, None, :], sliced[:, a:a + r0 * r1].reshape(p, r0, r1))[:, 0, :]
                      for v, (r0, r1), a in zip(vs, shapes, offsets)]
            else:  # (P, r0) @ (r0, n r1) per unknown, then each point's (n,) @ (n, r1)
                w = w[:, None, :]
                vs = [np.matmul(w, (v @ g).reshape(p, n, r1))[:, 0, :] for v, g, (n, r1) in zip(vs, table, shapes)]
        return [v[:, 0] for v in vs]


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
            window = _window_of(self.bases[first], flat[first])
            order = np.argsort(window, kind="stable")
            window = window[order]
            bounds = []
            edges = np.flatnonzero(np.diff(window)) + 1
            for lo, hi in zip(np.concatenate([[0], edges]), np.concatenate([edges, [size]])):
                bounds.extend((int(a), int(min(a + train.block, hi))) for a in range(int(lo), int(hi), train.block))
            targets = [out.get(u) for u in train.names]

            def run(todo, train=train, order=order, window=window, targets=targets, first=first):
                for lo, hi in todo:
                    idx = order[lo:hi]
                    k = int(window[lo])
                    rows = [_local_rows(b, x[idx], int(train.starts[k]), train.width) if j == first
                            else b.interpolation_matrix(x[idx]) for j, (b, x) in enumerate(zip(self.bases, flat))]
                    for target, values in zip(targets, train.contract(rows, k)):
                        if target is not None:
                            target[idx] = values

            (run_chunks or (lambda f, b: f(iter(b))))(run, bounds)
        return out
