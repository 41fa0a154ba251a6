"""A Dask cluster to run on, and the executor core.tiling hands its jobs to.

``--workers N`` starts a ``LocalCluster`` of N worker processes (one thread
each: the NumPy post holds the GIL between its vector operations) listening on
127.0.0.1 only; ``--scheduler tcp://HOST:PORT`` connects to a running
scheduler (``dask scheduler`` on the farm host, ``dask worker tcp://HOST:PORT``
on each machine, every one with ``cvsss[farm]`` installed, the pass and
output folders at the same paths, and ``DASK_CONFIG`` pointing at
``farm/dask``, see :data:`LOCAL_CONFIG`).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator
from typing import Any

FARM_HINT = "install the farm extra: pip install 'cvsss[farm]' (Dask distributed, openjd-cli)"


class FarmError(Exception):
    """A cluster cannot be had (missing extra, unreachable scheduler)."""


def _distributed():
    try:
        import distributed
    except ImportError:
        raise FarmError(f"--workers and --scheduler need Dask distributed: {FARM_HINT}") from None
    return distributed


class DaskExecutor:
    """core.tiling's Executor on a Dask ``Client``.

    Jobs are submitted impure (each is run, never deduplicated by hashing its
    arrays); scattered values are sent to the workers directly. Work is *lost*
    when a worker dies holding a scattered value or a result whose inputs are
    gone: the tiled processor then submits the frame again (tasks are pure).
    Tasks a dead worker was running are re-run by the scheduler itself.
    """

    def __init__(self, client) -> None:
        distributed = _distributed()
        from distributed.client import FutureCancelledError

        self.client = client
        self.lost: tuple[type[BaseException], ...] = (
            FutureCancelledError,
            distributed.comm.CommClosedError,
        )
        with contextlib.suppress(ImportError):
            from distributed.client import FutureLostError  # newer releases

            self.lost += (FutureLostError,)

    def submit(self, fn: Callable, *args: Any):
        return self.client.submit(fn, *args, pure=False)

    def scatter(self, value: Any):
        # A list of one, so a dict value is not scattered item by item.
        return self.client.scatter([value], hash=False)[0]

    def gather(self, handles: list) -> list:
        return self.client.gather(handles)

    def as_completed(self, handles: list):
        """The handles in the order they finish."""
        from distributed import as_completed

        return as_completed(handles)

    @property
    def workers(self) -> int:
        return len(self.client.scheduler_info(n_workers=-1)["workers"])


@contextlib.contextmanager
def open_cluster(
    workers: int | None = None,
    scheduler: str | None = None,
    *,
    log: Callable[[str], None] | None = None,
    timeout: float = 30.0,
) -> Iterator[DaskExecutor]:
    """A :class:`DaskExecutor` on a local cluster of ``workers`` processes, or on
    the scheduler at ``scheduler``; the local cluster is shut down on exit.

    Raises
    ------
    FarmError
        Dask is not installed, or the scheduler cannot be reached in ``timeout`` s.
    """
    if (workers is None) == (scheduler is None):
        raise ValueError("give workers or scheduler, not both")
    distributed = _distributed()
    # Worker restarts and lost connections are part of the fault handling; say
    # them through our own messages, not Dask's tracebacks.
    for name in ("distributed", "distributed.nanny", "distributed.scheduler"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    if scheduler is not None:
        try:
            client = distributed.Client(scheduler, timeout=timeout)
        except (OSError, TimeoutError) as exc:
            raise FarmError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
        try:
            if log:
                n = len(client.scheduler_info(n_workers=-1)["workers"])
                log(f"connected to {scheduler} ({n} worker(s))")
            yield DaskExecutor(client)
        finally:
            client.close()
        return
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    import dask

    with dask.config.set(LOCAL_CONFIG):
        cluster = _local_cluster(distributed, workers)
    try:
        client = distributed.Client(cluster)
        try:
            if log:
                log(f"local cluster: {workers} worker process(es) on {cluster.scheduler_address}")
            yield DaskExecutor(client)
        finally:
            client.close()
    finally:
        cluster.close()


#: Dask settings of the local cluster (farm/dask/cvsss.yaml says the same for farm hosts),
#: the environment each worker process starts with (a variable already set in the
#: environment wins: Dask's rule):
#:
#: - ``MALLOC_TRIM_THRESHOLD_``: Dask's default 65536 fixes glibc's mmap threshold at
#:   128 KiB, so each large NumPy temporary is a fresh mmap with page faults (measured
#:   2-3x slower per tile); None leaves glibc's adaptive default.
#: - ``OMP_WAIT_POLICY=PASSIVE``: numba's parallel kernels run on OpenMP threads, which
#:   by default spin for a while after each parallel loop; with two worker processes
#:   on two cores each one's spinning threads took the other's cores: CPU per tile
#:   96 → 44-47 ms with two workers, 50 → 36-38 ms with one (the bench's ``workers``
#:   section; README, *Render farms and clusters*). A single process (``cvsss post``
#:   without workers) keeps OpenMP's default: it has nothing to take cores from, and
#:   its frames were no faster asleep.
LOCAL_CONFIG = {
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    "distributed.nanny.pre-spawn-environ.OMP_WAIT_POLICY": "PASSIVE",
}


def _local_cluster(distributed, workers: int):
    return distributed.LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        # No dashboard, but the scheduler still serves HTTP (health routes); by default on
        # port 8787, with a warning on stderr when another Dask holds it: any free port.
        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
        silence_logs=logging.CRITICAL,
        memory_limit=0,
    )
