"""Run a push sweep: expand the spec, snapshot the undisturbed walks, run chunk by chunk.

Several devices: the MJX backend shards each chunk across ``jax.devices()``. Several
hosts: call ``jax.distributed.initialize(...)`` on every host before :func:`run_sweep` and
run the same command on each (with a shared run directory): ``jax.devices()`` then spans
the hosts, every process builds the same chunk (the start states are deterministic) and
hands it to the global sharding, and only process 0 writes results. Tested here with two
virtual CPU devices in one process (``tests/test_sweep.py``); not run on several hosts.

:func:`run_sweep` is what ``jaxloco push-sweep`` calls. Each chunk of ``chunk_size`` pushes
is one batched backend call (the last chunk is padded with copies of its last push, so every
call has the same shape and compiles once); its outcomes are written before the next chunk
starts (:mod:`.store`), and a second call on the same directory resumes. On one host the C
backend can run chunks in several processes, one per core (``workers``, :mod:`.workers`).
"""

from __future__ import annotations

import dataclasses
import math
import platform
import time
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxloco.control.presets import walking_config
from jaxloco.control.wblc import WBLCConfig
from jaxloco.dynamics.model import load_valkyrie
from jaxloco.locomotion import GaitParams, make_walking_controller
from jaxloco.sim.mjx_loop import PhysicsParams, physics_model
from jaxloco.sim.push import PushArrays, body_index
from jaxloco.sweep.backends import CBatchBackend, ChunkStarts, MJXBackend
from jaxloco.sweep.outcome import finalize
from jaxloco.sweep.spec import PushTable, SweepSpec, expand
from jaxloco.sweep.starts import (
    gather_starts,
    initial_controller_state,
    load_snapshots,
    save_snapshots,
    snapshot_walk,
    walk_key,
)
from jaxloco.sweep.store import SweepStore
from jaxloco.sweep.workers import available_cores, run_in_workers

BACKENDS = ("c", "mjx")


@dataclasses.dataclass
class SweepResult:
    table: PushTable
    outcomes: dict
    """Outcome columns (:data:`jaxloco.sweep.outcome.FIELDS`), one entry per push."""
    complete: np.ndarray
    """Rows that have results."""
    manifest: dict
    run_dir: Path


def _chunks(n: int, size: int) -> list[np.ndarray]:
    return [np.arange(i, min(i + size, n)) for i in range(0, n, size)]


def run_sweep(
    spec: SweepSpec,
    run_dir,
    backend: str = "c",
    chunk_size: int = 16,
    gait: GaitParams | None = None,
    physics: PhysicsParams | None = None,
    wblc: WBLCConfig | None = None,
    push_body: str = "pelvis",
    nthread: int | None = None,
    config: dict | None = None,
    progress: bool = True,
    max_chunks: int | None = None,
    workers: int = 1,
) -> SweepResult:
    """Run (or resume) the sweep ``spec`` into ``run_dir``.

    ``backend``: ``"c"`` (MuJoCo C batch + vmapped JAX controller) or ``"mjx"``.
    ``config``: the resolved experiment config, recorded in the manifest.
    ``max_chunks``: stop after this many new chunks (to split a long sweep into several runs).
    ``physics``: the simulated robot's solver settings and torque limit (default
    :class:`PhysicsParams`).
    ``wblc``: the controller's WBLC configuration (default: the walking preset).
    ``workers``: processes running chunks side by side, each pinned to its own core (C
    backend only; see :mod:`.workers`); 0 chooses: one per available core when each gets
    enough work to pay for its start (:func:`_auto_workers`), else 1. The results are the
    same for any number of workers.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}; got {backend!r}")
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1; got {chunk_size}")
    if workers < 0:
        raise ValueError(f"workers must be >= 0 (0: one per core); got {workers}")
    auto_workers = workers == 0
    if workers > 1 and backend != "c":
        raise ValueError(
            f"workers > 1 runs the C backend in several processes; got backend={backend!r} "
            "(MJX shards a chunk across JAX devices instead)"
        )
    if workers > 1 and jax.process_count() > 1:
        raise ValueError("workers > 1 is for one host; a multi-host run uses jax.distributed")
    gait = GaitParams() if gait is None else gait
    physics = PhysicsParams() if physics is None else physics
    devices = jax.devices()
    if backend == "mjx" and chunk_size % len(devices):
        chunk_size = len(devices) * math.ceil(chunk_size / len(devices))
    table = expand(spec)
    store = SweepStore(run_dir, writer=jax.process_index() == 0)
    chunks = _chunks(len(table), chunk_size)
    controller_config = wblc or walking_config()  # what make_walking_controller uses too
    store.open(
        {
            "spec_digest": spec.digest(),
            "spec": dataclasses.asdict(spec),
            "config": config,
            "gait": dataclasses.asdict(gait),
            "wblc_com_acc_limit": None if wblc is None else wblc.com_acc_limit,
            "wblc_force_qp": dataclasses.asdict(controller_config.force_qp),
            "wblc_hierarchy": {
                k: getattr(controller_config, k)
                for k in ("pinv_rtol", "whiten_tasks", "hierarchy_inverse", "torque_pinv_rtol")
            },
            "physics": None if physics is None else dataclasses.asdict(physics),
            "backend": backend,
            "chunk_size": chunk_size,
            "num_pushes": len(table),
            "num_chunks": len(chunks),
            "devices": [str(d) for d in devices],
            "host": platform.node(),
            "runs": [],
        },
        table,
    )
    todo = [i for i in range(len(chunks)) if not store.done(i)]
    if max_chunks is not None:
        todo = todo[:max_chunks]
    if auto_workers:
        workers = _auto_workers(backend, sum(len(chunks[i]) for i in todo) * spec.horizon)
    workers = min(workers, len(todo))
    if workers > 1:
        run_in_workers(
            spec, store, table, chunks, todo, backend, chunk_size, gait, physics, wblc,
            push_body, workers, progress,
        )  # fmt: skip
    elif todo:
        _run_chunks(
            spec, store, table, chunks, todo, backend, chunk_size, gait, physics, wblc,
            push_body, nthread, progress,
        )  # fmt: skip
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


@dataclasses.dataclass
class _ChunkContext:
    """What running chunks needs: the model, the backend runner, the start snapshots."""

    model: object
    runner: object
    snapshots: dict
    horizon_steps: int
    walks_s: float


def _prepare(spec, store, table, chunks, todo, backend, gait, physics, wblc, push_body, nthread,
             progress, make_runner=True):  # fmt: skip
    t_start = time.perf_counter()
    model = load_valkyrie()
    sim_model = physics_model(model, physics) if physics is not None else model
    body = body_index(model, push_body)
    ctrl = make_walking_controller(model, config=wblc, gait=gait)
    dt = model.opt.timestep
    horizon_steps = int(round(spec.horizon / dt))

    # Undisturbed walks: one per (speed, turn, replan) the remaining rows need, snapshotted
    # at every phase the whole table asks of it and kept on disk, so a resumed sweep walks
    # nothing twice (a walk does not depend on which phases it stops at).
    rows_todo = np.concatenate([chunks[i] for i in todo])
    step_fn = jax.jit(ctrl.step)
    snapshots = {}
    all_keys = [
        walk_key(table["apex_speed"][r], table["turn_deg"][r], table["replan"][r])
        for r in range(len(table))
    ]
    needed = sorted({all_keys[r] for r in rows_todo})
    for key in tqdm(needed, desc="undisturbed walks", disable=not progress):
        path = store.walk_path(key)
        if path.exists():
            template = initial_controller_state(ctrl, sim_model, *key)
            snapshots[key] = load_snapshots(path, template)
            continue
        phases = table["phase"][[k == key for k in all_keys]]
        snapshots[key] = snapshot_walk(
            sim_model, ctrl, step_fn, *key, spec.push_step, phases, spec.fall_height
        )
        if store.writer:
            save_snapshots(path, snapshots[key])
    t_walks = time.perf_counter() - t_start

    runner = None
    if make_runner and backend == "c":
        runner = CBatchBackend(sim_model, ctrl, body, spec.fall_height, nthread)
    elif make_runner:
        runner = MJXBackend(sim_model, ctrl, body, spec.fall_height, horizon_steps)
    return _ChunkContext(model, runner, snapshots, horizon_steps, t_walks)


def _chunk_starts(ctx, spec, table, rows, chunk_size) -> ChunkStarts:
    """The start states of a chunk's runs, padded to ``chunk_size`` with its last push."""
    model = ctx.model
    padded = np.concatenate([rows, np.full(chunk_size - len(rows), rows[-1])])
    times, phys, cstate = gather_starts(
        table, padded, ctx.snapshots, spec.qvel_noise, model.nq, model.nv
    )
    heading = np.asarray(cstate.gait.heading, float)
    pushes = PushArrays(
        magnitude=table["magnitude"][padded],
        direction=heading + np.radians(table["direction_deg"][padded]),
        start=times,
        duration=table["duration"][padded],
    )
    return ChunkStarts(times, phys, cstate, pushes)


def _run_one_chunk(ctx, spec, store, table, rows, index, chunk_size, tick_progress=None):
    """Run chunk ``index`` (its ``rows``), write it, return its outcome columns."""
    starts = _chunk_starts(ctx, spec, table, rows, chunk_size)
    outcome = ctx.runner.run(starts, ctx.horizon_steps, progress=tick_progress)
    cols = finalize(outcome, spec.steps_after)
    cols = {k: v[: len(rows)] for k, v in cols.items()}
    store.write_chunk(index, rows, cols)
    return cols


def _run_chunks(
    spec, store, table, chunks, todo, backend, chunk_size, gait, physics, wblc, push_body,
    nthread, progress,
):  # fmt: skip
    t_start = time.perf_counter()
    ctx = _prepare(
        spec, store, table, chunks, todo, backend, gait, physics, wblc, push_body, nthread,
        progress,
    )  # fmt: skip
    horizon_steps = ctx.horizon_steps
    done_rows = sum(len(chunks[i]) for i in range(len(chunks)) if store.done(i))
    recovered = attempted = 0
    bar = tqdm(
        total=len(table), initial=done_rows, desc=f"push sweep ({backend})", unit="push",
        disable=not progress,
    )  # fmt: skip
    chunk_times = []
    steps_done = [0]

    def tick_progress(n_env_steps):
        steps_done[0] += n_env_steps

    for index in todo:
        rows = chunks[index]
        t0 = time.perf_counter()
        steps_before = steps_done[0]
        cols = _run_one_chunk(ctx, spec, store, table, rows, index, chunk_size, tick_progress)
        elapsed = time.perf_counter() - t0
        chunk_times.append(elapsed)
        recovered += int(cols["recovered"].sum())
        attempted += len(rows)
        done_rows += len(rows)
        bar.update(len(rows))
        bar.set_postfix(
            recovered=f"{recovered}/{attempted}",
            env_steps_s=f"{(steps_done[0] - steps_before) / elapsed:.0f}",
        )
    bar.close()

    # The first chunk includes the compile: a steady rate needs a second chunk (None without).
    steady = float(np.mean(chunk_times[1:])) if len(chunk_times) > 1 else None
    manifest = store.read_manifest()
    manifest["runs"].append(
        {
            "chunks": list(todo),
            "undisturbed_walks_s": ctx.walks_s,
            "first_chunk_s": chunk_times[0],
            "first_chunk_env_steps_per_s": chunk_size * horizon_steps / chunk_times[0],
            "steady_chunk_s": steady,
            "env_steps_per_s": None if steady is None else chunk_size * horizon_steps / steady,
            "wall_s": time.perf_counter() - t_start,
        }
    )
    store.write_manifest(manifest)
