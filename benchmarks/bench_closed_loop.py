"""Closed-loop simulation speed: physics + WBLC + gait + learned planner, per env-step.

    python benchmarks/bench_closed_loop.py [--json PATH] [--quick]

For one robot and batches of 64 and 256 (``--quick``: 1 and 8), on both physics backends
the sweeps use, each against physics alone in the same run:

- **MJX**: ``jit(vmap(lax.scan(closed_loop_step)))`` (:mod:`jaxloco.sim.mjx_loop`), against
  ``jit(vmap(lax.scan(mjx.step)))`` with zero torques;
- **C**: the sweep's C backend (:class:`jaxloco.sweep.backends.CBatchBackend`, MuJoCo's
  ``mujoco.batch`` thread pool with the controller jitted and vmapped in JAX, one call a
  tick; one robot's tick is not vmapped), against ``mj_step`` (one robot) or
  ``Batch.step`` (batches) alone; for one robot also ``run_closed_loop`` with a
  :class:`~jaxloco.sim.mujoco_c.PackedController` (the path of ``simulate_walk``, the
  viewer and the experiments).

Each timed run is repeated 3 times (the median is reported). Both at the sweep's physics
settings (:class:`~jaxloco.sim.mjx_loop.PhysicsParams`). Runs
start mid-walk (a snapshot of the undisturbed walk during single support), so the gait,
planner and swing are live. Compile time is reported apart (AOT ``lower().compile()`` for
MJX; the first tick for C), split into JAX's tracing, lowering and XLA compile seconds, with
the seconds the persistent compilation cache saved (0 for a cold compile: point
``JAXLOCO_CACHE_DIR`` at an empty folder). Real-time factor = simulated seconds per
wall-clock second.
Under ``vmap`` both branches of the gait's conds run every tick (planning included), so
a batched tick costs more per robot than the single robot's.
"""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _common import (  # noqa: E402
    compile_seconds,
    compile_split,
    parse_args,
    print_table,
    print_targets,
    target,
    write_json,
)
from mujoco import batch as mj_batch  # noqa: E402
from mujoco import mjx  # noqa: E402

from jaxloco.dynamics.model import load_valkyrie  # noqa: E402
from jaxloco.locomotion import make_walking_controller  # noqa: E402
from jaxloco.runtime import enable_compilation_cache, watchdog  # noqa: E402
from jaxloco.sim.mjx_loop import PhysicsParams, physics_model  # noqa: E402
from jaxloco.sim.mujoco_c import PackedController, run_closed_loop  # noqa: E402
from jaxloco.sim.push import PushArrays, body_index  # noqa: E402
from jaxloco.sweep.backends import (  # noqa: E402
    CBatchBackend,
    ChunkStarts,
    MJXBackend,
    mjx_loop_states,
)
from jaxloco.sweep.outcome import init_outcome  # noqa: E402
from jaxloco.sweep.starts import snapshot_walk  # noqa: E402

SECOND_PROCESS = "--second-process"
REPEATS = 3
"""Each timed run is repeated this many times; the tables give the median."""


def median_wall(fn):
    """Median seconds of :data:`REPEATS` calls of ``fn()``, and the last call's result."""
    walls = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t0)
    return float(np.median(walls)), out


def starts_for(snap, n):
    """``n`` copies of the walk snapshot, no pushes."""
    return ChunkStarts(
        np.repeat(snap.times, n),
        np.repeat(snap.physics, n, axis=0),
        jax.tree.map(lambda x: np.repeat(x, n, axis=0), snap.controller),
        PushArrays.none((n,)),
    )


def bench_mjx(sim_model, ctrl, body, starts, steps):
    backend = MJXBackend(sim_model, ctrl, body, 0.7, steps)
    state = mjx_loop_states(sim_model, starts)
    outcome = jax.vmap(init_outcome)(state.controller)
    pushes = PushArrays(*starts.pushes).astype(state.data.qpos.dtype)
    with compile_split() as split:
        compile_s, compiled = compile_seconds(backend._run, state, outcome, pushes)
    wall, out = median_wall(lambda: jax.block_until_ready(compiled(state, outcome, pushes)))
    return compile_s, split, wall, int(np.asarray(out.fell).sum())


def bench_mjx_physics(mx, data, steps):
    def roll(d):
        return jax.lax.scan(lambda d, _: (mjx.step(mx, d), None), d, None, steps)[0]

    fn = jax.jit(jax.vmap(roll))
    compile_s, compiled = compile_seconds(fn, data)
    return compile_s, median_wall(lambda: jax.block_until_ready(compiled(data)))[0]


def bench_c(sim_model, ctrl, body, starts, steps):
    backend = CBatchBackend(sim_model, ctrl, body, 0.7)
    t0 = time.perf_counter()
    with compile_split() as split:
        backend.run(starts, 1)  # compiles the vmapped controller tick
    compile_s = time.perf_counter() - t0
    wall, out = median_wall(lambda: backend.run(starts, steps))
    return compile_s, split, wall, int(np.asarray(out.fell).sum())


def bench_c_loop(sim_model, ctrl, starts, steps):
    """One robot through ``run_closed_loop`` (what ``simulate_walk``, the viewer and the
    experiments run): a :class:`PackedController` of the walking step, MuJoCo C's terms.
    The first run compiles; the second, timed, reuses the compiled tick."""
    packed = PackedController(ctrl.step)
    cstate = jax.tree.map(lambda x: x[0], starts.controller)

    def run(n):
        data = mujoco.MjData(sim_model)
        mujoco.mj_setState(sim_model, data, starts.physics[0], mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(sim_model, data)
        t0 = time.perf_counter()
        log, _ = run_closed_loop(sim_model, data, packed, cstate, n, engine=True)
        return time.perf_counter() - t0, log

    with compile_split() as split:
        compile_s, _ = run(1)
    runs = [run(steps) for _ in range(REPEATS)]
    wall = float(np.median([w for w, _ in runs]))
    return compile_s, split, wall, int(runs[-1][1].fell)


def bench_c_physics(sim_model, starts, steps):
    n = len(starts.times)
    if n == 1:

        def run():
            d = mujoco.MjData(sim_model)
            mujoco.mj_setState(sim_model, d, starts.physics[0], mujoco.mjtState.mjSTATE_INTEGRATION)
            t0 = time.perf_counter()
            for _ in range(steps):
                mujoco.mj_step(sim_model, d)
            return time.perf_counter() - t0

    else:

        def run():
            batch = mj_batch.Batch(sim_model, n)
            batch.state[:] = starts.physics
            t0 = time.perf_counter()
            for _ in range(steps):
                batch.step()
            return time.perf_counter() - t0

    return float(np.median([run() for _ in range(REPEATS)]))


def first_tick_in_a_new_process(starts) -> dict:
    """Seconds to the first tick of one robot (C backend and ``run_closed_loop``) in a new
    process, from the persistent compilation cache the run has filled: what a user waits
    for the second time. JAX logs every cache miss (``jax_explain_cache_misses``); a miss
    means a program compiled again."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "starts.pkl"
        path.write_bytes(pickle.dumps(starts))
        out = subprocess.run(
            [sys.executable, __file__, SECOND_PROCESS, str(path)],
            capture_output=True,
            text=True,
            timeout=600,
            check=True,
        )
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["cache_misses"] = out.stderr.count("PERSISTENT COMPILATION CACHE MISS")
    return result


def second_process(path: str) -> None:
    """The child of :func:`first_tick_in_a_new_process`: prints one JSON line."""
    enable_compilation_cache()
    jax.config.update("jax_explain_cache_misses", True)
    starts = pickle.loads(Path(path).read_bytes())
    t0 = time.perf_counter()
    model = load_valkyrie()
    sim_model = physics_model(model, PhysicsParams())
    ctrl = make_walking_controller(model)
    built = time.perf_counter()
    with compile_split() as split:
        CBatchBackend(sim_model, ctrl, body_index(model, "pelvis"), 0.7).run(starts, 1)
    c_first = time.perf_counter()
    loop_s = bench_c_loop(sim_model, ctrl, starts, 1)[0]
    print(
        json.dumps(
            {
                "build_s": built - t0,
                "c_first_tick_s": c_first - built,
                "c_cache_saved_s": split["cache_saved_s"],
                "loop_first_tick_s": loop_s,
            }
        )
    )


def main() -> None:
    if len(sys.argv) == 3 and sys.argv[1] == SECOND_PROCESS:
        return second_process(sys.argv[2])
    args = parse_args(__doc__.splitlines()[0])
    enable_compilation_cache()
    sizes = [1, 8] if args.quick else [1, 64, 256]
    # 200 ticks in both modes: a run's fixed set-up (~10 ms) is a fifth of 50 ticks.
    steps = 200
    with watchdog(args.timeout, "bench_closed_loop"):
        model = load_valkyrie()
        sim_model = physics_model(model, PhysicsParams())
        ctrl = make_walking_controller(model)
        body = body_index(model, "pelvis")
        t0 = time.perf_counter()
        snap = snapshot_walk(sim_model, ctrl, jax.jit(ctrl.step), 1.0, 0.0, True, 3, [0.5])
        walk_s = time.perf_counter() - t0
        dt = model.opt.timestep
        rows = []
        for n in sizes:
            starts = starts_for(snap, n)
            env_steps = n * steps
            c_compile, c_split, c_wall, c_fell = bench_c(sim_model, ctrl, body, starts, steps)
            c_phys = bench_c_physics(sim_model, starts, steps)
            if n == 1:
                l_compile, l_split, l_wall, l_fell = bench_c_loop(sim_model, ctrl, starts, steps)
                loop_row = ("c, run_closed_loop", l_compile, l_split, l_wall, c_phys, 0.0, l_fell)
            m_compile, m_split, m_wall, m_fell = bench_mjx(sim_model, ctrl, body, starts, steps)
            mx = mjx.put_model(sim_model)
            data = mjx_loop_states(sim_model, starts).data  # the closed loop's start states
            p_compile, p_wall = bench_mjx_physics(mx, data, steps)
            cases = [
                ("c", c_compile, c_split, c_wall, c_phys, 0.0, c_fell),
                ("mjx", m_compile, m_split, m_wall, p_wall, p_compile, m_fell),
            ]
            if n == 1:
                cases.insert(1, loop_row)
            for backend, compile_s, split, wall, phys_wall, phys_compile, fell in cases:
                rows.append(
                    {
                        "backend": backend,
                        "robots": n,
                        "ticks": steps,
                        "compile_s": compile_s,
                        **split,
                        "env_steps_per_s": env_steps / wall,
                        "physics_env_steps_per_s": env_steps / phys_wall,
                        "physics_compile_s": phys_compile,
                        "closed_loop_over_physics": wall / phys_wall,
                        "real_time_factor": steps * dt / wall if n == 1 else None,
                        "fell": fell,
                    }
                )
                print(rows[-1], flush=True)
        warm = first_tick_in_a_new_process(starts_for(snap, 1))
        print("second process:", warm, flush=True)
        by = {(r["backend"], r["robots"]): r for r in rows}
        for n in sizes:
            by["mjx", n]["mjx_over_c"] = (
                by["c", n]["env_steps_per_s"] / by["mjx", n]["env_steps_per_s"]
            )
    tables = []
    tables.append(
        print_table(
            f"Closed loop (physics + WBLC + gait + planner), {steps} ticks at 1 kHz, Valkyrie "
            f"(nv = {model.nv}); baseline = physics alone in the same run",
            rows,
            [
                ("backend", "backend", "s"),
                ("robots", "robots", "d"),
                ("compile_s", "to first tick (s)", ".1f"),
                ("trace_s", "trace (s)", ".1f"),
                ("lower_s", "lower (s)", ".1f"),
                ("xla_compile_s", "XLA compile (s)", ".1f"),
                ("cache_saved_s", "saved by the cache (s)", ".1f"),
                ("env_steps_per_s", "closed loop env-steps/s", ".0f"),
                ("physics_env_steps_per_s", "physics alone env-steps/s", ".0f"),
                ("closed_loop_over_physics", "closed loop / physics time", ".1f"),
                ("real_time_factor", "real-time factor", ".3f"),
                ("mjx_over_c", "C speed / MJX speed", ".2f"),
                ("fell", "fell", "d"),
            ],
        )
    )
    # A 1 kHz controller runs in real time when a tick (physics included) takes < 1 ms;
    # twice real time leaves a real robot's loop half its millisecond.
    targets = [
        target(
            "one robot on MuJoCo C (sweep backend), real-time factor",
            by["c", 1]["real_time_factor"], 2, "x", at_most=False,
        ),
        target(
            "one robot on MuJoCo C (run_closed_loop), real-time factor",
            by["c, run_closed_loop", 1]["real_time_factor"], 2, "x", at_most=False,
        ),
        target(
            "one robot on MuJoCo C (sweep backend), seconds to the first tick in a new "
            "process from the persistent cache",
            warm["c_first_tick_s"], 2, "s",
        ),
    ]  # fmt: skip
    if by["c", 1]["cache_saved_s"] <= 0:  # a cold compile: the cache held none of it
        targets.append(
            target(
                "one robot on MuJoCo C (sweep backend), seconds to the first tick, cold cache",
                by["c", 1]["compile_s"], 8, "s",
            )
        )  # fmt: skip
    tables.append(
        print_table(
            "A new process from the persistent compilation cache the run filled (one robot)",
            [warm],
            [
                ("build_s", "load model, build controller (s)", ".2f"),
                ("c_first_tick_s", "C backend: to first tick (s)", ".2f"),
                ("c_cache_saved_s", "compile s saved by the cache", ".1f"),
                ("loop_first_tick_s", "run_closed_loop: to first tick (s)", ".2f"),
                ("cache_misses", "cache misses", "d"),
            ],
        )
    )
    print_targets(targets)
    write_json(
        args.json,
        "closed_loop",
        {
            "rows": rows,
            "second_process": warm,
            "ticks": steps,
            "undisturbed_walk_s": walk_s,
            "quick": args.quick,
        },
        tables=tables,
        targets=targets,
    )


if __name__ == "__main__":
    main()
