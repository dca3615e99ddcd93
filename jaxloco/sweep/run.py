"""Run a push sweep: expand the spec, snapshot the undisturbed walks, run chunk by chunk.

Several devices: the MJX backend shards each chunk across ``jax.devices()``. Several
hosts: call ``jax.distributed.initialize(...)`` on every host before :func:`run_sweep` and
run the same command on each (with a shared run directory): ``jax.devices()`` then spans
the hosts, every process builds the same chunk (the start states are deterministic) and
hands it to the global sharding, and only process 0 writes results. Tested here with two
virtual CPU devices in one process (``tests/test_sweep.py``); not run on several hosts.

:func:`run_sweep` is what ``jaxloco push-sweep`` calls. Each chunk of ``chunk_size`` pushes
is one batched backend call (the last chunk is padded with copies of its last push, so every
call has the same shape and compiles once); its outcomes are written as soon as it is done
(:mod:`.store`), and a second call on the same directory resumes. The C backend's chunks
can run as tasks on Dask distributed: a local cluster of one process per core, or a
cluster given by its address (:mod:`.cluster`).
"""

from __future__ import annotations

import dataclasses
import math
import platform
from pathlib import Path

import jax
import numpy as np

from jaxloco.control.presets import walking_config
from jaxloco.control.wblc import WBLCConfig
from jaxloco.locomotion import GaitParams
from jaxloco.robots import DEFAULT_ROBOT, robot_by_name
from jaxloco.sim.mjx_loop import PhysicsParams
from jaxloco.sweep.chunks import ChunkRunner, chunk_rows
from jaxloco.sweep.executors import available_cores, run_in_process
from jaxloco.sweep.job import BACKENDS, SweepJob
from jaxloco.sweep.spec import PushTable, SweepSpec, expand
from jaxloco.sweep.store import SweepStore, table_digest


@dataclasses.dataclass
class SweepResult:
    table: PushTable
    """The sweep's pushes, one row each."""
    outcomes: dict
    """Outcome columns (:data:`jaxloco.sweep.outcome.FIELDS`), one entry per push."""
    complete: np.ndarray
    """Rows that have results."""
    manifest: dict
    """The run directory's manifest: settings, runs, rates."""
    run_dir: Path
    """The run directory."""


def run_sweep(
    spec: SweepSpec,
    run_dir,
    backend: str = "c",
    chunk_size: int = 16,
    gait: GaitParams | None = None,
    physics: PhysicsParams | None = None,
    wblc: WBLCConfig | None = None,
    push_body: str | None = None,
    nthread: int | None = None,
    config: dict | None = None,
    progress: bool = True,
    max_chunks: int | None = None,
    workers: int = 1,
    address: str | None = None,
    planner: str | None = None,
    robot: str = DEFAULT_ROBOT.name,
) -> SweepResult:
    """Run (or resume) the sweep ``spec`` into ``run_dir``.

    ``backend``: ``"c"`` (MuJoCo C batch + vmapped JAX controller) or ``"mjx"``.
    ``config``: the resolved experiment config, recorded in the manifest.
    ``max_chunks``: stop after this many new chunks (to split a long sweep into several runs).
    ``physics``: the simulated robot's solver settings and torque limit (default
    :class:`PhysicsParams`).
    ``wblc``: the controller's WBLC configuration (default: the walking preset).
    ``workers``/``address``: where the chunks run (:func:`run_table`).
    ``planner``: the step policy's checkpoint folder (None: the shipped default).
    ``robot``: the shipped robot pushed (:data:`jaxloco.robots.ROBOTS`); ``gait`` is its own
    (e.g. :func:`~jaxloco.locomotion.walking.robot_gait`), ``push_body`` None: its base.
    """
    job = make_job(
        spec, run_dir, backend, chunk_size, gait, physics, wblc, push_body, nthread, robot
    )
    job = job.replace(planner=None if planner is None else str(planner))
    manifest = {"spec_digest": spec.digest(), "spec": dataclasses.asdict(spec)}
    return run_table(expand(spec), job, config, progress, max_chunks, workers, address, manifest)


def make_job(
    spec: SweepSpec,
    run_dir,
    backend: str = "c",
    chunk_size: int = 16,
    gait: GaitParams | None = None,
    physics: PhysicsParams | None = None,
    wblc: WBLCConfig | None = None,
    push_body: str | None = None,
    nthread: int | None = None,
    robot: str = DEFAULT_ROBOT.name,
) -> SweepJob:
    """The :class:`SweepJob` of running ``spec``'s pushes on ``robot`` into ``run_dir``
    (MJX: the chunk size rounded up to a multiple of the devices). Defaults: the reference
    gait numbers, the paper's physics, the robot's walking WBLC, pushes on its base."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}; got {backend!r}")
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1; got {chunk_size}")
    description = robot_by_name(robot)
    devices = jax.devices()
    if backend == "mjx" and chunk_size % len(devices):
        chunk_size = len(devices) * math.ceil(chunk_size / len(devices))
    return SweepJob.of(
        spec,
        run_dir,
        backend=backend,
        chunk_size=chunk_size,
        gait=GaitParams() if gait is None else gait,
        physics=PhysicsParams() if physics is None else physics,
        wblc=wblc or walking_config(description),  # what make_walking_controller uses too
        push_body=description.base_body if push_body is None else push_body,
        robot=robot,
        x64=bool(jax.config.jax_enable_x64),
        cache_dir=jax.config.jax_compilation_cache_dir or None,
        nthread=nthread or None,
    )


def run_table(
    table: PushTable,
    job: SweepJob,
    config: dict | None = None,
    progress: bool = True,
    max_chunks: int | None = None,
    workers: int = 1,
    address: str | None = None,
    manifest: dict | None = None,
    client=None,
    runner: ChunkRunner | None = None,
) -> SweepResult:
    """Run (or resume) the pushes of ``table`` as ``job`` says, into ``job.run_dir``.

    Where the chunks run: ``address`` (a Dask scheduler's, e.g. ``tcp://head:8786``): as
    tasks on that cluster (:mod:`.cluster`); else ``workers`` > 1: on a local Dask cluster
    of that many processes, one pinned per core (C backend only); 1: in this process; 0:
    one worker per core when each gets enough work to pay for its start
    (:func:`_auto_workers`), else in this process. The outcomes are the same wherever
    the chunks run. ``manifest``: more entries for the run directory's manifest.
    ``client``/``runner``: a Dask client (:func:`~jaxloco.sweep.cluster.dask_client`) and a
    runner of this process to reuse across calls (``workers``/``address`` then unused).
    """
    if workers < 0:
        raise ValueError(f"workers must be >= 0 (0: one per core); got {workers}")
    auto_workers = workers == 0
    if (workers > 1 or address) and job.backend != "c":
        raise ValueError(
            f"workers > 1 and address run the C backend on Dask workers; got backend="
            f"{job.backend!r} (MJX shards a chunk across JAX devices instead)"
        )
    if (workers > 1 or address) and jax.process_count() > 1:
        raise ValueError("workers and address are for one JAX process; a multi-host MJX run "
                         "uses jax.distributed")  # fmt: skip
    store = SweepStore(job.run_dir, writer=jax.process_index() == 0)
    chunks = chunk_rows(len(table), job.chunk_size)
    store.open(
        {
            **(manifest or {}),
            "table_digest": table_digest(table),
            "num_pushes": len(table),
            "settings": job.outcome_settings(),
            "config": config,
            "chunk_size": job.chunk_size,
            "num_chunks": len(chunks),
            "devices": [str(d) for d in jax.devices()],
            "host": platform.node(),
            "runs": [],
        },
        table,
    )
    todo = [i for i, rows in enumerate(chunks) if not store.done(i, rows)]
    if max_chunks is not None:
        todo = todo[:max_chunks]
    if auto_workers:
        workers = _auto_workers(job.backend, sum(len(chunks[i]) for i in todo) * job.horizon)
    if todo and client is not None:
        # Dask's import is heavy: only a sweep on workers pays for it.
        from jaxloco.sweep.cluster import run_on_dask  # noqa: PLC0415

        record = run_on_dask(job, todo, client, progress, runner)
    elif todo and (address or min(workers, len(todo)) > 1):
        from jaxloco.sweep.cluster import dask_client, run_on_dask  # noqa: PLC0415

        with dask_client(address, min(workers, len(todo))) as client:
            record = run_on_dask(job, todo, client, progress, runner)
    elif todo:
        record = run_in_process(job, todo, progress, runner)
    if todo:
        if store.writer:
            manifest = store.read_manifest()
            manifest["runs"].append(record)
            store.write_manifest(manifest)
    table, outcomes, have = store.load_results()
    return SweepResult(table, outcomes, have, store.read_manifest(), store.dir)


# A worker process takes ~10-15 s to start (imports, controller, walks from disk, the tick
# from the compile cache), so small sweeps run in one process (docs/sweep.md).
_ROBOT_SECONDS_PER_WORKER = 50.0


def _auto_workers(backend: str, robot_seconds: float) -> int:
    """Workers for ``workers=0``: one per core, but at most one per 50 simulated
    robot-seconds of remaining work; always 1 on MJX."""
    if backend != "c":
        return 1
    return max(1, min(len(available_cores()), int(robot_seconds // _ROBOT_SECONDS_PER_WORKER)))
