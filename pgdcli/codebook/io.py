"""Codebook files: the HDF5 layout (docs/codebook-format.md), its version check, atomic writes.

Reading returns the constructor arguments of :class:`~pgdcli.codebook.codebook.Codebook`, so this
module does not import the class (it is imported by it). numpy and h5py only (the query path).
"""

from __future__ import annotations

import io
import json
import os

import numpy as np

from .. import __version__
from ..discretization.basis import KINDS
from ..discretization.coordinates import CoordinateInfo
from ..errors import CodebookError
from ..limits import MAX_COORDINATES, MAX_UNKNOWNS, limit
from ..names import identifier_problem, printable, problem_name_problem
from .event_io import read_events, write_events
from .fields import TT, cp_field, tt_field
from .phase_io import PHASED, read_phases, write_phases
from .file_checks import (ARRAY_DIGESTS, CONTENT_DIGEST, Survey, array_digest, metadata_digest, open_codebook,
                          read_array, read_text, survey)

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "SUPPORTED_MAJOR", "save", "to_bytes", "write_atomic", "write_contents",
           "load_parts", "read_contents"]

FORMAT_NAME = "pgdcli-codebook"
#: 1.1: Fletcher-32 and a SHA-256 on every array, a SHA-256 of the metadata (1.0: neither);
#: 1.2: events (a 1.1 reader reads a 1.2 file without them); 1.3: phases of an event that acts (phase 0's
#: representations marked, so that an older reader refuses them)
FORMAT_VERSION = "1.3"
SUPPORTED_MAJOR = 1
#: HDF5 file format features of 1.10: checksummed superblock, object headers and chunk indexes
LIBVER = ("v110", "v110")
ROLES = ("time", "space", "parameter")

# pathlib and tempfile are imported by save() only: pgd query never writes


def save(cb, path: str | os.PathLike) -> "os.PathLike":
    """Write the codebook to ``path`` atomically (temporary file + rename).

    The file is built in memory by HDF5 and written by plain file calls: a full disk is an
    ``OSError`` here (one line), never a failure inside the HDF5 library. A crash or error while
    writing leaves any previous file at ``path`` untouched and no partial file behind.
    """
    if getattr(cb, "partial", False):
        raise CodebookError(f"{path}: this codebook was loaded without its spec and report (for "
                            f"evaluation only); load it whole to save it")
    return write_atomic(path, to_bytes(cb), what="the codebook")


def to_bytes(cb) -> bytes:
    """The codebook file's bytes (format :data:`FORMAT_VERSION`)."""
    import h5py

    buffer = io.BytesIO()
    with h5py.File(buffer, "w", libver=LIBVER) as f:
        write_contents(cb, f)
    return buffer.getvalue()


def write_atomic(path: str | os.PathLike, data: bytes | str, *, what: str = "the file",
                 mode: int = 0o666) -> "os.PathLike":
    """Write ``data`` to ``path`` atomically: a temporary file in the same folder, fsync, rename.

    Raises
    ------
    CodebookError
        The folder cannot be created or written, or the disk is full: ``path`` is left as it
        was and no temporary file remains.
    """
    import tempfile
    from pathlib import Path

    path = Path(path)
    payload = data.encode() if isinstance(data, str) else data
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise CodebookError(f"{path}: cannot write {what} ({one_line(exc)})") from None
    try:
        umask = os.umask(0)  # mkstemp creates 0600; the file gets the usual permissions
        os.umask(umask)
        os.fchmod(fd, mode & ~umask)
        view = memoryview(payload)
        while view:
            view = view[os.write(fd, view):]
        os.fsync(fd)
        os.close(fd)
        fd = -1
        os.replace(tmp, path)
    except BaseException as exc:
        if fd >= 0:
            os.close(fd)
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError):
            raise CodebookError(f"{path}: cannot write {what} ({one_line(exc)})") from None
        raise
    return path


def _array(group, name: str, values, digests: dict) -> None:
    """A dataset with Fletcher-32 (one chunk) where HDF5 allows it; its SHA-256 into ``digests``."""
    values = np.asarray(values)
    chunked = values.ndim > 0 and values.size > 0
    ds = group.create_dataset(name, data=values, chunks=values.shape if chunked else None, fletcher32=chunked)
    digests[ds.name.lstrip("/")] = array_digest(ds[()])


def write_contents(cb, f) -> None:
    """Write a codebook's groups and attributes into an open HDF5 file (the layout of docs/codebook-format.md)."""
    f.attrs["encoding-type"] = FORMAT_NAME
    f.attrs["encoding-version"] = FORMAT_VERSION
    f.attrs["pgdcli-version"] = __version__
    f.attrs["name"] = cb.name
    f.attrs["description"] = cb.description
    f.attrs["created"] = cb.created
    f.attrs["coordinate-order"] = np.array(cb.coordinate_names, dtype=object)
    f.attrs["unknown-order"] = np.array(cb.unknown_names, dtype=object)
    f.create_dataset("spec", data=cb.spec_text)
    digests = {"spec": array_digest(cb.spec_text)}
    gc = f.create_group("coordinates")
    for c in cb.coordinates:
        g = gc.create_group(c.name)
        g.attrs["domain"] = np.array(c.domain, dtype=float)
        g.attrs["discretization"] = c.discretization
        g.attrs["role"] = c.role
        if c.breakpoints:
            g.attrs["breakpoints"] = np.array(c.breakpoints, dtype=float)
        _array(g, "nodes", c.basis().nodes, digests)
    gu = f.create_group("unknowns")
    phased = PHASED if getattr(cb, "phases", None) is not None else ""
    for u, fm in cb.fields.items():
        g = gu.create_group(u)
        if isinstance(fm, TT):
            _write_train(g, cb.coordinates, fm, digests)
            g.attrs["representation"] = phased + "tensor-train"
            continue
        g.attrs["representation"] = phased + "cp"
        _array(g, "alphas", fm.weights, digests)
        gm = g.create_group("modes")
        for c, m in zip(cb.coordinates, fm.factors):
            _array(gm, c.name, m, digests)
    write_events(f, cb.events, lambda g, coordinates, train: _write_train(g, coordinates, train, digests))
    write_phases(f, cb, to_bytes, lambda g, name, values: _array(g, name, values, digests))
    gr = f.create_group("report")
    for key, value in cb.report.items():
        if isinstance(value, np.ndarray):
            _array(gr, key, value, digests)
        elif value is not None:
            gr.attrs[key] = value
    f.attrs[ARRAY_DIGESTS] = json.dumps(digests, sort_keys=True, separators=(",", ":"))
    f.attrs[CONTENT_DIGEST] = metadata_digest(survey(f, "<memory>"))


def _write_train(g, coordinates, fm: TT, digests: dict) -> None:
    g.attrs["representation"] = "tensor-train"
    g.attrs["mode-order"] = np.array([coordinates[j].name for j in fm.mode_order], dtype=object)
    gc = g.create_group("cores")
    for j, core in zip(fm.mode_order, fm.cores):
        _array(gc, coordinates[j].name, core, digests)


def load_parts(path: str | os.PathLike, basis, *, evaluation_only: bool = False) -> dict:
    """Read a codebook file: the keyword arguments of :class:`~pgdcli.codebook.codebook.Codebook`.

    ``basis(info)`` builds (or reuses) a coordinate's basis, to check the stored nodes. The
    file is checked before its data is read (:mod:`pgdcli.codebook.file_checks`). With
    ``evaluation_only`` the stored spec and the report's arrays are not read (``pgd query``).

    Raises
    ------
    CodebookError
        The file is missing, not a regular file, too large, not HDF5, truncated, not a
        codebook, of an unknown major version, not self-contained, inconsistent or corrupted.
    """
    p = str(path)
    f = open_codebook(p)
    try:
        with f:
            return read_contents(f, p, basis, evaluation_only=evaluation_only)
    except CodebookError:
        raise
    except (KeyError, OSError, ValueError, TypeError, RuntimeError, UnicodeDecodeError, IndexError,
            AttributeError, OverflowError) as exc:
        raise CodebookError(f"{p}: corrupt codebook ({one_line(exc)})") from None


def read_contents(f, p: str, basis, *, evaluation_only: bool = False) -> dict:
    """The constructor arguments of the codebook in an open HDF5 file (``p`` names it in errors)."""
    found = survey(f, p)
    version, checked = _format(found, p)
    digests = None
    if checked:
        stored = attr_str(found.attr("", CONTENT_DIGEST))
        if not stored:
            raise CodebookError(f"{p}: corrupt codebook: no {CONTENT_DIGEST} digest of its metadata")
        if stored != metadata_digest(found):
            raise CodebookError(f"{p}: the codebook is corrupted: its metadata does not match its "
                                f"{CONTENT_DIGEST} digest")
        digests = found.array_digests()
    name = attr_str(found.attr("", "name", "codebook"))
    why = problem_name_problem(name)
    if why:
        raise CodebookError(f"{p}: corrupt codebook: problem name {printable_name(name)}: {why}")
    coord_names = _names(found.attr("", "coordinate-order"), "coordinate", MAX_COORDINATES, p)
    unknown_names = _names(found.attr("", "unknown-order"), "unknown", MAX_UNKNOWNS, p)
    coords = [_coordinate(found, c, basis, digests) for c in coord_names]
    declared = 0
    fields = {}
    phased = "phases" in found.attrs
    for u in unknown_names:
        fields[u], size = _field(found, u, coords, digests, phased)
        declared += size
        if declared > limit("codebook_bytes"):
            raise CodebookError(f"{p}: corrupt codebook: its arrays declare more than "
                                f"{limit('codebook_bytes')} bytes (PGD_MAX_CODEBOOK_BYTES)")
    events = read_events(found, coords, lambda value, what, most: _names(value, what, most, p),
                         lambda e, mine, where: _tensor_train(found, e, mine, digests, where=where, what="event"))
    declared += sum(size for _, size in events.values())
    if declared > limit("codebook_bytes"):
        raise CodebookError(f"{p}: corrupt codebook: its arrays declare more than "
                            f"{limit('codebook_bytes')} bytes (PGD_MAX_CODEBOOK_BYTES)")
    phases = read_phases(found, lambda where, shape: read_array(found, where, shape, digests=digests, finite=False),
                         lambda nested, name: read_contents(nested, name, basis, evaluation_only=True))
    spec = ""
    if not evaluation_only and "spec" in found.datasets:
        spec = read_text(found, "spec", digests=digests)
    return dict(
        coordinates=coords, fields=fields, name=name, spec_text=spec,
        report=_report(found, digests, arrays=not evaluation_only),
        description=attr_str(found.attr("", "description", "")),
        created=attr_str(found.attr("", "created", "")) or None,
        partial=evaluation_only, format_version=version, events={e: ev for e, (ev, _) in events.items()},
        **phases,
    )


def _format(found: Survey, p: str) -> tuple[str, bool]:
    """Check the format name and version: the version, and whether the file carries digests (1.1 on)."""
    kind = attr_str(found.attr("", "encoding-type"))
    if kind != FORMAT_NAME:
        raise CodebookError(f"{p}: not a pgdcli codebook (encoding-type {printable_name(kind)}, expected "
                            f"{FORMAT_NAME!r})")
    version = attr_str(found.attr("", "encoding-version"))
    try:
        major, minor = (int(v) for v in version.split("."))
    except ValueError:
        raise CodebookError(f"{p}: unreadable encoding-version {printable_name(version)}") from None
    if major > SUPPORTED_MAJOR:
        raise CodebookError(
            f"{p}: codebook format {version} is newer than this pgdcli supports "
            f"({SUPPORTED_MAJOR}.x); upgrade pgdcli (pip install -U pgdcli)"
        )
    if major < 1:
        raise CodebookError(f"{p}: unsupported codebook format {version}")
    return version, (major, minor) >= (1, 1)


def _names(value, what: str, most: int, p: str) -> list[str]:
    """A list of coordinate or unknown names from an attribute, each a valid, distinct identifier."""
    if value is None:
        raise CodebookError(f"{p}: corrupt codebook: no {what}-order")
    items = [value] if isinstance(value, (str, bytes)) else list(np.asarray(value, dtype=object).reshape(-1))
    if not 1 <= len(items) <= most:
        raise CodebookError(f"{p}: corrupt codebook: {len(items)} {what}s (expected 1 to {most})")
    names = [attr_str(v) for v in items]
    for name in names:
        why = identifier_problem(name)
        if why:
            raise CodebookError(f"{p}: corrupt codebook: {what} name {printable_name(name)}: {why}")
    if len(set(names)) != len(names):
        raise CodebookError(f"{p}: corrupt codebook: a {what} name appears twice")
    return names


def _coordinate(found: Survey, name: str, basis, digests: dict | None) -> CoordinateInfo:
    p = found.source
    where = f"coordinates/{name}"
    if f"{where}/nodes" not in found.datasets:
        raise CodebookError(f"{p}: corrupt codebook: coordinate {name!r} has no nodes")
    domain = _floats(found.attr(where, "domain"), f"coordinate {name!r}: domain", p)
    if len(domain) != 2 or not domain[0] < domain[1]:
        raise CodebookError(f"{p}: corrupt codebook: coordinate {name!r}: domain {domain} is not [low, high] "
                            f"with low < high")
    kind = attr_str(found.attr(where, "discretization"))
    if kind not in KINDS:
        raise CodebookError(f"{p}: coordinate {name!r} has unknown discretization {printable_name(kind)}")
    role = attr_str(found.attr(where, "role", "parameter"))
    if role not in ROLES:
        raise CodebookError(f"{p}: corrupt codebook: coordinate {name!r} has role {printable_name(role)}")
    shape = found.datasets[f"{where}/nodes"][0]
    most = limit("time_nodes") + 1
    if len(shape) != 1 or not 2 <= shape[0] <= most:
        raise CodebookError(f"{p}: corrupt codebook: coordinate {name!r} has nodes of shape {shape} "
                            f"(expected 2 to {most} nodes)")
    breakpoints = _floats(found.attr(where, "breakpoints", ()), f"coordinate {name!r}: breakpoints", p)
    if breakpoints and not (len(breakpoints) <= shape[0] and breakpoints[0] == domain[0]
                            and breakpoints[-1] == domain[1] and np.all(np.diff(breakpoints) > 0)):
        raise CodebookError(f"{p}: corrupt codebook: coordinate {name!r}: breakpoints do not split its domain")
    info = CoordinateInfo(name, domain, shape[0], kind, role, breakpoints)
    try:
        expected = basis(info).nodes
    except (ValueError, ZeroDivisionError) as exc:
        raise CodebookError(f"{p}: corrupt codebook: coordinate {name!r}: {one_line(exc)}") from None
    nodes = read_array(found, f"{where}/nodes", shape, digests=digests)
    if not np.array_equal(expected, nodes):  # built once: the codebook reuses it
        raise CodebookError(f"{p}: stored nodes of coordinate {name!r} do not match its {kind} basis")
    return info


def _floats(value, what: str, p: str) -> tuple:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise CodebookError(f"{p}: corrupt codebook: {what} is not numbers") from None
    if not np.isfinite(arr).all():
        raise CodebookError(f"{p}: corrupt codebook: {what} is not finite")
    return tuple(float(v) for v in arr)


def _field(found: Survey, u: str, coords: list, digests: dict | None, phased: bool = False):
    """One unknown's field, every array's shape checked against the coordinates before it is read."""
    p = found.source
    where = f"unknowns/{u}"
    if where not in found.attrs:
        raise CodebookError(f"{p}: corrupt codebook: no unknown {u!r}")
    names = [c.name for c in coords]
    representation = attr_str(found.attr(where, "representation", "cp"))
    if phased != representation.startswith(PHASED):
        raise CodebookError(f"{p}: corrupt codebook: unknown {u!r}: representation {printable_name(representation)} "
                            f"{'without' if phased else 'with'} the mark of phase 0 of a codebook with phases")
    representation = representation.removeprefix(PHASED)
    if representation == "tensor-train":
        return _tensor_train(found, u, coords, digests)
    if representation != "cp":
        raise CodebookError(f"{p}: unknown {u!r} has representation {printable_name(representation)}, which "
                            f"this pgdcli does not know; upgrade pgdcli (pip install -U pgdcli)")
    rank_shape = found.datasets.get(f"{where}/alphas", ((),))[0]
    if len(rank_shape) != 1:
        raise CodebookError(f"{p}: corrupt codebook: unknown {u!r}: alphas of shape {rank_shape}, expected (rank,)")
    rank = rank_shape[0]
    alphas = read_array(found, f"{where}/alphas", (rank,), digests=digests)
    modes = tuple(read_array(found, f"{where}/modes/{c}", (n.nodes, rank), digests=digests)
                  for c, n in zip(names, coords))
    return cp_field(u, alphas, modes), 8 * rank * (1 + sum(c.nodes for c in coords))


def _tensor_train(found: Survey, u: str, coords: list, digests: dict | None, *, where: str | None = None,
                  what: str = "unknown"):
    p = found.source
    where = where or f"unknowns/{u}"
    names = [c.name for c in coords]
    order = _names(found.attr(where, "mode-order"), f"{what} {u!r}: mode", len(names), p)
    stray = [c for c in order if c not in names]
    if stray:
        raise CodebookError(f"{p}: {what} {u!r}: tensor-train core for unknown coordinate {stray[0]!r}")
    if len(order) != len(names):
        raise CodebookError(f"{p}: corrupt codebook: {what} {u!r}: {len(order)} cores for {len(names)} "
                            f"coordinates")
    shapes, left = [], 1
    for k, c in enumerate(order):
        shape = found.datasets.get(f"{where}/cores/{c}", ((),))[0]
        n = coords[names.index(c)].nodes
        last = k == len(order) - 1
        if len(shape) != 3 or shape[0] != left or shape[1] != n or (last and shape[2] != 1):
            raise CodebookError(f"{p}: corrupt codebook: {what} {u!r}: core {c!r} has shape {shape}, "
                                f"expected ({left}, {n}, {'1' if last else 'r'})")
        shapes.append(shape)
        left = shape[2]
    cores = tuple(read_array(found, f"{where}/cores/{c}", shape, digests=digests) for c, shape in zip(order, shapes))
    return (tt_field(u if what == "unknown" else f"{what} {u}", cores, [names.index(c) for c in order]),
            sum(8 * int(np.prod(s)) for s in shapes))


def _report(found: Survey, digests: dict | None, *, arrays: bool) -> dict:
    """The solver report: its attributes, and its arrays unless only evaluation is wanted."""
    p = found.source
    report = {}
    for key, value in found.attrs.get("report", {}).items():
        if identifier_problem(key):
            raise CodebookError(f"{p}: corrupt codebook: report key {printable_name(key)}")
        report[key] = attr_value(value)
    for where in found.datasets:
        if where.startswith("report/"):
            key = where[len("report/"):]
            if identifier_problem(key):
                raise CodebookError(f"{p}: corrupt codebook: report key {printable_name(key)}")
            if arrays:
                report[key] = read_array(found, where, None, digests=digests, finite=False)
    return report


def printable_name(text) -> str:
    """A name from a file, quoted and shortened, its control characters escaped (for messages)."""
    return repr(printable(text, 60))


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
