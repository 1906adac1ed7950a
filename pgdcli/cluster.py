"""Opening a Dask cluster: a scheduler at an address, or a ``LocalCluster`` on this machine.

Imported only when a cluster is asked for (``--scheduler``, ``--workers``, ``PGD_SCHEDULER``), so that
nothing else pays for Dask. :func:`connect` returns a :class:`pgdcli.executors.DaskExecutor`; a
scheduler that cannot be reached, that has no workers, or whose workers lack this version of
pgdcli is one :class:`~pgdcli.errors.ClusterError` before any work.
"""

from __future__ import annotations

import logging

import pgdcli  # its __version__ read at call time (a test may stand in another)
from .errors import ClusterError
from .dask_executor import DaskExecutor

__all__ = ["connect", "local_cluster", "CONNECT_TIMEOUT"]

#: Seconds to reach a scheduler, and to wait for its first worker.
CONNECT_TIMEOUT = 10.0


def connect(address: str | None = None, workers: int | None = None, *, option: str = "--scheduler",
            timeout: float | None = None) -> DaskExecutor:
    """A :class:`DaskExecutor` on the scheduler at ``address``, or on a new ``LocalCluster`` of
    ``workers`` processes (one thread each).

    Parameters
    ----------
    address : str, optional
        ``tcp://host:port`` (or ``host:port``) of a running ``dask scheduler``.
    workers : int, optional
        Worker processes of a local cluster (when no address is given).
    option : str
        How the user named the address, for messages (``--scheduler``, ``PGD_SCHEDULER``).
    timeout : float, optional
        Seconds to reach the scheduler and to wait for a worker (default :data:`CONNECT_TIMEOUT`).

    Raises
    ------
    ClusterError
        distributed is not installed; the scheduler cannot be reached, has no worker, or its workers
        lack this version of pgdcli.
    """
    timeout = CONNECT_TIMEOUT if timeout is None else timeout
    try:
        from distributed import Client
    except ImportError:
        raise ClusterError(f"{option}: a Dask cluster needs the optional package distributed: "
                           f"pip install 'pgdcli[dask]'") from None
    if address is None:
        if workers is None or int(workers) < 1:
            raise ClusterError(f"--workers: expected a number of worker processes >= 1, got {workers!r}")
        try:
            cluster = local_cluster(int(workers))
        except Exception as exc:  # noqa: BLE001 - the machine refused: ports, processes
            raise ClusterError(f"--workers {workers}: cannot start a local Dask cluster "
                               f"({' '.join(str(exc).split()) or type(exc).__name__})") from None
        client = Client(cluster)
        return DaskExecutor(client, cluster=cluster)
    try:
        client = Client(address, timeout=timeout)
    except Exception as exc:  # noqa: BLE001 - unreachable, refused, malformed: one line
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise ClusterError(f"{option} {address}: cannot reach a Dask scheduler there ({reason})") from None
    executor = DaskExecutor(client, owns_client=True)
    try:
        _check_workers(client, address, option, timeout)
    except BaseException:
        executor.close()
        raise
    executor.refresh()
    return executor


def local_cluster(workers: int):
    """A ``distributed.LocalCluster`` of ``workers`` processes (one thread each, logs silenced) that
    keeps its workers after one dies, and closes cleanly then.

    Each worker runs under a nanny that starts it again when it dies (killed, out of memory). The
    cluster object of distributed closes the nanny of a worker that is not back within
    ``distributed.deploy.lost-worker-timeout`` (15 s), which a loaded machine exceeds: the cluster
    would shrink for good. It can also miss the arrival of a worker its nanny started in place of a
    killed one (the scheduler's "add" message lost in the restart), and then fail on the departure of
    that worker when it closes (a ``KeyError`` out of ``close()``, the cluster left half closed). A
    departure here only forgets the worker: its nanny stays, and one never seen to arrive is ignored.
    """
    from distributed import LocalCluster

    class _LocalCluster(LocalCluster):
        def _update_worker_status(self, op, msg):
            if op == "remove":
                self.scheduler_info.get("workers", {}).pop(msg, None)
                return
            super()._update_worker_status(op, msg)

    return _LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                         silence_logs=logging.CRITICAL)


def _check_workers(client, address: str, option: str, timeout: float) -> None:
    """At least one worker, and every worker runs this version of pgdcli."""
    try:
        client.wait_for_workers(1, timeout=timeout)
    except Exception:  # noqa: BLE001 - a timeout, in whichever class this version raises it
        raise ClusterError(f"{option} {address}: the scheduler has no workers (start some with "
                           f"'dask worker {address}')") from None
    found = client.run(_worker_version, on_error="return")  # by reference: fails where pgdcli is missing
    for worker, value in found.items():
        if isinstance(value, BaseException):
            raise ClusterError(f"{option} {address}: the worker {worker} cannot import pgdcli (install it where "
                               f"the workers run: pip install 'pgdcli[dask]')")
        if value != pgdcli.__version__:
            raise ClusterError(f"{option} {address}: the worker {worker} runs pgdcli {value}, this is "
                               f"{pgdcli.__version__} (install the same version on the workers)")


def _worker_version() -> str:
    """pgdcli's version where this runs."""
    return pgdcli.__version__
