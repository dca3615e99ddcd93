"""The chunk runner: what every executor calls to run one chunk of a sweep.

:class:`ChunkRunner` is built from a :class:`~jaxloco.sweep.job.SweepJob` in the process
that runs chunks: it loads the model, builds the walking controller and makes the physics
backend (whose compiled tick it keeps). :meth:`ChunkRunner.run_chunk` then runs chunk
``index`` of the push table in a job's run directory, starting each push from a snapshot
of the undisturbed walk (loaded from the walks folder, or walked once and kept there), and
writes the chunk's outcomes (:mod:`.store`). The in-process executor and every distributed
worker run a chunk through this one method, so outcomes do not depend on where a chunk
ran. One runner serves every job with the same :meth:`~SweepJob.settings_digest` (e.g. the
rounds of a limit search), whatever its run directory.
"""

from __future__ import annotations

import dataclasses
import functools
import time

import jax
import mujoco
import numpy as np
from tqdm.auto import tqdm

from jaxloco.control.presets import walking_config
from jaxloco.learning.loading import load_planner
from jaxloco.locomotion import make_walking_controller
from jaxloco.locomotion.walking import robot_planner
from jaxloco.robots import robot_by_name
from jaxloco.runtime import enable_compilation_cache
from jaxloco.sim.mjx_loop import physics_model
from jaxloco.sim.push import PushArrays, body_index
from jaxloco.sweep.backends import CBatchBackend, ChunkStarts, MJXBackend
from jaxloco.sweep.job import SweepJob
from jaxloco.sweep.outcome import finalize
from jaxloco.sweep.spec import PushTable
from jaxloco.sweep.starts import (
    STATE_SPEC,
    gather_starts,
    initial_controller_state,
    kept_phases,
    load_snapshots,
    save_snapshots,
    snapshot_walk,
    walk_key,
)
from jaxloco.sweep.store import SweepStore


def chunk_rows(num_pushes: int, chunk_size: int) -> list[np.ndarray]:
    """The row indices of every chunk: ``[0, size), [size, 2 size), ...``."""
    return [np.arange(i, min(i + chunk_size, num_pushes)) for i in range(0, num_pushes, chunk_size)]


@dataclasses.dataclass(frozen=True)
class ChunkReport:
    """What running one chunk gave (its outcomes are on disk)."""

    index: int
    """The chunk's index in the sweep."""
    pushes: int
    """Pushes in the chunk (without the padding)."""
    recovered: int
    """Pushes recovered in the chunk."""
    seconds: float
    """Wall time of the chunk (the first one a runner runs includes the compile)."""
    env_steps: int
    """Simulated ticks of the chunk, padding included."""
    worker: str = "local"
    """Where it ran: ``local`` (this process) or a Dask worker's address."""


@dataclasses.dataclass
class _Sweep:
    """One run directory's push table, as a runner reads it."""

    run_dir: str
    """The run directory."""
    store: SweepStore
    """Its store of chunk outcomes."""
    table: PushTable
    """Its push table."""
    chunks: list[np.ndarray]
    """Row indices of each chunk's pushes."""


def load_sweep(job: SweepJob) -> _Sweep:
    """The push table and chunks of ``job``'s run directory (as the store holds them)."""
    store = SweepStore(job.run_dir, writer=jax.process_index() == 0)
    table = store.load_table()
    return _Sweep(job.run_dir, store, table, chunk_rows(len(table), job.chunk_size))


def walks_needed(sweep: _Sweep, row_groups) -> dict[tuple, set]:
    """The undisturbed walks the rows start from: ``{(speed, turn, replan): phases}``,
    each with every phase the whole table asks of it (so that one walk serves every
    chunk)."""
    table = sweep.table
    keys = [
        walk_key(table["apex_speed"][r], table["turn_deg"][r], table["replan"][r])
        for r in range(len(table))
    ]
    wanted = sorted({keys[r] for rows in row_groups for r in rows})
    return {
        key: set(np.unique(table["phase"][[k == key for k in keys]]).tolist()) for key in wanted
    }


def _in_job_precision(method):
    """Run ``method`` with JAX's float64 switched as the runner's job says, for this call
    only (a context, not a process-wide change: the caller's setting stands outside)."""

    @functools.wraps(method)
    def wrapped(self, *args, **kwargs):
        with jax.enable_x64(self.x64):
            return method(self, *args, **kwargs)

    return wrapped


class ChunkRunner:
    """Runs chunks of sweeps with ``job``'s settings in this process (see the module doc).

    Every method computes in the job's precision (``job.x64``), whatever the process's
    own setting. ``make_backend``: False prepares walks only."""

    def __init__(self, job: SweepJob, make_backend: bool = True):
        self.x64 = bool(job.x64)
        with jax.enable_x64(self.x64):
            self._init(job, make_backend)

    def _init(self, job: SweepJob, make_backend: bool) -> None:
        if job.cache_dir:
            enable_compilation_cache(job.cache_dir)
        self.job = job
        self.robot = robot_by_name(job.robot)
        self.model = self.robot.load()
        self.sim_model = physics_model(self.model, job.physics)
        body = body_index(self.model, job.push_body)
        self.ctrl = make_walking_controller(
            self.model,
            config=job.wblc or walking_config(self.robot),
            gait=job.gait,
            planner=robot_planner(
                self.robot, self.model, load_planner(job.planner) if job.planner else None
            ),
            robot=self.robot,
        )
        self.horizon_steps = int(round(job.horizon / self.model.opt.timestep))
        self.snapshots: dict = {}
        self._sweep: _Sweep | None = None
        self.warm = False
        """Whether :meth:`warm_up` ran (a worker compiles once)."""
        self._step = None  # the jitted single-robot step the walks use, compiled once
        self.backend = None
        if make_backend and job.backend == "c":
            self.backend = CBatchBackend(
                self.sim_model, self.ctrl, body, job.fall_height, job.nthread
            )
        elif make_backend:
            self.backend = MJXBackend(
                self.sim_model, self.ctrl, body, job.fall_height, self.horizon_steps
            )

    @_in_job_precision
    def sweep(self, job: SweepJob) -> _Sweep:
        """The push table and chunks of ``job``'s run directory."""
        if job.settings_digest() != self.job.settings_digest():
            raise ValueError("ChunkRunner: a job with other settings needs its own runner")
        if self._sweep is None or self._sweep.run_dir != job.run_dir:
            self._sweep = load_sweep(job)
        return self._sweep

    @_in_job_precision
    def prepare_walks(self, job: SweepJob, chunks, progress: bool = False) -> float:
        """Load or walk the undisturbed walks that ``chunks`` of ``job`` start from;
        returns the seconds it took."""
        t0 = time.perf_counter()
        sweep = self.sweep(job)
        needed = walks_needed(sweep, [sweep.chunks[i] for i in chunks])
        for key, phases in tqdm(needed.items(), "undisturbed walks", disable=not progress):
            self.walk(job, key, phases)
        return time.perf_counter() - t0

    @_in_job_precision
    def walk(self, job: SweepJob, key: tuple, phases: set) -> float:
        """Have the undisturbed walk ``key`` (speed, turn, replan) snapshotted at
        ``phases`` at hand: held already, or kept in the walks folder, or walked now (at
        every phase it is asked for and was kept at) and kept there, so that no process
        walks it twice (a walk does not depend on which phases it stops at). Returns the
        seconds it took."""
        t0 = time.perf_counter()
        have = self.snapshots.get(key)
        if have is not None and phases <= set(have.phases.tolist()):
            return 0.0
        path = job.walk_path(key)
        kept = kept_phases(path)
        if kept and phases <= kept:
            template = initial_controller_state(self.ctrl, self.sim_model, *key)
            self.snapshots[key] = load_snapshots(path, template)
            return time.perf_counter() - t0
        if self._step is None:
            self._step = jax.jit(self.ctrl.step)
        self.snapshots[key] = snapshot_walk(
            self.sim_model, self.ctrl, self._step, *key, job.push_step, sorted(phases | kept),
            job.fall_height,
        )  # fmt: skip
        if jax.process_index() == 0:
            save_snapshots(path, self.snapshots[key])
        return time.perf_counter() - t0

    @_in_job_precision
    def starts(self, job: SweepJob, index: int) -> ChunkStarts:
        """The start states of chunk ``index`` of ``job``, padded to ``chunk_size`` with
        its last push."""
        sweep = self.sweep(job)
        rows = sweep.chunks[index]
        for key, phases in walks_needed(sweep, [rows]).items():
            self.walk(job, key, phases)
        table, model = sweep.table, self.model
        padded = np.concatenate([rows, np.full(job.chunk_size - len(rows), rows[-1])])
        times, phys, cstate = gather_starts(
            table, padded, self.snapshots, job.qvel_noise, model.nq, model.nv
        )
        heading = np.asarray(cstate.gait.heading, float)
        pushes = PushArrays(
            magnitude=table["magnitude"][padded],
            direction=heading + np.radians(table["direction_deg"][padded]),
            start=times,
            duration=table["duration"][padded],
        )
        return ChunkStarts(times, phys, cstate, pushes)

    @_in_job_precision
    def run_chunk(self, job: SweepJob, index: int, tick_progress=None) -> ChunkReport:
        """Run chunk ``index`` of ``job`` and write its outcomes to its run directory."""
        t0 = time.perf_counter()
        sweep = self.sweep(job)
        rows = sweep.chunks[index]
        outcome = self.backend.run(self.starts(job, index), self.horizon_steps, tick_progress)
        cols = finalize(outcome, job.steps_after)
        cols = {k: v[: len(rows)] for k, v in cols.items()}
        sweep.store.write_chunk(index, rows, cols)
        return ChunkReport(
            index=index,
            pushes=len(rows),
            recovered=int(cols["recovered"].sum()),
            seconds=time.perf_counter() - t0,
            env_steps=job.chunk_size * self.horizon_steps,
        )

    @_in_job_precision
    def warm_up(self) -> float:
        """Compile the backend's chunk program now, before any walk exists: one tick of
        ``chunk_size`` robots standing at the walking keyframe (the shapes and dtypes of
        every chunk), results discarded. Returns the seconds it took."""
        t0 = time.perf_counter()
        n, model = self.job.chunk_size, self.sim_model
        data = mujoco.MjData(model)
        data.qpos[:] = self.robot.keyframe_qpos(model)
        mujoco.mj_forward(model, data)
        state = np.zeros(mujoco.mj_stateSize(model, STATE_SPEC))
        mujoco.mj_getState(model, data, state, STATE_SPEC)
        cstate = initial_controller_state(self.ctrl, model, 1.0, 0.0, True)
        starts = ChunkStarts(
            times=np.zeros(n),
            physics=np.tile(state, (n, 1)),
            controller=jax.tree.map(lambda x: np.repeat(np.asarray(x)[None], n, axis=0), cstate),
            pushes=PushArrays.none((n,)),
        )
        steps = 1 if self.job.backend == "c" else self.horizon_steps
        self.backend.run(starts, steps)
        self.warm = True
        return time.perf_counter() - t0
