"""What a codebook file must be before anything in it is read: self-contained, bounded, intact.

Codebooks travel between machines and people, so a file is treated as untrusted input:

- **self-contained**: every link is a hard link inside the file; no external link, soft link,
  external storage (raw bytes of another file, a FIFO, a device), virtual dataset or filter other
  than those pgdcli writes. A file breaking this is refused before any of its data is read, so
  HDF5 never opens another file or a plugin on its behalf;
- **bounded**: the file's size is at most ``PGD_MAX_CODEBOOK_BYTES``; an array is read only
  when its declared size is stored in the file (no fill values or decompression that expand a
  small file into gigabytes) and its shape is the one the codebook's metadata implies; an
  attribute is read only when it declares at most :data:`MAX_ATTRIBUTE_BYTES`;
- **intact** (format 1.1): every array carries HDF5's Fletcher-32 checksum and a SHA-256 of its
  contents, and the root carries a SHA-256 of all metadata (every attribute, the arrays' digests
  included); a mismatch is "the codebook is corrupted", naming the dataset.

numpy, h5py and the standard library only (the query path).
"""

from __future__ import annotations

import hashlib
import os
import stat

import numpy as np

from ..errors import CodebookError
from ..limits import limit

__all__ = ["Survey", "open_codebook", "survey", "read_array", "read_attribute", "array_digest",
           "metadata_digest", "DIGEST_ATTRIBUTE", "CONTENT_DIGEST", "MAX_ATTRIBUTE_BYTES", "MAX_OBJECTS"]

#: Attribute holding a dataset's SHA-256 (hex), and the root's digest of all metadata.
DIGEST_ATTRIBUTE = "sha256"
CONTENT_DIGEST = "content-sha256"
#: Largest attribute read (bytes declared), attributes per object, objects per file, depth.
MAX_ATTRIBUTE_BYTES = 2**20
MAX_ATTRIBUTES = 1000
MAX_OBJECTS = 100_000
MAX_DEPTH = 8
#: Filters pgdcli writes (Fletcher-32) or older h5py defaults may add (shuffle); nothing else is read.
_ALLOWED_FILTERS = None  # set on first use: h5py is imported lazily


class Survey:
    """The datasets of a file: path -> (shape, dtype, checked), after :func:`survey` accepted it."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.datasets: dict[str, tuple[tuple[int, ...], np.dtype, bool]] = {}


def open_codebook(path: str):
    """Open ``path`` for reading after checking it is a regular file within the size limit.

    A FIFO or a device would block or never end; they are refused by their type, not opened.
    """
    import h5py

    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise CodebookError(f"{path}: no such file") from None
    except OSError as exc:
        raise CodebookError(f"{path}: cannot read the codebook ({exc.strerror or exc})") from None
    if stat.S_ISDIR(info.st_mode):
        raise CodebookError(f"{path}: is a directory, expected a codebook file (.h5)")
    if not stat.S_ISREG(info.st_mode):
        raise CodebookError(f"{path}: not a regular file (a pipe, socket or device), expected a codebook file")
    cap = limit("codebook_bytes")
    if info.st_size > cap:
        raise CodebookError(f"{path}: the file has {info.st_size} bytes, over the limit of {cap} "
                            f"(PGD_MAX_CODEBOOK_BYTES)")
    try:
        return h5py.File(path, "r", locking=False)
    except OSError:
        raise CodebookError(f"{path}: not a readable HDF5 file (truncated or not a codebook)") from None


def _allowed_filters() -> frozenset:
    global _ALLOWED_FILTERS
    if _ALLOWED_FILTERS is None:
        from h5py import h5z

        _ALLOWED_FILTERS = frozenset({h5z.FILTER_FLETCHER32, h5z.FILTER_SHUFFLE})
    return _ALLOWED_FILTERS


def survey(f, source: str) -> Survey:
    """Walk every link and object of an open file; refuse what is not self-contained and bounded.

    Raises
    ------
    CodebookError
        "corrupt codebook: ..." naming the object: a soft or external link, external storage, a
        virtual dataset, an unknown filter, an array whose declared bytes are not stored in the
        file, too many objects or attributes, or nesting deeper than a codebook has.
    """
    import h5py

    out = Survey(source)
    seen: set = set()
    pending = [(f, "", 0)]
    count = 0
    while pending:
        group, prefix, depth = pending.pop()
        _check_attributes(group, prefix or "/", source)
        for name in _member_names(group, prefix, source):
            where = f"{prefix}/{name}" if prefix else name
            link = group.get(name, getlink=True)
            if not isinstance(link, h5py.HardLink):
                kind = "an external link" if isinstance(link, h5py.ExternalLink) else "a soft link"
                raise _corrupt(source, f"{where!r} is {kind}; a codebook holds only its own objects")
            count += 1
            if count > MAX_OBJECTS:
                raise _corrupt(source, f"more than {MAX_OBJECTS} objects")
            obj = group[name]
            key = obj.id
            if key in seen:
                raise _corrupt(source, f"{where!r} links back to an object already seen (a link loop)")
            seen.add(key)
            if isinstance(obj, h5py.Group):
                if depth + 1 > MAX_DEPTH:
                    raise _corrupt(source, f"{where!r} is nested deeper than a codebook's layout")
                pending.append((obj, where, depth + 1))
            elif isinstance(obj, h5py.Dataset):
                out.datasets[where] = _check_dataset(obj, where, source)
            else:
                raise _corrupt(source, f"{where!r} is a {type(obj).__name__}, not a group or dataset")
    return out


def _member_names(group, prefix: str, source: str) -> list[str]:
    try:
        names = list(group.keys())
    except (OSError, RuntimeError, ValueError, KeyError) as exc:
        raise _corrupt(source, f"group {prefix or '/'!r} cannot be listed ({_one_line(exc)})") from None
    return names


def _check_attributes(obj, where: str, source: str) -> None:
    count = obj.id.get_num_attrs() if hasattr(obj.id, "get_num_attrs") else len(obj.attrs)
    if count > MAX_ATTRIBUTES:
        raise _corrupt(source, f"{where!r} has {count} attributes (at most {MAX_ATTRIBUTES})")


def _check_dataset(ds, where: str, source: str) -> tuple[tuple[int, ...], np.dtype, bool]:
    """Storage of one dataset: in the file, unfiltered or checksummed, as large as it declares."""
    from h5py import h5d

    try:
        dcpl = ds.id.get_create_plist()
        layout = dcpl.get_layout()
        external = dcpl.get_external_count()
        filters = [dcpl.get_filter(i)[0] for i in range(dcpl.get_nfilters())]
        shape, dtype = tuple(int(n) for n in (ds.shape or ())), ds.dtype
        stored = int(ds.id.get_storage_size())
    except (OSError, RuntimeError, ValueError, TypeError) as exc:
        raise _corrupt(source, f"dataset {where!r} cannot be inspected ({_one_line(exc)})") from None
    if layout == getattr(h5d, "VIRTUAL", -1):
        raise _corrupt(source, f"dataset {where!r} is a virtual dataset (its data would come from other files)")
    if external:
        raise _corrupt(source, f"dataset {where!r} keeps its data in another file (external storage)")
    unknown = [fid for fid in filters if fid not in _allowed_filters()]
    if unknown:
        raise _corrupt(source, f"dataset {where!r} uses HDF5 filter {unknown[0]}, which pgdcli does not write")
    if dtype.kind not in "fiub" and not (dtype.kind == "O" and shape == ()):
        raise _corrupt(source, f"dataset {where!r} has type {dtype}, expected numbers")
    declared = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize if dtype.kind != "O" else 0
    cap = limit("codebook_bytes")
    if declared > cap:
        raise _corrupt(source, f"dataset {where!r} declares {declared} bytes, over the limit of {cap} "
                               f"(PGD_MAX_CODEBOOK_BYTES)")
    if declared and stored < declared:
        raise _corrupt(source, f"dataset {where!r} declares {declared} bytes but stores {stored}")
    return shape, dtype, bool(filters)


def read_array(f, survey_: Survey, where: str, shape: tuple[int, ...] | None = None, *,
               checked: bool = False, finite: bool = True) -> np.ndarray:
    """Dataset ``where`` after checking its declared shape (``None``: any); float64 when ``finite``.

    With ``checked`` its SHA-256 attribute must match its contents. A Fletcher-32 failure or
    a digest mismatch is "the codebook is corrupted"; with ``finite`` so is a NaN or infinity.
    """
    source = survey_.source
    if where not in survey_.datasets:
        raise _corrupt(source, f"missing dataset {where!r}")
    found, dtype, _ = survey_.datasets[where]
    if shape is not None and found != tuple(shape):
        raise _corrupt(source, f"dataset {where!r} has shape {found}, expected {tuple(shape)}")
    if dtype.kind not in "fiu":
        raise _corrupt(source, f"dataset {where!r} has type {dtype}, expected numbers")
    ds = f[where]
    try:
        raw = ds[()]
    except (OSError, RuntimeError, ValueError) as exc:
        raise CodebookError(f"{source}: the codebook is corrupted: dataset {where!r} cannot be read "
                            f"({_one_line(exc)})") from None
    if checked:
        _check_digest(ds, raw, where, source)
    if not finite:
        return np.asarray(raw)
    values = np.asarray(raw, dtype=float)
    if not np.isfinite(values).all():
        raise _corrupt(source, f"dataset {where!r} holds non-finite numbers")
    return values


def read_text(f, survey_: Survey, where: str, *, checked: bool = False, limit_bytes: int = 2**20) -> str:
    """A scalar string dataset (the stored spec), at most ``limit_bytes`` long."""
    source = survey_.source
    found, dtype, _ = survey_.datasets[where]
    ds = f[where]
    try:
        raw = ds[()]
    except (OSError, RuntimeError, ValueError) as exc:
        raise CodebookError(f"{source}: the codebook is corrupted: dataset {where!r} cannot be read "
                            f"({_one_line(exc)})") from None
    if isinstance(raw, np.ndarray) and raw.dtype.kind in "iu" and raw.ndim == 1:
        raw = raw.astype(np.uint8).tobytes()
    if not isinstance(raw, (bytes, str)):
        raise _corrupt(source, f"dataset {where!r} is not text")
    if len(raw) > limit_bytes:
        raise _corrupt(source, f"dataset {where!r} holds {len(raw)} bytes of text (at most {limit_bytes})")
    if checked:
        _check_digest(ds, raw, where, source)
    try:
        return raw.decode() if isinstance(raw, bytes) else str(raw)
    except UnicodeDecodeError:
        raise _corrupt(source, f"dataset {where!r} is not UTF-8 text") from None


def read_attribute(obj, name: str, source: str, default=None):
    """Attribute ``name`` of ``obj`` (``default`` when absent), its declared size checked first."""
    try:
        if name not in obj.attrs:
            return default
        aid = obj.attrs.get_id(name)
        size = int(aid.get_storage_size())
        if size > MAX_ATTRIBUTE_BYTES:
            raise _corrupt(source, f"attribute {name!r} declares {size} bytes (at most {MAX_ATTRIBUTE_BYTES})")
        return obj.attrs[name]
    except CodebookError:
        raise
    except (OSError, RuntimeError, ValueError, TypeError, KeyError) as exc:
        raise CodebookError(f"{source}: the codebook is corrupted: attribute {name!r} cannot be read "
                            f"({_one_line(exc)})") from None


def attribute_names(obj, source: str) -> list[str]:
    """The attribute names of ``obj`` (bounded by :func:`survey`), each checked to be readable text."""
    try:
        return [str(n) for n in obj.attrs.keys()]
    except (OSError, RuntimeError, ValueError, UnicodeDecodeError) as exc:
        raise CodebookError(f"{source}: the codebook is corrupted: attributes cannot be listed "
                            f"({_one_line(exc)})") from None


def _check_digest(ds, raw, where: str, source: str) -> None:
    stored = read_attribute(ds, DIGEST_ATTRIBUTE, source)
    if isinstance(stored, bytes):
        stored = stored.decode("ascii", "replace")
    if stored is None:
        raise _corrupt(source, f"dataset {where!r} has no {DIGEST_ATTRIBUTE} digest")
    if str(stored) != array_digest(raw):
        raise CodebookError(f"{source}: the codebook is corrupted: dataset {where!r} does not match its "
                            f"{DIGEST_ATTRIBUTE} digest")


def array_digest(value) -> str:
    """SHA-256 (hex) of a dataset's value: its type, shape and bytes (text: its UTF-8 bytes)."""
    h = hashlib.sha256()
    if isinstance(value, (bytes, str)):
        h.update(b"text:")
        h.update(value.encode() if isinstance(value, str) else value)
        return h.hexdigest()
    arr = np.asarray(value)
    little = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
    h.update(f"{little.dtype.str}:{arr.shape}:".encode())
    h.update(np.ascontiguousarray(little).tobytes())
    return h.hexdigest()


def _canonical(value) -> bytes:
    """Bytes of an attribute value that do not depend on how h5py returns it (str or bytes, scalar or 0-d)."""
    if isinstance(value, (bytes, str)):
        return b"s" + (value.encode() if isinstance(value, str) else value)
    arr = np.asarray(value)
    if arr.dtype.kind in "OSU":
        return b"l" + b"\0".join(_canonical(v) for v in arr.reshape(-1).tolist())
    little = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
    return f"{little.dtype.str}:{arr.shape}:".encode() + np.ascontiguousarray(little).tobytes()


def metadata_digest(f, source: str) -> str:
    """SHA-256 (hex) of every attribute in the file but the root's own digest, in path order."""
    import h5py

    h = hashlib.sha256()
    pending = [("", f)]
    while pending:
        where, obj = pending.pop()
        for name in sorted(attribute_names(obj, source)):
            if where == "" and name == CONTENT_DIGEST:
                continue
            h.update(f"{where}@{name}=".encode())
            h.update(_canonical(read_attribute(obj, name, source)))
            h.update(b"\n")
        if isinstance(obj, h5py.Group):
            h.update(f"{where}:{sorted(obj.keys())}\n".encode())
            pending.extend((f"{where}/{n}", obj[n]) for n in sorted(obj.keys(), reverse=True))
    return h.hexdigest()


def _corrupt(source: str, what: str) -> CodebookError:
    return CodebookError(f"{source}: corrupt codebook: {what}")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:200] or type(exc).__name__
