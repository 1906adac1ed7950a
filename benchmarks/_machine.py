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
