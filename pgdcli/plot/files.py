"""Image files: default names, atomic writes (PNG/SVG), and :func:`render`, what ``pgd plot`` does."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable, Iterable

from ..codebook.codebook import Codebook
from ..codebook.phases import refuse_phases
from ..errors import PgdError, QueryError
from .draw import draw_convergence, draw_error, draw_modes, draw_solution
from .modes import convergence_data, modes_data
from .options import (DEFAULT_COUNT, DEFAULT_DPI, DEFAULT_KIND, FORMATS, KINDS, parse_point, parse_size,
                      require_matplotlib)
from .phase import draw_phase, phase_data
from .sobol import draw_sensitivity, sensitivity_data
from .solution import error_data, reference_solver, solution_data

__all__ = ["default_output", "save_figure", "render"]


# ----------------------------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------------------------
def default_output(codebook_path: str | os.PathLike, kind: str) -> Path:
    """``<directory of the codebook>/<codebook stem>-<kind>.png``."""
    p = Path(codebook_path)
    return p.with_name(f"{p.stem}-{kind}.png")


def _format(path: Path) -> str:
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise PgdError(f"--output {path}: unsupported file type {path.suffix or '(no suffix)'!r}; "
                       f"expected a .png or .svg file")
    return fmt


def save_figure(fig, path: str | os.PathLike, *, dpi: int = DEFAULT_DPI) -> Path:
    """Write ``fig`` as PNG or SVG (by the suffix of ``path``), atomically; returns the path.

    The image is ``figsize * dpi`` pixels (PNG) or ``figsize * 72`` points (SVG);
    no tight bounding box, so the size is exactly the figure's.
    """
    import matplotlib

    path = Path(path)
    fmt = _format(path)
    if path.is_dir():
        raise PgdError(f"--output {path}: is a directory, expected a .png or .svg file name")
    if not path.parent.is_dir():
        raise PgdError(f"--output {path}: directory {str(path.parent)!r} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    # reproducible files: no timestamps, fixed SVG ids
    metadata = {"Date": None} if fmt == "svg" else {"Software": None}
    try:
        with matplotlib.rc_context({"svg.hashsalt": "pgdcli", "svg.fonttype": "path"}):
            fig.savefig(tmp, format=fmt, dpi=dpi, metadata=metadata)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; an image gets the usual permissions
        os.replace(tmp, path)
    except OSError as exc:
        _unlink(tmp)
        raise PgdError(f"--output {path}: cannot write ({exc.strerror or exc})") from None
    except BaseException:
        _unlink(tmp)
        raise
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _unlink(p: str) -> None:
    try:
        os.unlink(p)
    except FileNotFoundError:
        pass


_APPLIES = {
    "modes": {"--count", "--points", "--field"},
    "convergence": set(),
    "solution": {"--at", "--over", "--fix", "--reference", "--points", "--field"},
    "error": {"--at", "--over", "--fix", "--points", "--field"},
    "phase": {"--at", "--reference", "--points", "--x", "--y"},
    "sensitivity": {"--at", "--points", "--field", "--density"},
}


def render(codebook_path: str | os.PathLike, kind: str = DEFAULT_KIND, output: str | os.PathLike | None = None, *,
           field: str | None = None, count: int | None = None, at: Iterable[str] | None = None,
           over: str | None = None, fix: Iterable[str] | None = None, reference: bool = False,
           points: int | None = None, dpi: int = DEFAULT_DPI, size: str | tuple[float, float] | None = None,
           warn: Callable[[str], None] | None = None, max_seconds: float | None = None, x: str | None = None,
           y: str | None = None, densities: dict | None = None) -> Path:
    """What ``pgd plot`` does: load the codebook, compute, draw and save; returns the written path.

    Options that do not apply to ``kind`` raise :class:`QueryError` (naming
    the option) rather than being ignored. ``warn`` receives reference
    failures (one line each). The reference integrations stop after ``max_seconds``
    (:class:`~pgdcli.errors.TimeBudgetExceeded`; nothing is written). ``x``, ``y``: the unknowns
    of a phase portrait; ``densities``: the inputs' densities of a sensitivity plot
    (``{"k": "normal:2,0.3"}``).
    """
    require_matplotlib("pgd plot")
    if kind not in KINDS:
        raise QueryError(f"--kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    target = Path(output) if output is not None else default_output(codebook_path, kind)
    _format(target)  # before any work
    if int(dpi) != dpi or not 10 <= dpi <= 1200:
        raise QueryError(f"--dpi: expected an integer between 10 and 1200, got {dpi}")
    figsize = parse_size(size) if isinstance(size, str) else (tuple(size) if size is not None else None)
    at = list(at or [])
    fix = list(fix or [])
    given = {"--count": count is not None, "--at": bool(at), "--over": over is not None, "--fix": bool(fix),
             "--reference": bool(reference), "--points": points is not None, "--field": field is not None,
             "--x": x is not None, "--y": y is not None, "--density": bool(densities)}
    for opt, present in given.items():
        if present and opt not in _APPLIES[kind]:
            applies = [k for k, a in _APPLIES.items() if opt in a]
            note = " (error plots always compare with the reference)" if opt == "--reference" else ""
            raise QueryError(f"{opt} does not apply to --kind {kind}; it is for --kind {' and '.join(applies)}{note}")
    cb = Codebook.load(codebook_path)
    refuse_phases(cb, "pgd plot")
    if kind == "modes":
        data = modes_data(cb, DEFAULT_COUNT if count is None else count, field, points=points)
        fig = draw_modes(data, figsize=figsize)
    elif kind == "convergence":
        data = convergence_data(cb)
        fig = draw_convergence(data, figsize=figsize)
    elif kind == "solution":
        ref = reference_solver(cb, source=str(codebook_path), max_seconds=max_seconds) if reference else False
        data = solution_data(cb, field, at=at, over=over, fix=fix, points=points, reference=ref)
        fig = draw_solution(data, figsize=figsize)
    elif kind == "error":
        ref = reference_solver(cb, source=str(codebook_path), max_seconds=max_seconds)
        data = error_data(cb, field, at=at, over=over, fix=fix, points=points, reference=ref)
        fig = draw_error(data, figsize=figsize)
    elif kind == "phase":
        ref = reference_solver(cb, source=str(codebook_path), max_seconds=max_seconds) if reference else False
        data = phase_data(cb, x, y, at=at, points=points, reference=ref)
        fig = draw_phase(data, figsize=figsize)
    else:
        fixed = {}
        for text in at:  # one point: the coordinates held fixed
            for name, value in parse_point(text, cb, "--at").items():
                if name in fixed:
                    raise QueryError(f"--at: coordinate {name!r} given twice")
                fixed[name] = value
        data = sensitivity_data(cb, field, at=fixed, points=points, densities=densities)
        fig = draw_sensitivity(data, figsize=figsize)
    if warn is not None:
        for message in data.get("failures", []):
            warn(message)
    return save_figure(fig, target, dpi=dpi)
