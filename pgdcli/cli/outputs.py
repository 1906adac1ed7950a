"""Output paths checked before any work (``pgd solve -o``, ``pgd plot -o``).

The rule, the same for every command that writes a file: the path must not be
a directory or a special file (device, FIFO, socket); its directory is created
if missing (as ``mkdir -p``), and must accept a new file, which is tried at
once with a probe file (created and removed). So a solve of several minutes
is not lost to a typo in ``-o``, and ``-o /proc/x.png`` is one line, not a
traceback after the plot was drawn.
"""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

from ..errors import PgdError

__all__ = ["prepare_output"]


def _reason(exc: OSError) -> str:
    return exc.strerror or " ".join(str(exc).split())


def prepare_output(path: str | os.PathLike, option: str = "--output", suffixes: tuple[str, ...] = ()) -> Path:
    """Check that ``path`` can be written, creating its directory; return it as a Path.

    Parameters
    ----------
    path : path-like
        The file to be written later (atomically, by a temporary file and a rename).
    option : str
        Named in messages (``--output x.h5: ...``).
    suffixes : tuple of str, optional
        Allowed suffixes (lower case, with the dot); empty: any.

    Raises
    ------
    PgdError
        One line naming the path and what is wrong with it.
    """
    path = Path(path)
    if suffixes and path.suffix.lower() not in suffixes:
        raise PgdError(f"{option} {path}: unsupported file type {path.suffix or '(no suffix)'!r}; expected "
                       f"{' or '.join(suffixes)}")
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:  # e.g. a path through a regular file: ENOTDIR
        raise PgdError(f"{option} {path}: cannot write there ({_reason(exc)})") from None
    if mode is not None and stat.S_ISDIR(mode):
        raise PgdError(f"{option} {path}: is a directory, expected a file name")
    if mode is not None and not stat.S_ISREG(mode):
        raise PgdError(f"{option} {path}: not a regular file (a device, FIFO or socket); expected a file name")
    directory = path.parent
    try:
        directory.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".probe", dir=directory)
    except OSError as exc:
        raise PgdError(f"{option} {path}: cannot write in directory {str(directory)!r} ({_reason(exc)})") from None
    os.close(fd)
    os.unlink(probe)
    return path
