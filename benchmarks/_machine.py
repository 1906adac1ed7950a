"""What the benchmark scripts print about the machine they ran on, and where they write their table.

Every script runs its measurements inside :func:`published`: what it prints on stdout (its table
in Markdown) goes to the terminal and, with a header naming the machine, the date and the command,
to ``benchmarks/results/<script>.md``, the file the documentation shows.
"""

from __future__ import annotations

import contextlib
import datetime
import io
import os
import platform
import shlex
import sys
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def machine_facts() -> dict:
    """Processor, CPUs, load average, Python/numpy/scipy versions and the BLAS libraries, as strings."""
    import numpy
    import scipy

    try:
        from threadpoolctl import threadpool_info

        blas = ", ".join(f"{i['internal_api']} {i['version']} ({i['num_threads']} threads)"
                         for i in threadpool_info() if i["user_api"] == "blas")
    except Exception:  # pragma: no cover - threadpoolctl is a dependency
        blas = "?"
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load = " ".join(f"{v:.2f}" for v in os.getloadavg()) if hasattr(os, "getloadavg") else "?"
    return {"processor": _processor(), "cpus": cpus, "load": load,
            "python": platform.python_version(), "numpy": numpy.__version__, "scipy": scipy.__version__,
            "blas": blas}


def _processor() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux), else what :mod:`platform` knows."""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def cell(value) -> str:
    """A Markdown table cell: ``|`` inside a value (``max |error|``) would split the cell."""
    return str(value).replace("|", "\\|")


class _Tee(io.TextIOBase):
    """Writes to the real stdout and keeps a copy."""

    def __init__(self, stream):
        self.stream, self.copy = stream, io.StringIO()

    def write(self, text: str) -> int:
        self.copy.write(text)
        return self.stream.write(text)

    def flush(self) -> None:
        self.stream.flush()


@contextlib.contextmanager
def published(script: str, title: str, variant: str | None = None):
    """Print the benchmark's header and table, and write them to ``benchmarks/results/<script>.md``.

    Parameters
    ----------
    script : str
        The script's ``__file__``; its stem names the results file.
    title : str
        The table's title (a Markdown heading in the file).
    variant : str, optional
        A second table of the same script (an option that measures something else): written to
        ``<script>-<variant>.md``.

    The header gives the date (UTC), the command that made the table and the machine (load
    average at the start and at the end: the machine is shared, so ratios measured in the same
    run are what to compare). The file is written only when the run ends normally.
    """
    started = datetime.datetime.now(datetime.timezone.utc)
    command = "python " + " ".join(shlex.quote(a) for a in [f"benchmarks/{Path(script).name}", *sys.argv[1:]])
    facts = machine_facts()
    tee = _Tee(sys.stdout)
    header = (f"### {title}\n\n"
              f"`{command}`, {started:%Y-%m-%d %H:%M} UTC; {facts['processor']}, {facts['cpus']} CPUs, "
              f"Python {facts['python']}, numpy {facts['numpy']}, scipy {facts['scipy']}, BLAS {facts['blas']}; "
              f"load average at the start {facts['load']}.\n\n")
    tee.write(header)
    with contextlib.redirect_stdout(tee):
        yield
    minutes = (datetime.datetime.now(datetime.timezone.utc) - started).total_seconds() / 60
    tee.write(f"\nWall time {minutes:.1f} min; load average at the end {machine_facts()['load']}.\n")
    tee.flush()
    RESULTS.mkdir(exist_ok=True)
    target = RESULTS / f"{Path(script).stem}{'-' + variant if variant else ''}.md"
    target.write_text(tee.copy.getvalue())
    print(f"table written to {target.relative_to(RESULTS.parents[0])}", file=sys.stderr)


def median_seconds(func, repeats: int) -> float:
    """Median wall time of ``func()`` over ``repeats`` runs, after one warm-up (seconds)."""
    import statistics
    import time

    func()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def markdown_table(rows, header) -> str:
    """Rows (tuples of cells) under a header, as an aligned Markdown table."""
    widths = [max(len(str(r[k])) for r in list(rows) + [header]) for k in range(len(header))]

    def line(r):
        return "| " + " | ".join(str(c).ljust(w) for c, w in zip(r, widths)) + " |"

    return "\n".join([line(header), "|" + "|".join("-" * (w + 2) for w in widths) + "|"] + [line(r) for r in rows])


def report(script: str, table: str, extra: str = "", output=None) -> str:
    """A run's report: when and how it ran (date, command, machine), then the table; printed, and
    written to ``output`` (a path) when given. ``extra``: what else to say of the machine."""
    import datetime
    import sys

    facts = machine_facts()
    text = "\n".join([
        f"Run {datetime.datetime.now().isoformat(timespec='minutes')}: "
        f"`{' '.join(['python', f'benchmarks/{script}'] + sys.argv[1:])}`",
        f"Machine: {facts['processor']}, {facts['cpus']} CPUs (load average {facts['load']}); "
        + (f"{extra}; " if extra else "") + f"Python {facts['python']}, numpy {facts['numpy']}, scipy {facts['scipy']}, "
        f"BLAS {facts['blas']}", "", table, ""])
    print(text)
    if output is not None:
        output.write_text(text)
    return text
