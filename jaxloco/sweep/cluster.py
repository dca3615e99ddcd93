"""Running a sweep's chunks as tasks on a Dask distributed cluster.

Why Dask distributed: it is pure Python and pip-installable with no service of its own to
run, the same code drives a ``LocalCluster`` of worker processes on one machine and a
cluster given by its scheduler's address, its workers are restarted by their nanny when
they die and their tasks retried elsewhere, and ``dask-jobqueue`` starts workers on SLURM,
PBS or SGE when a cluster has a batch scheduler.

Each chunk is one task (:func:`run_chunk_task`). A worker builds one runner per set of
settings and keeps it between tasks and sweeps (:class:`SweepWorkerPlugin`); the driver
walks the undisturbed walks and compiles the chunk program into the persistent cache
first (:func:`run_on_dask`), then each chunk task loads the walks it needs and writes the
chunk's file itself, so the driver only waits. If a worker dies, its task runs
again on another; if the driver dies, running the same command again resumes from the
chunk files. On one machine :func:`local_cluster` starts one single-threaded worker
process per core, each pinned to its core (the batched tick keeps one core busy, so
pinned processes do the most work); on a cluster, give the scheduler's address and a run
directory every worker can read and write (a shared file system).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
import time
from collections.abc import Sequence

import dask
from distributed import Client, LocalCluster, as_completed, get_worker
from distributed.diagnostics.plugin import WorkerPlugin

from jaxloco.sweep.chunks import ChunkReport, ChunkRunner
from jaxloco.sweep.executors import available_cores, pin_process, progress_bar, run_record
from jaxloco.sweep.job import SweepJob

PLUGIN_NAME = "jaxloco-sweep"


class SweepWorkerPlugin(WorkerPlugin):
    """Holds this worker's prepared :class:`ChunkRunner` (keyed by
    :meth:`SweepJob.settings_digest`: the rounds of a limit search share it). ``cores``: pin
    the worker named ``k`` to ``cores[k % len(cores)]`` (a local cluster); None: leave the
    worker as it is."""

    def __init__(self, cores: Sequence[int] | None = None):
        self.cores = None if cores is None else list(cores)
        self.runners: dict[str, ChunkRunner] = {}

    def setup(self, worker) -> None:
        if self.cores:
            pin_process(self.cores[int(worker.name) % len(self.cores)])

    def teardown(self, worker) -> None:
        self.runners.clear()

    def runner(self, job: SweepJob) -> ChunkRunner:
        key = job.settings_digest()
        if key not in self.runners:
            self.runners.clear()  # one controller at a time: free the last one's programs
            self.runners[key] = ChunkRunner(job.replace(nthread=1))
        return self.runners[key]


def _runner(job: SweepJob) -> ChunkRunner:
    plugin = get_worker().plugins.get(PLUGIN_NAME)
    if plugin is None:  # not registered on this worker: run without keeping the runner
        plugin = SweepWorkerPlugin()
    return plugin.runner(job)


def run_chunk_task(job: SweepJob, index: int) -> ChunkReport:
    """The task of chunk ``index``: run it on this worker's runner and write it."""
    job = job.replace(nthread=1)
    report = _runner(job).run_chunk(job, index)
    return dataclasses.replace(report, worker=str(get_worker().address))


WORKER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
}
"""Dask settings of the local workers: no statistical profiler (nothing reads its samples,
and its sampling thread shares the worker's one core with the chunk), and glibc's own
malloc trimming instead of Dask's fixed threshold, which also turns off glibc's adaptive
mmap threshold: the chunk's per-tick loop allocates many short-lived buffers
(``docs/sweep.md``)."""


WORKER_PRELOAD = "jaxloco.runtime"
"""The module a worker process imports as it starts (its ``dask_setup``): MJX without the
lines about a GPU backend jaxloco does not use."""


def local_cluster(workers: int) -> LocalCluster:
    """A ``LocalCluster`` of ``workers`` single-threaded worker processes (no dashboard,
    :data:`WORKER_CONFIG`, :data:`WORKER_PRELOAD`)."""
    with dask.config.set(WORKER_CONFIG):  # the nannies hand it to their workers
        return LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            memory_limit=0,  # compiled programs, not data, fill a worker
            preload=[WORKER_PRELOAD],
        )


@contextlib.contextmanager
def quiet_dask_logs():
    """Dask's INFO lines (workers registered, streams opened and closed at shutdown) hidden
    while it lasts; its warnings and errors still show. A level a user chose (e.g. DEBUG by
    ``hydra.verbose=distributed``) is kept."""
    logger = logging.getLogger("distributed")
    level = logger.level
    if level in (logging.NOTSET, logging.INFO):
        logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(level)


@contextlib.contextmanager
def dask_client(address: str | None = None, workers: int = 2):
    """A Dask client with the sweep plugin registered: of the cluster whose scheduler is at
    ``address`` (e.g. ``tcp://head:8786``), or of a local cluster of ``workers`` processes,
    one pinned per core (closed on exit)."""
    with contextlib.ExitStack() as stack:
        stack.enter_context(quiet_dask_logs())
        if address:
            client = stack.enter_context(Client(address))
            cores = None
        else:
            cluster = stack.enter_context(local_cluster(workers))
            client = stack.enter_context(Client(cluster))
            cores = available_cores()
        client.register_plugin(SweepWorkerPlugin(cores), name=PLUGIN_NAME)
        yield client


def run_on_dask(
    job: SweepJob,
    todo: Sequence[int],
    client,
    progress: bool = True,
    driver: ChunkRunner | None = None,
) -> dict:
    """Run the chunks ``todo`` of ``job`` as tasks on ``client``'s cluster
    (:func:`dask_client`). Returns the run's record for the manifest.

    First this process (``driver``: a runner of it to reuse) walks the undisturbed walks
    the chunks start from, into the walks folder, and, with a persistent compile cache,
    compiles the chunk program into it: XLA compiles faster unpinned than on a worker's
    one core, and every worker then loads the program instead of compiling it."""
    t_start = time.perf_counter()
    # The cluster as the run found it: read later, a worker lost and being restarted by its
    # nanny was missing from the count.
    n_workers = len(client.scheduler_info()["workers"])
    driver = driver or ChunkRunner(job, make_backend=bool(job.cache_dir))
    walks_s = driver.prepare_walks(job, todo, progress)
    if job.cache_dir and driver.backend is not None and not driver.warm:
        driver.warm_up()  # into the persistent cache, for every worker to load
    t_tasks = time.perf_counter()
    tag = hashlib.sha256(job.run_dir.encode()).hexdigest()[:8]
    futures = [
        client.submit(run_chunk_task, job, i, key=f"chunk-{tag}-{i:05d}", pure=False) for i in todo
    ]
    reports = []
    label = f"push sweep ({job.backend}, {n_workers} Dask workers)"
    with progress_bar(driver.sweep(job), todo, label, progress) as bar:
        for future in as_completed(futures):
            report = future.result()
            reports.append(report)
            steps = sum(r.env_steps for r in reports)
            bar.advance(report, steps / (time.perf_counter() - t_tasks))
    extra = {"executor": "dask", "workers": n_workers}
    return run_record(todo, reports, walks_s, time.perf_counter() - t_start, extra)
