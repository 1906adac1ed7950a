"""Codebook files: the HDF5 layout (docs/codebook-format.md), its version check, atomic writes.

Reading returns the constructor arguments of :class:`~pgdcli.codebook.codebook.Codebook`, so this
module does not import the class (it is imported by it). numpy and h5py only (the query path).
"""

from __future__ import annotations

import os

import numpy as np

from ..discretization.basis import KINDS
from ..discretization.coordinates import CoordinateInfo
from ..errors import CodebookError
from .fields import FieldModes, FieldTT

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "SUPPORTED_MAJOR", "save", "write_contents", "load_parts", "read_contents"]

FORMAT_NAME = "pgdcli-codebook"
FORMAT_VERSION = "1.0"
SUPPORTED_MAJOR = 1

# pathlib and tempfile are imported by save() only: pgd query never writes


def save(cb, path: str | os.PathLike) -> "os.PathLike":
    """Write the codebook to ``path`` atomically (temporary file + rename).

    A crash or error while writing leaves any previous file at ``path``
    untouched and no partial file behind.
    """
    import tempfile
    from pathlib import Path

    import h5py

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise CodebookError(f"{path}: cannot write the codebook ({one_line(exc)})") from None
    os.close(fd)
    try:
        # mkstemp creates 0600; a codebook gets the usual permissions (umask applies)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        with h5py.File(tmp, "w") as f:
            write_contents(cb, f)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError):
            raise CodebookError(f"{path}: cannot write the codebook ({one_line(exc)})") from None
        raise
    return path


def write_contents(cb, f) -> None:
    """Write a codebook's groups and attributes into an open HDF5 file (the layout of docs/codebook-format.md)."""
    from .. import __version__

    f.attrs["encoding-type"] = FORMAT_NAME
    f.attrs["encoding-version"] = FORMAT_VERSION
    f.attrs["pgdcli-version"] = __version__
    f.attrs["name"] = cb.name
    f.attrs["description"] = cb.description
    f.attrs["created"] = cb.created
    f.attrs["coordinate-order"] = np.array(cb.coordinate_names, dtype=object)
    f.attrs["unknown-order"] = np.array(cb.unknown_names, dtype=object)
    f.create_dataset("spec", data=cb.spec_text)
    gc = f.create_group("coordinates")
    for c in cb.coordinates:
        g = gc.create_group(c.name)
        g.attrs["domain"] = np.array(c.domain, dtype=float)
        g.attrs["discretization"] = c.discretization
        g.attrs["role"] = c.role
        if c.breakpoints:
            g.attrs["breakpoints"] = np.array(c.breakpoints, dtype=float)
        g.create_dataset("nodes", data=c.basis().nodes)
    gu = f.create_group("unknowns")
    for u, fm in cb.fields.items():
        g = gu.create_group(u)
        if isinstance(fm, FieldTT):
            g.attrs["representation"] = "tensor-train"
            g.attrs["mode-order"] = np.array([cb.coordinates[j].name for j in fm.mode_order], dtype=object)
            gc = g.create_group("cores")
            for j, core in zip(fm.mode_order, fm.cores):
                gc.create_dataset(cb.coordinates[j].name, data=core)
            continue
        g.attrs["representation"] = "cp"
        g.create_dataset("alphas", data=fm.alphas)
        gm = g.create_group("modes")
        for c, m in zip(cb.coordinates, fm.modes):
            gm.create_dataset(c.name, data=m)
    gr = f.create_group("report")
    for key, value in cb.report.items():
        if isinstance(value, np.ndarray):
            gr.create_dataset(key, data=value)
        elif value is not None:
            gr.attrs[key] = value


def load_parts(path: str | os.PathLike, basis) -> dict:
    """Read a codebook file: the keyword arguments of :class:`~pgdcli.codebook.codebook.Codebook`.

    ``basis(info)`` builds (or reuses) a coordinate's basis, to check the stored nodes.

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
            return read_contents(f, p, basis)
    except CodebookError:
        raise
    except (KeyError, OSError, ValueError, TypeError) as exc:
        raise CodebookError(f"{p}: corrupt codebook ({one_line(exc)})") from None


def read_contents(f, p: str, basis) -> dict:
    """The constructor arguments of the codebook in an open HDF5 file (``p`` names it in errors)."""
    kind = attr_str(f.attrs.get("encoding-type"))
    if kind != FORMAT_NAME:
        raise CodebookError(f"{p}: not a pgdcli codebook (encoding-type {kind!r}, expected {FORMAT_NAME!r})")
    version = attr_str(f.attrs.get("encoding-version"))
    try:
        major = int(version.split(".")[0])
    except (ValueError, AttributeError):
        raise CodebookError(f"{p}: unreadable encoding-version {version!r}") from None
    if major > SUPPORTED_MAJOR:
        raise CodebookError(
            f"{p}: codebook format {version} is newer than this pgdcli supports "
            f"({SUPPORTED_MAJOR}.x); upgrade pgdcli (pip install -U pgdcli)"
        )
    if major < 1:
        raise CodebookError(f"{p}: unsupported codebook format {version}")
    coord_names = [attr_str(x) for x in f.attrs["coordinate-order"]]
    unknown_names = [attr_str(x) for x in f.attrs["unknown-order"]]
    coords = []
    for name in coord_names:
        g = f["coordinates"][name]
        domain = tuple(float(v) for v in g.attrs["domain"])
        kind_ = attr_str(g.attrs["discretization"])
        if kind_ not in KINDS:
            raise CodebookError(f"{p}: coordinate {name!r} has unknown discretization {kind_!r}")
        nodes = g["nodes"][()]
        breakpoints = tuple(float(v) for v in g.attrs.get("breakpoints", ()))
        info = CoordinateInfo(name, domain, int(nodes.size), kind_, attr_str(g.attrs.get("role", "parameter")),
                              breakpoints)
        if not np.array_equal(basis(info).nodes, nodes):  # built once: the codebook reuses it
            raise CodebookError(f"{p}: stored nodes of coordinate {name!r} do not match its {kind_} basis")
        coords.append(info)
    fields = {}
    for u in unknown_names:
        g = f["unknowns"][u]
        representation = attr_str(g.attrs.get("representation", "cp"))
        if representation == "tensor-train":
            order = [attr_str(x) for x in g.attrs["mode-order"]]
            unknown_coords = [c for c in order if c not in coord_names]
            if unknown_coords:
                raise CodebookError(f"{p}: unknown {u!r}: tensor-train core for unknown coordinate "
                                    f"{unknown_coords[0]!r}")
            cores = tuple(np.asarray(g["cores"][c][()], dtype=float) for c in order)
            fields[u] = FieldTT(cores, tuple(coord_names.index(c) for c in order))
            continue
        if representation != "cp":
            raise CodebookError(f"{p}: unknown {u!r} has representation {representation!r}, which this "
                                f"pgdcli does not know; upgrade pgdcli (pip install -U pgdcli)")
        modes = tuple(np.asarray(g["modes"][c][()], dtype=float) for c in coord_names)
        fields[u] = FieldModes(np.asarray(g["alphas"][()], dtype=float).reshape(-1), modes)
    report = {}
    if "report" in f:
        gr = f["report"]
        report.update({k: attr_value(v) for k, v in gr.attrs.items()})
        report.update({k: gr[k][()] for k in gr.keys()})
    spec = f["spec"][()] if "spec" in f else b""
    return dict(
        coordinates=coords, fields=fields,
        name=attr_str(f.attrs.get("name", "codebook")),
        spec_text=spec.decode() if isinstance(spec, bytes) else str(spec),
        report=report,
        description=attr_str(f.attrs.get("description", "")),
        created=attr_str(f.attrs.get("created", "")) or None,
    )


def one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def attr_str(v) -> str:
    if isinstance(v, bytes):
        return v.decode()
    if v is None:
        return ""
    return str(v)


def attr_value(v):
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.generic):
        return v.item()
    return v
