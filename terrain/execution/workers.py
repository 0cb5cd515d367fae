"""What every Dask worker of a chunked run gets, those that join or restart later included.

Kept apart from :mod:`terrain.execution.chunked` so that importing that module does not
import ``distributed`` (a client made by :func:`~terrain.execution.chunked.dask_client` does).
"""

from __future__ import annotations

from distributed.diagnostics.plugin import WorkerPlugin

__all__ = ["PrepareWorker"]


class PrepareWorker(WorkerPlugin):
    """Run :func:`terrain.execution.chunked.prepare_worker` on every worker, now and later.

    Registered by :func:`~terrain.execution.chunked.dask_client`: the scheduler hands it to
    each worker that connects, so a worker its nanny restarts (one killed half way through a
    run) is prepared like the first ones.

    Parameters
    ----------
    keep_freed : bool
        Passed on to ``prepare_worker`` (the local cluster's workers only).
    """

    name = "craterscape-prepare-worker"

    def __init__(self, keep_freed: bool = False):
        self.keep_freed = keep_freed

    def setup(self, worker) -> None:
        """Prepare the worker's process (its imports, and its allocator if asked)."""
        from terrain.execution.chunked import prepare_worker

        prepare_worker(self.keep_freed)
