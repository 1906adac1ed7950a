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
- **intact** (format 1.1): every array carries HDF5's Fletcher-32 checksum, the root lists a
  SHA-256 of every array's contents (:data:`ARRAY_DIGESTS`) and holds a SHA-256 of all
  metadata, that list included (:data:`CONTENT_DIGEST`); a mismatch is "the codebook is
  corrupted", naming the dataset.

:func:`survey` walks the file once and keeps every attribute, so the reader and the digest use
the same values and HDF5 is asked for each only once. numpy, h5py and the standard library only
(the query path).
"""

from __future__ import annotations

import hashlib
import json
import os
import stat

import numpy as np

from ..errors import CodebookError
from ..limits import limit

__all__ = ["Survey", "open_codebook", "survey", "read_array", "read_text", "array_digest", "metadata_digest",
           "ARRAY_DIGESTS", "CONTENT_DIGEST", "MAX_ATTRIBUTE_BYTES", "MAX_OBJECTS"]

#: Root attributes: the arrays' SHA-256 (JSON, path -> hex), and the SHA-256 of all metadata.
ARRAY_DIGESTS = "array-sha256"
CONTENT_DIGEST = "content-sha256"
#: Largest attribute read (bytes declared), attributes per object, objects per file, depth.
MAX_ATTRIBUTE_BYTES = 4 * 2**20
MAX_ATTRIBUTES = 1000
MAX_OBJECTS = 100_000
MAX_DEPTH = 8


class Survey:
    """A file's objects after :func:`survey` accepted them.

    Attributes
    ----------
    source : str
        The file's name in messages.
    datasets : dict
        Path -> (shape, dtype) of every dataset.
    attrs : dict
        Path (``""`` for the root) -> {attribute name: value} of every object.
    objects : dict
        Path -> the h5py object.
    """

    def __init__(self, source: str) -> None:
        self.source = source
        self.datasets: dict[str, tuple[tuple[int, ...], np.dtype]] = {}
        self.attrs: dict[str, dict] = {}
        self.objects: dict = {}

    def attr(self, path: str, name: str, default=None):
        """Attribute ``name`` of the object at ``path`` (``default`` when absent)."""
        return self.attrs.get(path, {}).get(name, default)

    def array_digests(self) -> dict[str, str]:
        """The root's list of array digests (path -> hex), checked to be a JSON object of strings."""
        text = self.attr("", ARRAY_DIGESTS)
        try:
            digests = json.loads(text.decode() if isinstance(text, bytes) else str(text))
        except (ValueError, UnicodeDecodeError):
            digests = None
        if not isinstance(digests, dict) or not all(isinstance(v, str) for v in digests.values()):
            raise _corrupt(self.source, f"no readable {ARRAY_DIGESTS} list of array digests")
        return digests


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


def survey(f, source: str) -> Survey:
    """Walk every link and object of an open file once; refuse what is not self-contained and bounded.

    Raises
    ------
    CodebookError
        "corrupt codebook: ..." naming the object: a soft or external link, external storage, a
        virtual dataset, an unknown filter, an array whose declared bytes are not stored in the
        file, an attribute too large, too many objects or attributes, or nesting too deep.
    """
    import h5py

    out = Survey(source)
    names = _link_names(f, source)
    seen: set = set()
    out.attrs[""] = _attributes(f, "/", source)
    out.objects[""] = f
    for where in names:
        obj = f[where]
        if obj.id in seen:
            raise _corrupt(source, f"{where!r} names an object already seen (a second hard link or a loop)")
        seen.add(obj.id)
        out.objects[where] = obj
        out.attrs[where] = _attributes(obj, where, source)
        if isinstance(obj, h5py.Dataset):
            out.datasets[where] = _check_dataset(obj, where, source)
        elif not isinstance(obj, h5py.Group):
            raise _corrupt(source, f"{where!r} is a {type(obj).__name__}, not a group or dataset")
    return out


def _link_names(f, source: str) -> list[str]:
    """Every link's path, each checked to be a hard link, in HDF5's own (C) walk of the file."""
    from h5py import h5l

    names: list[str] = []
    problem: list[str] = []

    def visit(name: bytes, info):
        try:
            text = name.decode()
        except UnicodeDecodeError:
            problem.append(f"a link name {name[:40]!r} is not UTF-8")
            return True
        if info.type != h5l.TYPE_HARD:
            kind = "an external link" if info.type == h5l.TYPE_EXTERNAL else "a soft link"
            problem.append(f"{text!r} is {kind}; a codebook holds only its own objects")
        elif len(names) >= MAX_OBJECTS:
            problem.append(f"more than {MAX_OBJECTS} objects")
        elif text.count("/") >= MAX_DEPTH:
            problem.append(f"{text!r} is nested deeper than a codebook's layout")
        else:
            names.append(text)
            return None
        return True  # stop the walk

    try:
        f.id.links.visit(visit, info=True)
    except (OSError, RuntimeError, ValueError, KeyError) as exc:
        raise _corrupt(source, f"its links cannot be read ({_one_line(exc)})") from None
    if problem:
        raise _corrupt(source, problem[0])
    return names


def _attributes(obj, where: str, source: str) -> dict:
    """All attributes of ``obj``, each read only after its declared size is checked."""
    try:
        count = obj.id.get_num_attrs() if hasattr(obj.id, "get_num_attrs") else len(obj.attrs)
        if count > MAX_ATTRIBUTES:
            raise _corrupt(source, f"{where!r} has {count} attributes (at most {MAX_ATTRIBUTES})")
        if not count:
            return {}
        values = {}
        for name in obj.attrs:
            size = int(obj.attrs.get_id(name).get_storage_size())
            if size > MAX_ATTRIBUTE_BYTES:
                raise _corrupt(source, f"attribute {name!r} of {where!r} declares {size} bytes "
                                       f"(at most {MAX_ATTRIBUTE_BYTES})")
            values[str(name)] = obj.attrs[name]
        return values
    except CodebookError:
        raise
    except (OSError, RuntimeError, ValueError, TypeError, KeyError, UnicodeDecodeError) as exc:
        raise CodebookError(f"{source}: the codebook is corrupted: the attributes of {where!r} cannot be read "
                            f"({_one_line(exc)})") from None


def _check_dataset(ds, where: str, source: str) -> tuple[tuple[int, ...], np.dtype]:
    """Storage of one dataset: in the file, unfiltered or checksummed, as large as it declares."""
    from h5py import h5d, h5z

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
    unknown = [fid for fid in filters if fid not in (h5z.FILTER_FLETCHER32, h5z.FILTER_SHUFFLE)]
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
    return shape, dtype


def read_array(survey_: Survey, where: str, shape: tuple[int, ...] | None = None, *,
               digests: dict | None = None, finite: bool = True) -> np.ndarray:
    """Dataset ``where`` after checking its declared shape (``None``: any); float64 when ``finite``.

    With ``digests`` (format 1.1) its SHA-256 must be the listed one. A Fletcher-32 failure or a
    digest mismatch is "the codebook is corrupted"; with ``finite`` so is a NaN or infinity.
    """
    source = survey_.source
    if where not in survey_.datasets:
        raise _corrupt(source, f"missing dataset {where!r}")
    found, dtype = survey_.datasets[where]
    if shape is not None and found != tuple(shape):
        raise _corrupt(source, f"dataset {where!r} has shape {found}, expected {tuple(shape)}")
    if dtype.kind not in "fiu":
        raise _corrupt(source, f"dataset {where!r} has type {dtype}, expected numbers")
    raw = _read(survey_, where)
    if digests is not None:
        _check_digest(digests, raw, where, source)
    if not finite:
        return np.asarray(raw)
    values = np.asarray(raw, dtype=float)
    if not np.isfinite(values).all():
        raise _corrupt(source, f"dataset {where!r} holds non-finite numbers")
    return values


def read_text(survey_: Survey, where: str, *, digests: dict | None = None, limit_bytes: int = 2**20) -> str:
    """A scalar string dataset (the stored spec), at most ``limit_bytes`` long."""
    source = survey_.source
    raw = _read(survey_, where)
    if not isinstance(raw, (bytes, str)):
        raise _corrupt(source, f"dataset {where!r} is not text")
    if len(raw) > limit_bytes:
        raise _corrupt(source, f"dataset {where!r} holds {len(raw)} bytes of text (at most {limit_bytes})")
    if digests is not None:
        _check_digest(digests, raw, where, source)
    try:
        return raw.decode() if isinstance(raw, bytes) else str(raw)
    except UnicodeDecodeError:
        raise _corrupt(source, f"dataset {where!r} is not UTF-8 text") from None


def _read(survey_: Survey, where: str):
    try:
        return survey_.objects[where][()]
    except (OSError, RuntimeError, ValueError, TypeError) as exc:
        raise CodebookError(f"{survey_.source}: the codebook is corrupted: dataset {where!r} cannot be read "
                            f"({_one_line(exc)})") from None


def _check_digest(digests: dict, raw, where: str, source: str) -> None:
    if digests.get(where) != array_digest(raw):
        raise CodebookError(f"{source}: the codebook is corrupted: dataset {where!r} does not match its digest")


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


def metadata_digest(survey_: Survey) -> str:
    """SHA-256 (hex) of the file's structure and every attribute but the root's own digest."""
    h = hashlib.sha256()
    h.update(json.dumps(sorted(survey_.objects)).encode())
    for where in sorted(survey_.attrs):
        for name in sorted(survey_.attrs[where]):
            if where == "" and name == CONTENT_DIGEST:
                continue
            h.update(f"\n{where}@{name}=".encode())
            h.update(_canonical(survey_.attrs[where][name]))
    return h.hexdigest()


def _corrupt(source: str, what: str) -> CodebookError:
    return CodebookError(f"{source}: corrupt codebook: {what}")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:200] or type(exc).__name__
