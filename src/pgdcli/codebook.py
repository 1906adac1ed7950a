"""Codebooks: evaluation of separated solutions and their HDF5 files.

A codebook holds, for every unknown ``u``, a separated representation

    u(x_1, ..., x_d) = sum_i alpha_i  U_i1(x_1) * ... * U_id(x_d)

with the modes stored by their values at the nodes of each coordinate's
basis, plus the problem spec and the solver report. Evaluation interpolates
each mode with its basis's own interpolant (barycentric for Chebyshev,
piecewise linear for linear elements), so a query at the nodes returns the
nodal values exactly.

The file layout is documented in ``docs/codebook-format.md``. This module is
on the query path: it imports numpy and h5py only (no scipy, no yaml).
"""

from __future__ import annotations

import datetime as _dt
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from .basis import KINDS, make_basis
from .errors import CodebookError, QueryError

__all__ = ["Codebook", "CoordinateInfo", "FieldModes", "FORMAT_NAME", "FORMAT_VERSION"]

FORMAT_NAME = "pgdcli-codebook"
FORMAT_VERSION = "1.0"
_SUPPORTED_MAJOR = 1


@dataclass(frozen=True)
class CoordinateInfo:
    """A coordinate of the codebook: name, domain, nodes, discretization and role."""

    name: str
    domain: tuple[float, float]
    nodes: int
    discretization: str = "chebyshev"
    role: str = "parameter"  # 'time' | 'parameter'

    def basis(self):
        return make_basis(self.discretization, self.domain, self.nodes)


@dataclass(frozen=True, eq=False)
class FieldModes:
    """Separated representation of one unknown (weights + one mode matrix per coordinate).

    Parameters
    ----------
    alphas : ndarray, shape (n,)
    modes : tuple of ndarray, each shape (nodes_j, n)
    """

    alphas: np.ndarray
    modes: tuple[np.ndarray, ...]

    @property
    def rank(self) -> int:
        return int(self.alphas.size)


def _validate(name: str, coordinates: Sequence[CoordinateInfo], fm: FieldModes) -> None:
    if fm.alphas.ndim != 1:
        raise CodebookError(f"unknown {name!r}: alphas must be 1D, got shape {fm.alphas.shape}")
    if len(fm.modes) != len(coordinates):
        raise CodebookError(f"unknown {name!r}: {len(fm.modes)} mode matrices for {len(coordinates)} coordinates")
    for j, (c, m) in enumerate(zip(coordinates, fm.modes)):
        if m.shape != (c.nodes, fm.rank):
            raise CodebookError(
                f"unknown {name!r}: modes of coordinate {j} ({c.name!r}) have shape {m.shape}, "
                f"expected ({c.nodes}, {fm.rank})"
            )
    if not (np.all(np.isfinite(fm.alphas)) and all(np.all(np.isfinite(m)) for m in fm.modes)):
        raise CodebookError(f"unknown {name!r}: alphas or modes contain non-finite values")


class Codebook:
    """A separated solution that evaluates anywhere in its domain.

    Parameters
    ----------
    coordinates : sequence of CoordinateInfo
        In dimension order.
    fields : mapping
        Unknown name -> :class:`FieldModes`, in output order.
    name : str
    spec_text : str
        The YAML spec the codebook was solved from.
    report : dict
        Solver report (see ``docs/codebook-format.md``).
    description : str

    Examples
    --------
    >>> cb = Codebook.load("codebooks/parametric.h5")      # doctest: +SKIP
    >>> cb(t=[0.0, 5.0], k=2.0)["u"]                        # doctest: +SKIP
    array([0., 20.])
    """

    def __init__(self, coordinates: Sequence[CoordinateInfo], fields: Mapping[str, FieldModes], *,
                 name: str = "codebook", spec_text: str = "", report: Mapping | None = None,
                 description: str = "", created: str | None = None):
        self.coordinates = tuple(coordinates)
        if not self.coordinates:
            raise CodebookError("a codebook needs at least one coordinate")
        self.fields = dict(fields)
        if not self.fields:
            raise CodebookError("a codebook needs at least one unknown")
        for uname, fm in self.fields.items():
            _validate(uname, self.coordinates, fm)
        self.name = name
        self.spec_text = spec_text
        self.description = description
        self.report = dict(report or {})
        self.created = created or _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        self._bases = [c.basis() for c in self.coordinates]
        # all unknowns' modes side by side: one interpolation per coordinate serves every unknown
        self._stacked = [np.hstack([fm.modes[j] for fm in self.fields.values()]) for j in range(len(self.coordinates))]
        bounds = np.cumsum([0] + [fm.rank for fm in self.fields.values()])
        self._slices = {u: slice(bounds[i], bounds[i + 1]) for i, u in enumerate(self.fields)}

    # ------------------------------------------------------------------ introspection
    @property
    def coordinate_names(self) -> list[str]:
        return [c.name for c in self.coordinates]

    @property
    def unknown_names(self) -> list[str]:
        return list(self.fields)

    def coordinate(self, name: str) -> CoordinateInfo:
        for c in self.coordinates:
            if c.name == name:
                return c
        raise QueryError(f"unknown coordinate {name!r}; this codebook has {', '.join(self.coordinate_names)}")

    def __repr__(self) -> str:
        coords = ", ".join(f"{c.name}=[{c.domain[0]:g}, {c.domain[1]:g}]" for c in self.coordinates)
        ranks = ", ".join(f"{u}: {fm.rank}" for u, fm in self.fields.items())
        return f"<Codebook {self.name!r} coordinates ({coords}) modes ({ranks})>"

    # ------------------------------------------------------------------ evaluation
    def __call__(self, **coordinates) -> dict[str, np.ndarray]:
        """Evaluate every unknown; see :meth:`evaluate`."""
        return self.evaluate(coordinates)

    def evaluate(self, coordinates: Mapping[str, object], fields: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """Evaluate unknowns at points given per coordinate.

        Parameters
        ----------
        coordinates : mapping
            Every coordinate name -> scalar or array_like; the arrays are
            broadcast together with numpy rules.
        fields : sequence of str, optional
            Unknowns to evaluate (default: all, in declared order).

        Returns
        -------
        dict
            Unknown name -> ndarray of the broadcast shape (0-d for scalars).

        Raises
        ------
        QueryError
            Missing, unknown or out-of-domain coordinates, unknown fields.
        """
        names = self.coordinate_names
        for key in coordinates:
            if key not in names:
                raise QueryError(f"unknown coordinate {key!r}; this codebook has {', '.join(names)}")
        for c in self.coordinates:
            if c.name not in coordinates:
                raise QueryError(f"missing coordinate {c.name!r} (domain [{c.domain[0]:g}, {c.domain[1]:g}])")
        selected = self._select(fields)
        arrays = np.broadcast_arrays(*[np.asarray(coordinates[n], dtype=float) for n in names])
        shape = arrays[0].shape
        flat = [self._checked(c, a.reshape(-1)) for c, a in zip(self.coordinates, arrays)]
        values = self._evaluate_flat(flat, selected)
        return {u: v.reshape(shape) for u, v in values.items()}

    def _select(self, fields: Sequence[str] | None) -> list[str]:
        if fields is None:
            return self.unknown_names
        out = []
        for f in fields:
            if f not in self.fields:
                raise QueryError(f"unknown field {f!r}; this codebook has {', '.join(self.unknown_names)}")
            out.append(f)
        return out

    @staticmethod
    def _checked(c: CoordinateInfo, x: np.ndarray) -> np.ndarray:
        low, high = c.domain
        slack = 1e-12 * max(1.0, abs(low), abs(high))  # rounding in user-side arithmetic (e.g. linspace)
        bad = ~((x >= low - slack) & (x <= high + slack))
        if bad.any():
            v = float(x[bad][0])
            raise QueryError(f"coordinate {c.name!r}: value {v!r} is outside the domain [{low:g}, {high:g}]")
        return np.clip(x, low, high)

    def _evaluate_flat(self, flat: list[np.ndarray], selected: list[str]) -> dict[str, np.ndarray]:
        product = None
        for basis, stacked, x in zip(self._bases, self._stacked, flat):
            vals = basis.interpolation_matrix(x) @ stacked  # (P, total rank)
            product = vals if product is None else product * vals
        return {u: product[:, self._slices[u]] @ self.fields[u].alphas for u in selected}

    def nodal_values(self, field_name: str) -> np.ndarray:
        """The unknown on the full tensor grid of nodes (small codebooks only: tests and plots)."""
        fm = self.fields[self._select([field_name])[0]]
        out = np.zeros(tuple(c.nodes for c in self.coordinates))
        letters = "abcdefghijklmnopqrstuvwxyz"[: len(self.coordinates)]
        expr = ",".join(f"{l}r" for l in letters) + ",r->" + letters
        out += np.einsum(expr, *fm.modes, fm.alphas)
        return out

    # ------------------------------------------------------------------ summary
    def info(self, path: str | os.PathLike | None = None) -> dict:
        """Summary as plain Python data (what ``pgd info`` prints)."""
        rep = self.report
        out = {
            "name": self.name,
            "description": self.description,
            "format": f"{FORMAT_NAME} {FORMAT_VERSION}",
            "created": self.created,
            "coordinates": [
                {"name": c.name, "role": c.role, "domain": [c.domain[0], c.domain[1]], "nodes": c.nodes,
                 "discretization": c.discretization}
                for c in self.coordinates
            ],
            "unknowns": {u: {"modes": fm.rank} for u, fm in self.fields.items()},
            "converged": bool(rep.get("converged", False)),
            "residual": float(rep.get("residual", np.nan)),
            "tolerance": float(rep.get("tolerance", np.nan)),
            "solve_time": float(rep.get("wall_time", np.nan)),
            "pgdcli_version": str(rep.get("pgdcli_version", "")),
        }
        if path is not None:
            out["size_bytes"] = os.path.getsize(path)
        return out

    # ------------------------------------------------------------------ I/O
    def save(self, path: str | os.PathLike) -> Path:
        """Write the codebook to ``path`` atomically (temporary file + rename).

        A crash or error while writing leaves any previous file at ``path``
        untouched and no partial file behind.
        """
        import h5py

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        os.close(fd)
        try:
            with h5py.File(tmp, "w") as f:
                self._write(f)
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
            raise
        return path

    def _write(self, f) -> None:
        from . import __version__

        f.attrs["encoding-type"] = FORMAT_NAME
        f.attrs["encoding-version"] = FORMAT_VERSION
        f.attrs["pgdcli-version"] = __version__
        f.attrs["name"] = self.name
        f.attrs["description"] = self.description
        f.attrs["created"] = self.created
        f.attrs["coordinate-order"] = np.array(self.coordinate_names, dtype=object)
        f.attrs["unknown-order"] = np.array(self.unknown_names, dtype=object)
        f.create_dataset("spec", data=self.spec_text)
        gc = f.create_group("coordinates")
        for c in self.coordinates:
            g = gc.create_group(c.name)
            g.attrs["domain"] = np.array(c.domain, dtype=float)
            g.attrs["discretization"] = c.discretization
            g.attrs["role"] = c.role
            g.create_dataset("nodes", data=c.basis().nodes)
        gu = f.create_group("unknowns")
        for u, fm in self.fields.items():
            g = gu.create_group(u)
            g.create_dataset("alphas", data=fm.alphas)
            gm = g.create_group("modes")
            for c, m in zip(self.coordinates, fm.modes):
                gm.create_dataset(c.name, data=m)
        gr = f.create_group("report")
        for key, value in self.report.items():
            if isinstance(value, np.ndarray):
                gr.create_dataset(key, data=value)
            elif value is not None:
                gr.attrs[key] = value

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Codebook":
        """Read a codebook file.

        Raises
        ------
        CodebookError
            The file is missing, not HDF5, truncated, not a codebook, of an
            unknown major version, or inconsistent.
        """
        import h5py

        p = str(path)
        if not os.path.exists(p):
            raise CodebookError(f"{p}: no such file")
        if os.path.isdir(p):
            raise CodebookError(f"{p}: is a directory, expected a codebook file (.h5)")
        try:
            f = h5py.File(p, "r")
        except OSError:
            raise CodebookError(f"{p}: not a readable HDF5 file (truncated or not a codebook)") from None
        try:
            with f:
                return cls._read(f, p)
        except CodebookError:
            raise
        except (KeyError, OSError, ValueError, TypeError) as exc:
            raise CodebookError(f"{p}: corrupt codebook ({_one_line(exc)})") from None

    @classmethod
    def _read(cls, f, p: str) -> "Codebook":
        kind = _attr_str(f.attrs.get("encoding-type"))
        if kind != FORMAT_NAME:
            raise CodebookError(f"{p}: not a pgdcli codebook (encoding-type {kind!r}, expected {FORMAT_NAME!r})")
        version = _attr_str(f.attrs.get("encoding-version"))
        try:
            major = int(version.split(".")[0])
        except (ValueError, AttributeError):
            raise CodebookError(f"{p}: unreadable encoding-version {version!r}") from None
        if major > _SUPPORTED_MAJOR:
            raise CodebookError(
                f"{p}: codebook format {version} is newer than this pgdcli supports "
                f"({_SUPPORTED_MAJOR}.x); upgrade pgdcli (pip install -U pgdcli)"
            )
        if major < 1:
            raise CodebookError(f"{p}: unsupported codebook format {version}")
        coord_names = [_attr_str(x) for x in f.attrs["coordinate-order"]]
        unknown_names = [_attr_str(x) for x in f.attrs["unknown-order"]]
        coords = []
        for name in coord_names:
            g = f["coordinates"][name]
            domain = tuple(float(v) for v in g.attrs["domain"])
            kind_ = _attr_str(g.attrs["discretization"])
            if kind_ not in KINDS:
                raise CodebookError(f"{p}: coordinate {name!r} has unknown discretization {kind_!r}")
            nodes = g["nodes"][()]
            info = CoordinateInfo(name, domain, int(nodes.size), kind_, _attr_str(g.attrs.get("role", "parameter")))
            if not np.array_equal(info.basis().nodes, nodes):
                raise CodebookError(f"{p}: stored nodes of coordinate {name!r} do not match its {kind_} basis")
            coords.append(info)
        fields = {}
        for u in unknown_names:
            g = f["unknowns"][u]
            modes = tuple(np.asarray(g["modes"][c][()], dtype=float) for c in coord_names)
            fields[u] = FieldModes(np.asarray(g["alphas"][()], dtype=float).reshape(-1), modes)
        report = {}
        if "report" in f:
            gr = f["report"]
            report.update({k: _attr_value(v) for k, v in gr.attrs.items()})
            report.update({k: gr[k][()] for k in gr.keys()})
        spec = f["spec"][()] if "spec" in f else b""
        return cls(
            coords, fields,
            name=_attr_str(f.attrs.get("name", "codebook")),
            spec_text=spec.decode() if isinstance(spec, bytes) else str(spec),
            report=report,
            description=_attr_str(f.attrs.get("description", "")),
            created=_attr_str(f.attrs.get("created", "")) or None,
        )


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _attr_str(v) -> str:
    if isinstance(v, bytes):
        return v.decode()
    if v is None:
        return ""
    return str(v)


def _attr_value(v):
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.generic):
        return v.item()
    return v


def codebook_from_solution(problem, disc, alphas: np.ndarray, factors: list[np.ndarray], report: dict) -> Codebook:
    """Assemble the codebook of a solved problem: lift terms + PGD terms per unknown."""
    from . import __version__

    coords = [CoordinateInfo(c.name, tuple(c.domain), c.nodes, c.discretization, c.role) for c in problem.coordinates]
    nodal = disc.nodal_factors(factors)
    fields = {}
    for u in disc.unknowns:
        lift = disc.lift[u]
        modes = nodal[u]
        # a term whose time function vanishes for this unknown carries nothing for it
        keep = np.any(modes[[c.name for c in coords].index(disc.time)] != 0.0, axis=0) & (alphas != 0.0)
        fields[u] = FieldModes(
            np.concatenate([lift.weights, alphas[keep]]),
            tuple(np.hstack([lf, nf[:, keep]]) for lf, nf in zip(lift.factors, modes)),
        )
    report = dict(report)
    report["pgdcli_version"] = __version__
    return Codebook(coords, fields, name=problem.name, spec_text=problem.source_text, report=report,
                    description=problem.description)
