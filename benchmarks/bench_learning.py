"""RL-PSP training speed: wall time to a survival basin, transitions/s, memory, features.

    python benchmarks/bench_learning.py [--json PATH] [--quick]

Targets (2 CPU cores): a policy with survival basin >= 50% in <= 10 s, compile
included (reported apart). Cases: the default (the FAST preset of Algorithm 1, then the
pathwise refinement of :mod:`jaxloco.learning.refine`), Algorithm 1 alone, refinement
alone (no Algorithm 1: 2-step rollouts from the initial weights, the fastest route to the
target), and as the baseline the paper's exact Algorithm 1 configuration (plain summed updates,
alpha = beta = 3e-5) given the same iteration budget; and dense evaluation of all 30,240 RBF
features against the local one. The kept weights are chosen on the training evaluator's
draw (2048 states), so each is also scored on two independent draws: 4096 states, the seed
``jaxloco policy-eval`` uses, and 65,536 states (one standard error 0.002).
"""

from __future__ import annotations

import dataclasses
import functools
import resource
import time

import jax
import jax.numpy as jnp
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
    ActorCriticConfig,
    RefineConfig,
    TrainConfig,
    mean_policy,
    rbf,
    survival_basin,
    train,
)
from jaxloco.learning import policy as pol
from jaxloco.learning.actor_critic import init_train_state
from jaxloco.learning.training import params_fingerprint
from jaxloco.runtime import watchdog

THRESHOLDS = (0.30, 0.40, 0.50)


def time_to_basin(result, threshold):
    for row in result.history:
        if row.get("basin", -1.0) >= threshold:
            return row["wall_s"]
    return None


HELD_OUT_SEED, HELD_OUT_STATES = 2024, 4096
# A large independent draw: one standard error of a basin near 0.5 is 0.002 (0.008 for the
# 4096 states above).
LARGE_SEED, LARGE_STATES = 7, 65536


@functools.partial(jax.jit, static_argnums=(1, 2))
def independent_basin(params, seed, num_states):
    grid, psp = TrainConfig().grid, TrainConfig().planner
    key = jax.random.PRNGKey(seed)
    return survival_basin(mean_policy(params, grid, psp), psp, key, num_states)[0]


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
        held_out_basin=float(independent_basin(result.best_params, HELD_OUT_SEED, HELD_OUT_STATES)),
        large_draw_basin=float(independent_basin(result.best_params, LARGE_SEED, LARGE_STATES)),
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
        row[f"t_basin_{int(th * 100)}"] = time_to_basin(result, th)
    return row, result


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
    max_iterations = 60 if args.quick else FAST.max_iterations
    refine_iterations = 50 if args.quick else RefineConfig().iterations
    # The default exactly as `jaxloco train-planner` runs it (evaluation every 25 iterations).
    default = TrainConfig(
        actor_critic=dataclasses.replace(FAST, max_iterations=max_iterations),
        refine=RefineConfig(iterations=refine_iterations),
    )
    fast = dataclasses.replace(default, refine=RefineConfig(iterations=0))
    paper = TrainConfig(
        refine=RefineConfig(iterations=0),
        actor_critic=dataclasses.replace(
            ActorCriticConfig(),
            episodes_per_iteration=FAST.episodes_per_iteration,
            max_episode_steps=FAST.max_episode_steps,
            max_iterations=max_iterations,
        ),
    )
    with watchdog(args.timeout, "bench_learning"):
        rows = []
        default_row, _ = run_training(
            f"default: FAST ({max_iterations} it. or spread < {FAST.spread_target}), "
            f"then {refine_iterations} refinement steps",
            default,
        )
        rows.append(default_row)
        rows.append(run_training("FAST preset, Algorithm 1 alone", fast)[0])
        # The fastest route: no Algorithm 1, refinement (2-step rollouts) from the initial
        # weights (every mean at the nominal action).
        untrained = dataclasses.replace(
            default,
            actor_critic=dataclasses.replace(FAST, max_iterations=0),
            refine=RefineConfig(iterations=50 if args.quick else 100, horizon=2),
        )
        rows.append(
            run_training(
                f"refinement alone, horizon 2, {untrained.refine.iterations} steps "
                "(no Algorithm 1)",
                untrained,
            )[0]
        )
        rows.append(run_training("paper's Algorithm 1 config, same budget (baseline)", paper)[0])
        again, _ = run_training("default again (same seed)", default)
        reproducible = again["fingerprint"] == default_row["fingerprint"]
        features, feature_diff = bench_features(2048 if args.quick else 16384, 5)
    peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    tables = []
    tables.append(
        print_table(
            "RL-PSP training (basin on 2048 uniform box states, 50 steps, every 25 iterations)",
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
