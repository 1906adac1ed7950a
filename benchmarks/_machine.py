"""What the benchmark scripts print about the machine they ran on (shared by them)."""

from __future__ import annotations

import os
import platform


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
    return {"processor": platform.processor() or platform.machine(), "cpus": cpus, "load": load,
            "python": platform.python_version(), "numpy": numpy.__version__, "scipy": scipy.__version__,
            "blas": blas}


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
