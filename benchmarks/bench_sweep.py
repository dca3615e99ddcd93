"""Push-sweep speed: the sweep as users run it, on both backends, against physics alone.

    python benchmarks/bench_sweep.py [--json PATH] [--quick]

1. **End to end** (:func:`jaxloco.sweep.run_sweep`, what ``jaxloco push-sweep`` calls), each
   run twice into fresh directories with one fresh XLA cache: the first run compiles, the
   second starts from the cache (what a user sees re-running a sweep). Wall time of each,
   and closed-loop env-steps/s over the steady chunks (from the manifest).

   - **The default sweep** (``SweepSpec()``, ``jaxloco push-sweep task=grid``: 64 pushes,
     chunks of 16, 2 Dask worker processes, one per core; ``--quick``: its 0.5 s horizon
     only): each worker runs two chunks, and the rate is over the second ones, side by
     side.
   - A small sweep of 520 N pushes (8 directions, one gait phase, 1 s; ``--quick``: 2
     directions, 0.3 s) in two chunks, on the C backend in one process and on MJX. Its
     "recovered" is only "standing at the end of the horizon" (``steps_after=0``): a speed
     benchmark, not a robustness result.
2. **Physics alone** in the same run, same batch, same ticks, from the same mid-walk
   states, zero torques: MuJoCo's ``mujoco.rollout`` (2 threads), the ``mujoco.batch``
   thread pool the C backend steps, and ``jit(vmap(scan(mjx.step)))``.
3. **Where the time goes**: the vmapped controller tick (gait + planner + WBLC) alone,
   jitted, for the same batch: its time per env-step against the closed loop's.

Targets: >= 10^4 closed-loop env-steps/s on 2 cores for the default sweep, and the closed
loop at most 10x the physics time of the same run.
"""

from __future__ import annotations

import inspect
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _common import (  # noqa: E402
    compile_seconds,
    parse_args,
    print_table,
    target,
    time_calls,
    write_json,
)
from bench_closed_loop import bench_c_physics, bench_mjx_physics  # noqa: E402
from mujoco import mjx, rollout  # noqa: E402

from jaxloco.dynamics.model import load_valkyrie  # noqa: E402
from jaxloco.locomotion import make_walking_controller  # noqa: E402
from jaxloco.runtime import enable_compilation_cache, watchdog  # noqa: E402
from jaxloco.sim.mjx_loop import PhysicsParams, physics_model  # noqa: E402
from jaxloco.sim.push import PushArrays  # noqa: E402
from jaxloco.sweep import SweepSpec, run_sweep  # noqa: E402
from jaxloco.sweep.backends import ChunkStarts, mjx_loop_states  # noqa: E402
from jaxloco.sweep.spec import expand  # noqa: E402
from jaxloco.sweep.starts import gather_starts, snapshot_walk, walk_key  # noqa: E402


def sweep_spec(quick: bool) -> SweepSpec:
    return SweepSpec(
        directions_deg=(0.0, 90.0) if quick else tuple(45.0 * k for k in range(8)),
        magnitudes=(520.0,),
        phases=(0.5,),
        replan=(True,),
        horizon=0.3 if quick else 1.0,
        steps_after=0,
    )


def default_sweep_spec(quick: bool) -> SweepSpec:
    """The default grid sweep, ``SweepSpec()`` (``--quick``: over a 0.5 s horizon)."""
    return SweepSpec(horizon=0.5, steps_after=0) if quick else SweepSpec()


def end_to_end(spec, backend, root: Path, workers: int = 1, chunk_size=None) -> dict:
    """Two runs of the same sweep into fresh directories (the cache is shared).
    ``chunk_size``: None for two chunks (the second is steady)."""
    walls, rates = [], []
    for k in range(2):
        t0 = time.perf_counter()
        result = run_sweep(
            spec,
            root / f"{backend}_{workers}_{chunk_size}_{k}",
            backend=backend,
            chunk_size=chunk_size or max(1, len(expand(spec)) // 2),
            progress=False,
            workers=workers,
        )
        walls.append(time.perf_counter() - t0)
        run = result.manifest["runs"][-1]
        # A worker with one chunk has no compile-free chunk: its rate is over the whole
        # run (start-up and cached compile included).
        rates.append(run["env_steps_per_s"] or run.get("overall_env_steps_per_s"))
    return {
        "first_wall_s": walls[0],
        "cached_wall_s": walls[1],
        "env_steps_per_s": rates[1],
        "recovered": int(np.asarray(result.outcomes["recovered"]).sum()),
    }


def physics_alone(sim_model, starts, steps) -> dict:
    """Env-steps/s of ``mujoco.rollout`` on 2 threads and of the ``mujoco.batch`` pool."""
    n = len(starts.times)
    datas = [mujoco.MjData(sim_model) for _ in range(2)]
    # rollout takes mjSTATE_FULLPHYSICS; the sweep keeps mjSTATE_INTEGRATION.
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    initial = np.zeros((n, mujoco.mj_stateSize(sim_model, full)))
    for k, row in enumerate(starts.physics):
        mujoco.mj_setState(sim_model, datas[0], row, mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_getState(sim_model, datas[0], initial[k], full)
    rollout.rollout(sim_model, datas, initial, nstep=2)  # warm up the thread pool
    t0 = time.perf_counter()
    rollout.rollout(sim_model, datas, initial, nstep=steps)
    return {
        "rollout_2_threads": n * steps / (time.perf_counter() - t0),
        "batch": n * steps / bench_c_physics(sim_model, starts, steps),
    }


DEFAULT_CHUNK = inspect.signature(run_sweep).parameters["chunk_size"].default
"""``jaxloco push-sweep``'s default ``chunk_size``."""


def _ticks(spec, model) -> int:
    return int(round(spec.horizon / model.opt.timestep))


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    spec = sweep_spec(args.quick)
    n = len(expand(spec))
    with (
        tempfile.TemporaryDirectory(prefix="bench-sweep-") as tmp,
        watchdog(args.timeout, "bench_sweep"),
    ):
        root = Path(tmp)
        enable_compilation_cache(str(root / "xla"))  # fresh: the first run compiles
        default = default_sweep_spec(args.quick)
        rows = {
            "c, 2 workers, default sweep": end_to_end(
                default, "c", root, workers=2, chunk_size=DEFAULT_CHUNK
            ),
            "c": end_to_end(spec, "c", root),
            "mjx": end_to_end(spec, "mjx", root),
        }

        model = load_valkyrie()
        sim_model = physics_model(model, PhysicsParams())
        ctrl = make_walking_controller(model)
        snap = snapshot_walk(
            sim_model, ctrl, jax.jit(ctrl.step), 1.0, 0.0, True, spec.push_step, [0.5]
        )
        table = expand(spec)
        snapshots = {walk_key(1.0, 0.0, True): snap}
        times, phys, cstate = gather_starts(table, np.arange(n), snapshots, 0.0, model.nq, model.nv)
        steps = int(round(spec.horizon / model.opt.timestep))
        starts = ChunkStarts(times, phys, cstate, PushArrays.none((n,)))
        c_phys = physics_alone(sim_model, starts, steps)
        loop = mjx_loop_states(sim_model, starts)
        mjx_compile, mjx_wall = bench_mjx_physics(mjx.put_model(sim_model), loop.data, steps)
        mjx_rate = n * steps / mjx_wall

        # The controller alone: one vmapped tick for the batch, from the same states.
        tick = jax.jit(jax.vmap(ctrl.step))
        qpos = jnp.asarray(loop.data.qpos, jnp.float32)
        qvel = jnp.asarray(loop.data.qvel, jnp.float32)
        t = jnp.asarray(times, jnp.float32)
        cs = jax.tree.map(jnp.asarray, cstate)
        tick_compile, tick_c = compile_seconds(tick, t, qpos, qvel, cs)
        timing = time_calls(tick_c, t, qpos, qvel, cs, repeats=5 if args.quick else 20)
        controller_rate = n / timing["median_s"]

    # Physics alone: MuJoCo C on 2 threads for the 2-worker default sweep, one thread in
    # process; MJX in process.
    physics = {
        "c, 2 workers, default sweep": c_phys["rollout_2_threads"],
        "c": c_phys["batch"],
        "mjx": mjx_rate,
    }
    sizes = {
        "c, 2 workers, default sweep": (len(expand(default)), _ticks(default, model)),
        "c": (n, steps),
        "mjx": (n, steps),
    }
    table_rows = []
    for backend, r in rows.items():
        table_rows.append(
            {
                "backend": backend,
                "pushes": sizes[backend][0],
                "ticks": sizes[backend][1],
                "first_wall_s": r["first_wall_s"],
                "cached_wall_s": r["cached_wall_s"],
                "env_steps_per_s": r["env_steps_per_s"],
                "physics_env_steps_per_s": physics[backend],
                "closed_loop_over_physics": physics[backend] / r["env_steps_per_s"],
                "recovered": r["recovered"],
            }
        )
    tables = [None, None]
    tables[0] = print_table(
        "Push sweeps: the default grid (64 pushes) and a small one in 2 chunks; two runs each "
        "with one fresh XLA cache; baseline = physics alone in the same run",
        table_rows,
        [
            ("backend", "backend", "s"),
            ("pushes", "pushes", "d"),
            ("first_wall_s", "first run (s)", ".1f"),
            ("cached_wall_s", "cached run (s)", ".1f"),
            ("env_steps_per_s", "closed loop env-steps/s", ".0f"),
            ("physics_env_steps_per_s", "physics alone env-steps/s", ".0f"),
            ("closed_loop_over_physics", "closed loop / physics time", ".1f"),
            ("recovered", "recovered", "d"),
        ],
    )
    profile = [
        {
            "part": "mujoco.rollout, 2 threads (physics)",
            "env_steps_per_s": c_phys["rollout_2_threads"],
        },
        {"part": "mujoco.batch step (physics, C backend)", "env_steps_per_s": c_phys["batch"]},
        {"part": "mjx.step, jit(vmap(scan))", "env_steps_per_s": mjx_rate},
        {"part": "controller tick alone, jit(vmap)", "env_steps_per_s": controller_rate},
    ]
    tables[1] = print_table(
        f"Where the time goes (batch {n}; compile: controller {tick_compile:.1f} s, "
        f"mjx.step {mjx_compile:.1f} s)",
        profile,
        [("part", "part", "s"), ("env_steps_per_s", "env-steps/s", ".0f")],
    )
    targets = []
    for r in table_rows:
        if r["backend"] == "c, 2 workers, default sweep":
            targets = [
                target(
                    "default sweep, env-steps/s", r["env_steps_per_s"], 1e4, "env-steps/s", False
                ),
                target(
                    "default sweep, closed loop / physics time",
                    r["closed_loop_over_physics"],
                    10.0,
                    "x",
                ),
                target(
                    "default sweep, pushes recovered",
                    r["recovered"],
                    60,
                    f"of {r['pushes']}",
                    False,
                ),
            ]
    write_json(
        args.json,
        "sweep",
        {
            "rows": table_rows,
            "profile": profile,
            "controller_tick": timing,
            "controller_compile_s": tick_compile,
            "mjx_physics_compile_s": mjx_compile,
            "quick": args.quick,
        },
        tables=tables,
        targets=targets,
    )


if __name__ == "__main__":
    main()
