"""Step-policy learners side by side: wall time to a survival basin, basins on independent
draws, throughput, and (full run) how each policy walks the full robot.

    python benchmarks/bench_learning.py [--json PATH] [--quick]

Targets (2 CPU cores): ``jaxloco train-planner``'s default reaches a 50% survival basin in
<= 10 s, compile included (reported apart), and its kept policy scores >= 0.50 on an
independent 65,536-state draw. Cases:

- the default (:data:`~jaxloco.learning.WARM_START`: 50 iterations of Algorithm 1's FAST
  preset, then the pathwise refinement of :mod:`jaxloco.learning.refine`), and the same
  again to check that a seed reproduces it;
- Algorithm 1 alone (FAST, its full budget), and as the baseline the paper's exact
  Algorithm 1 configuration (plain summed updates, alpha = beta = 3e-5) with that budget;
- the refinement alone (no Algorithm 1);
- Brax's PPO on :class:`~jaxloco.learning.brax_env.StepEnv` (:mod:`jaxloco.learning.ppo`);
- the one-step look-ahead search over the action grid, as a reference (no training);
- the policies shipped in ``assets/policies`` (no training): the walking controller's
  default, Algorithm 1's and the refined one.

The kept weights are chosen on the training evaluator's draw (2048 states), so each policy
is also scored on two independent draws: 4096 states (the seed ``jaxloco policy-eval``
uses) and 65,536 states (one standard error 0.002). Without ``--quick`` each trained policy
also walks Fig. 11's steering schedule on the full robot (MuJoCo C, walking WBLC) and runs
the default 64-push grid sweep (``jaxloco push-sweep task=grid``, 2 workers); the table
gives whether the walk completed and how many pushes were recovered. And the RBF network's
local read-out is timed against the dense one.
"""

from __future__ import annotations

import dataclasses
import resource
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _common import (
    compile_seconds,
    parse_args,
    print_table,
    print_targets,
    target,
    time_calls,
    write_json,
)

from jaxloco.learning import (
    FAST,
    WARM_START,
    ActorCriticConfig,
    RefineConfig,
    TrainConfig,
    load_planner,
    mean_policy,
    rbf,
    save_checkpoint,
    survival_basin,
    train,
)
from jaxloco.learning import policy as pol
from jaxloco.learning.actor_critic import init_train_state
from jaxloco.learning.checkpoint import SHIPPED_POLICIES, assets_dir
from jaxloco.learning.ppo import PPOConfig, save_ppo_checkpoint, train_ppo
from jaxloco.learning.training import params_fingerprint
from jaxloco.planner import PSPParams, make_lookahead_policy, turn_schedule
from jaxloco.runtime import watchdog

THRESHOLDS = (0.30, 0.40, 0.50)
FIG11 = ((12, 18.8), (5, 0.0), (12, -18.8))
"""Fig. 11's steering schedule: (steps, deg per step)."""


def time_to_basin(history, threshold):
    for row in history:
        if (row.get("basin") or -1.0) >= threshold:
            return row["wall_s"]
    return None


HELD_OUT_SEED, HELD_OUT_STATES = 2024, 4096
# A large independent draw: one standard error of a basin near 0.5 is 0.002 (0.008 for the
# 4096 states above).
LARGE_SEED, LARGE_STATES = 7, 65536


def independent_basins(policy) -> dict:
    """Survival basins of a deterministic policy ``(3,) -> (3,)`` on the two draws."""
    psp = PSPParams()
    out = {}
    for name, seed, n in (
        ("held_out_basin", HELD_OUT_SEED, HELD_OUT_STATES),
        ("large_draw_basin", LARGE_SEED, LARGE_STATES),
    ):
        basin = jax.jit(lambda key, n=n: survival_basin(policy, psp, key, n)[0])
        out[name] = float(basin(jax.random.PRNGKey(seed)))
    return out


def run_training(name, config):
    t0 = time.perf_counter()
    result = train(config, progress=False)
    total = time.perf_counter() - t0
    ac = config.actor_critic
    ref = result.refinement
    stages = [result] + ([ref] if ref is not None else [])
    iterations = len(result.history) - (len(ref.history) if ref is not None else 0)
    env_steps = iterations * ac.episodes_per_iteration * ac.max_episode_steps
    lengths = sum(row.get("mean_length", 0.0) for row in result.history) * ac.episodes_per_iteration
    row = dict(
        case=name,
        iterations=iterations,
        refine_iterations=len(ref.history) if ref is not None else 0,
        actor_critic_basin=result.actor_critic_basin,
        best_basin=result.best_basin,
        **independent_basins(mean_policy(result.best_params, config.grid, config.planner)),
        total_s=total,
        compile_s=sum(stage.compile_seconds for stage in stages),
        train_s=sum(stage.train_seconds for stage in stages),
        eval_s=sum(stage.eval_seconds for stage in stages),
        refine_step_ms=1e3 * ref.train_seconds / max(len(ref.history) - 1, 1) if ref else None,
        # Algorithm 1's rates; None when it ran only its compiling first iteration.
        transitions_per_s=env_steps / result.train_seconds if result.train_seconds else None,
        live_transitions_per_s=lengths / result.train_seconds if result.train_seconds else None,
        stop_reason=result.stop_reason,
        fingerprint=params_fingerprint(result.best_params),
    )
    for th in THRESHOLDS:
        row[f"t_basin_{int(th * 100)}"] = time_to_basin(result.history, th)
    return row, result


def run_ppo(name, config: PPOConfig):
    """Brax's PPO; its history rows carry the basin and wall time like training's."""
    t0 = time.perf_counter()
    result = train_ppo(config, progress=False)
    total = time.perf_counter() - t0
    row = dict(
        case=name,
        best_basin=result.best_basin,
        **independent_basins(result.planner.policy),
        total_s=total,
        transitions_per_s=result.history[-1]["env_steps"] / total,
    )
    for th in THRESHOLDS:
        row[f"t_basin_{int(th * 100)}"] = time_to_basin(result.history, th)
    return row, result


def run_lookahead():
    """The search policy (no training): its basins, and the time they took."""
    t0 = time.perf_counter()
    row = dict(
        case="look-ahead search, 9 x 9 x 11 action grid (reference; no training)",
        **independent_basins(make_lookahead_policy(PSPParams())),
    )
    row["eval_s"] = time.perf_counter() - t0
    return row


SHIPPED = (
    ("default", "the walking controller's: Algorithm 1, with the refined policy as fallback"),
    ("algorithm1", "Algorithm 1 alone (FAST, 600 it.)"),
    ("refined", "Algorithm 1 (600 it.), then 300 refinement steps"),
)


def run_shipped(key, description):
    """A policy shipped in assets/ (no training): its basins, and the time they took."""
    t0 = time.perf_counter()
    row = dict(
        case=f"shipped '{key}': {description}",
        **independent_basins(load_planner(shipped=key).policy),
    )
    row["eval_s"] = time.perf_counter() - t0
    return row


def robot_trials(checkpoint, run_dir) -> dict:
    """How a policy walks the full robot: Fig. 11's steering schedule (completed or not)
    and the default 64-push grid sweep (recovered pushes), both on MuJoCo C."""
    from jaxloco.dynamics.model import load_valkyrie
    from jaxloco.locomotion import make_walking_controller
    from jaxloco.sim.scenarios import simulate_walk
    from jaxloco.sweep import SweepSpec, run_sweep

    model = load_valkyrie()
    ctrl = make_walking_controller(model, planner=load_planner(checkpoint))
    turns = turn_schedule(FIG11)
    steps = len(turns) + 2
    walk = simulate_walk(model, ctrl, 40.0, turns=turns, max_steps=steps)
    sweep = run_sweep(SweepSpec(), run_dir, workers=2, progress=False, planner=str(checkpoint))
    recovered = np.asarray(sweep.outcomes["recovered"])
    return {
        "fig11": "yes" if (not walk.fell and walk.steps_taken >= steps) else "no",
        "fig11_steps": walk.steps_taken,
        "grid_recovered": f"{int(recovered.sum())}/{recovered.size}",
    }


def bench_features(n, repeats):
    grid = rbf.RBFGrid()
    params = init_train_state(ActorCriticConfig(), grid).params
    states = jax.random.uniform(
        jax.random.key(0), (n, 3), minval=jnp.asarray(grid.low), maxval=jnp.asarray(grid.high)
    )

    def local(s):
        return jax.vmap(lambda x: pol.network_outputs(params, rbf.local_features(grid, x))[1])(s)

    table = rbf.unpad(grid, params.table).reshape(-1, pol.NUM_OUTPUTS)

    def dense(s):
        phi = jax.vmap(lambda x: rbf.dense_features(grid, x))(s)
        return (phi @ table + params.bias)[:, pol.MEAN]

    rows = []
    for name, fn in (("dense: all 30,240 Gaussians (baseline)", dense), ("local window", local)):
        jitted = jax.jit(fn)
        comp, _ = compile_seconds(jitted, states)
        t = time_calls(jitted, states, repeats=repeats)
        rows.append(dict(case=name, compile_s=comp, per_state_us=t["median_s"] / n * 1e6))
    rows[1]["vs_baseline"] = rows[0]["per_state_us"] / rows[1]["per_state_us"]
    got, want = jax.jit(local)(states), jax.jit(dense)(states)
    max_diff = float(jnp.max(jnp.abs(got - want)))
    return rows, max_diff


def main():
    args = parse_args(__doc__.splitlines()[0])
    ac_iterations = 60 if args.quick else FAST.max_iterations
    default = TrainConfig()  # exactly what `jaxloco train-planner` runs
    algorithm1 = TrainConfig(
        actor_critic=dataclasses.replace(FAST, max_iterations=ac_iterations),
        refine=RefineConfig(iterations=0),
    )
    paper = dataclasses.replace(
        algorithm1,
        actor_critic=dataclasses.replace(
            ActorCriticConfig(),
            episodes_per_iteration=FAST.episodes_per_iteration,
            max_episode_steps=FAST.max_episode_steps,
            max_iterations=ac_iterations,
        ),
    )
    refine_alone = TrainConfig(
        actor_critic=dataclasses.replace(FAST, max_iterations=0),
        refine=RefineConfig(iterations=100 if args.quick else 300),
    )
    ppo = PPOConfig(num_timesteps=1_000_000, num_evals=6) if args.quick else PPOConfig()
    with watchdog(args.timeout, "bench_learning"), tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rows, checkpoints = [], {}
        default_row, default_run = run_training(
            f"default: FAST for {WARM_START.max_iterations} it., then "
            f"{default.refine.iterations} refinement steps (horizon {default.refine.horizon})",
            default,
        )
        rows.append(default_row)
        checkpoints["default"] = save_checkpoint(tmp / "default", default_run.best_params, default)
        a1_row, a1_run = run_training(
            f"Algorithm 1 alone: FAST, {ac_iterations} it. or spread < {FAST.spread_target}",
            algorithm1,
        )
        rows.append(a1_row)
        checkpoints["algorithm1"] = save_checkpoint(tmp / "a1", a1_run.best_params, algorithm1)
        rows.append(
            run_training(
                f"refinement alone, {refine_alone.refine.iterations} steps (no Algorithm 1)",
                refine_alone,
            )[0]
        )
        rows.append(run_training("paper's Algorithm 1 config, same budget (baseline)", paper)[0])
        ppo_row, ppo_run = run_ppo(
            f"PPO (Brax), {ppo.num_timesteps:.3g} env steps, {ppo.num_envs} envs", ppo
        )
        rows.append(ppo_row)
        checkpoints["ppo"] = save_ppo_checkpoint(tmp / "ppo", ppo_run.planner)
        rows.append(run_lookahead())
        on_robot = [(default_row, "default"), (a1_row, "algorithm1"), (ppo_row, "ppo")]
        for key, description in SHIPPED:
            rows.append(run_shipped(key, description))
            checkpoints[f"shipped_{key}"] = assets_dir() / SHIPPED_POLICIES[key]
            on_robot.append((rows[-1], f"shipped_{key}"))
        again, _ = run_training("default again (same seed)", default)
        reproducible = again["fingerprint"] == default_row["fingerprint"]
        if not args.quick:
            for row, key in on_robot:
                row.update(robot_trials(checkpoints[key], tmp / f"sweep_{key}"))
        features, feature_diff = bench_features(2048 if args.quick else 16384, 5)
    peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    tables = []
    tables.append(
        print_table(
            "Step-policy learners (basin: share of the Eq. 1 box surviving 50 steps; the "
            "training evaluator's draw has 2048 states, evaluated every 25 iterations)",
            rows,
            [
                ("case", "case", "s"),
                ("iterations", "iters", "d"),
                ("refine_iterations", "refine", "d"),
                ("actor_critic_basin", "Alg. 1 basin", ".3f"),
                ("best_basin", "best basin", ".3f"),
                ("held_out_basin", "held-out", ".3f"),
                ("large_draw_basin", "65k draw", ".3f"),
                ("t_basin_30", "s to 30%", ".1f"),
                ("t_basin_40", "s to 40%", ".1f"),
                ("t_basin_50", "s to 50%", ".1f"),
                ("total_s", "total s", ".1f"),
                ("compile_s", "compile s", ".1f"),
                ("train_s", "train s", ".1f"),
                ("eval_s", "eval s", ".1f"),
                ("refine_step_ms", "ms/refine", ".0f"),
                ("transitions_per_s", "steps/s", ".3g"),
                ("live_transitions_per_s", "live steps/s", ".3g"),
                ("fig11", "Fig. 11 walk", "s"),
                ("grid_recovered", "grid pushes", "s"),
            ],
        )
    )
    reached = default_row["t_basin_50"]
    targets = [
        target(
            "default training, basin on an independent 65,536-state draw",
            default_row["large_draw_basin"], 0.5, "", at_most=False,
        ),
        target(
            "default training, wall time to a 50% basin, compile included",
            float("inf") if reached is None else reached, 10, "s",
        ),
    ]  # fmt: skip
    print_targets(targets)
    print(f"reproducible for a seed: {reproducible} (fingerprint {default_row['fingerprint']})")
    print(f"peak resident memory of this process: {peak_rss_mb:.0f} MB")
    tables.append(
        print_table(
            "RBF network evaluation (means of 3 actions), per state",
            features,
            [
                ("case", "case", "s"),
                ("per_state_us", "us/state", ".3f"),
                ("compile_s", "compile s", ".2f"),
                ("vs_baseline", "x dense", ".1f"),
            ],
        )
    )
    print(f"(local vs dense max |difference| of the means: {feature_diff:.2e}, truncation)")
    write_json(
        args.json,
        "bench_learning",
        {
            "quick": args.quick,
            "training": rows,
            "reproducible": reproducible,
            "peak_rss_mb": peak_rss_mb,
            "features": features,
            "feature_truncation_max_diff": feature_diff,
        },
        tables=tables,
        targets=targets,
    )


if __name__ == "__main__":
    main()
