"""Planner speed: PSP transitions/s, 15-step replan latency, batched replans/s.

    python benchmarks/bench_planner.py [--json PATH] [--quick]

Baselines measured in the same run: a vectorised NumPy implementation of the same PSP step
(benchmarks/_numpy_psp.py, checked against the JAX planner first), NumPy 15-step loops, and
the floor of a trivial jitted call. All float32. Targets (2 CPU cores):
>= 5e7 transitions/s and >= 10x NumPy; a jitted 15-step replan called from Python in
<= 25 us; >= 3e6 batched 15-step replans/s.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np
from _common import compile_seconds, parse_args, print_table, target, time_calls, write_json
from _numpy_psp import plan_step_numpy

from jaxloco.learning import load_planner
from jaxloco.planner import PSPParams, make_lookahead_policy, plan_step, plan_steps
from jaxloco.runtime import watchdog

P = PSPParams()
HORIZON = 15
STATE_LOW, STATE_HIGH = np.array([-0.14, 0.03, -0.55]), np.array([0.20, 0.61, 0.55])


def draw(rng, n):
    states = rng.uniform(STATE_LOW, STATE_HIGH, (n, 3)).astype(np.float32)
    actions = rng.uniform(P.action_low, P.action_high, (n, 3)).astype(np.float32)
    return states, actions


def check_numpy_matches(states, actions) -> float:
    """Max |difference| of next_state between NumPy and JAX on safe steps (float64)."""
    s64, a64 = states[:20000].astype(np.float64), actions[:20000].astype(np.float64)
    with jax.enable_x64(True):
        ref = plan_step(jnp.asarray(s64), jnp.asarray(a64), P)
        ref_next = np.asarray(ref.next_state)
        ref_term = np.asarray(ref.terminal)
    got = plan_step_numpy(s64, a64, P)
    assert np.array_equal(got["terminal"], ref_term), "NumPy baseline disagrees on terminal"
    safe = ~ref_term
    err = float(np.max(np.abs(got["next_state"][safe] - ref_next[safe])))
    assert err < 1e-9, f"NumPy baseline disagrees with the JAX planner: {err}"
    return err


def bench_transitions(n, repeats):
    rng = np.random.default_rng(0)
    states, actions = draw(rng, n)
    err = check_numpy_matches(states, actions)
    s, a = jnp.asarray(states), jnp.asarray(actions)

    full = jax.jit(lambda s, a: plan_step(s, a, P))

    def rl_fields(s, a):
        plan = plan_step(s, a, P)
        return plan.next_state, plan.reward, plan.terminal

    rl = jax.jit(rl_fields)

    def output_floor(s, a):
        # Writes exactly the StepPlan's shapes and dtypes with one arithmetic op each: the
        # cost of producing the outputs alone (the profile row for the full plan).
        shapes = jax.eval_shape(lambda s, a: plan_step(s, a, P), s, a)
        base = s[:, 0] * a[:, 0] + s[:, 1]
        leaves, treedef = jax.tree.flatten(shapes)
        out = []
        for i, leaf in enumerate(leaves):
            x = base + i
            x = jnp.broadcast_to(x[:, None], leaf.shape) if len(leaf.shape) == 2 else x
            out.append(x > 0 if leaf.dtype == jnp.bool_ else x.astype(leaf.dtype))
        return jax.tree.unflatten(treedef, out)

    rows = []
    t_np = time_calls(plan_step_numpy, states, actions, P, repeats=max(3, repeats // 3))
    np_rate = n / t_np["median_s"]
    rows.append(
        dict(
            case="NumPy, all fields (baseline)",
            size=n,
            rate=np_rate,
            rate_p10=n / t_np["p10_s"],
            **t_np,
        )
    )
    cases = (
        ("JAX jit, full StepPlan", full),
        ("JAX jit, RL fields", rl),
        ("output floor: write StepPlan-sized outputs (profile)", jax.jit(output_floor)),
    )
    for name, fn in cases:
        compile_s, compiled = compile_seconds(fn, s, a)
        t = time_calls(fn, s, a, repeats=repeats)
        rate = n / t["median_s"]
        rows.append(
            dict(
                case=name,
                size=n,
                rate=rate,
                rate_p10=n / t["p10_s"],
                compile_s=compile_s,
                vs_baseline=rate / np_rate,
                fusions=count_fusions(compiled),
                **t,
            )
        )
    return rows, err


def count_fusions(compiled) -> int:
    """Loop fusions in the compiled XLA program: each one streams its arrays through memory."""
    return sum(" fusion(" in line for line in compiled.as_text().splitlines())


def bench_latency(repeats):
    s0 = jnp.asarray(P.nominal_state, jnp.float32)
    actions = jnp.tile(jnp.asarray([0.3, 0.2, 0.0], jnp.float32), (HORIZON, 1))
    lookahead = make_lookahead_policy(P)
    learned = load_planner(shipped="algorithm1")  # the RL-PSP policy shipped in assets/

    def compact(plan):
        return plan.footsteps, plan.t_switch, plan.t_apex, plan.alive

    cases = {
        "trivial jit call (dispatch floor)": jax.jit(lambda s: s + 1.0),
        "15 steps, actions -> footsteps+times": jax.jit(
            lambda s: compact(plan_steps(s, actions, P))
        ),
        "15 steps, actions -> full FootstepPlan": jax.jit(lambda s: plan_steps(s, actions, P)),
        "15 steps, learned RL-PSP policy -> footsteps+times": jax.jit(
            lambda s: compact(plan_steps(s, learned.policy, P, num_steps=HORIZON))
        ),
        "15 steps, lookahead policy -> footsteps+times": jax.jit(
            lambda s: compact(plan_steps(s, lookahead, P, num_steps=HORIZON))
        ),
    }
    rows = []
    # Baseline: the same 15 straight steps in NumPy, one call per step.
    s_np, a_np = np.asarray(s0)[None], np.asarray(actions[:1])

    def numpy_replan():
        state = s_np
        for _ in range(HORIZON):
            state = plan_step_numpy(state, a_np, P)["next_state"]
        return state

    t_np = time_calls(numpy_replan, repeats=repeats, inner=20)
    rows.append(dict(case="NumPy 15-step loop (baseline)", latency_us=t_np["median_s"] * 1e6))
    for name, fn in cases.items():
        compile_s, _ = compile_seconds(fn, s0)
        inner = 200 if "lookahead" not in name else 20
        t = time_calls(fn, s0, repeats=repeats, inner=inner, warmup=20)
        rows.append(
            dict(
                case=name,
                latency_us=t["median_s"] * 1e6,
                p90_us=t["p90_s"] * 1e6,
                compile_s=compile_s,
                vs_baseline=t_np["median_s"] / t["median_s"],
            )
        )
    return rows


def bench_batched_replans(batch, repeats):
    rng = np.random.default_rng(1)
    states, _ = draw(rng, batch)
    actions = rng.uniform(P.action_low, P.action_high, (batch, HORIZON, 3)).astype(np.float32)

    def replan(s, a):
        plan = plan_steps(s, a, P)
        return plan.footsteps, plan.t_switch, plan.t_apex, plan.alive

    fn = jax.jit(jax.vmap(replan))
    s, a = jnp.asarray(states), jnp.asarray(actions)
    compile_s, compiled = compile_seconds(fn, s, a)
    t = time_calls(fn, s, a, repeats=repeats)

    def numpy_replans(states, actions):
        state = states
        for k in range(HORIZON):
            out = plan_step_numpy(state, actions[:, k], P)
            state = out["next_state"]
        return state

    t_np = time_calls(numpy_replans, states, actions, repeats=max(3, repeats // 3))
    rate, np_rate = batch / t["median_s"], batch / t_np["median_s"]
    return [
        dict(case="NumPy 15 vectorised steps (baseline)", size=batch, rate=np_rate, **t_np),
        dict(
            case="JAX jit(vmap(plan_steps)) -> footsteps+times",
            size=batch,
            rate=rate,
            compile_s=compile_s,
            vs_baseline=rate / np_rate,
            fusions=count_fusions(compiled),
            **t,
        ),
    ]


def main():
    args = parse_args(__doc__.splitlines()[0])
    n = 10**5 if args.quick else 10**6
    batch = 2**14 if args.quick else 2**17
    repeats = 5 if args.quick else 21
    t_start = time.perf_counter()
    with watchdog(args.timeout, "bench_planner"):
        transitions, np_err = bench_transitions(n, repeats)
        latency = bench_latency(repeats)
        replans = bench_batched_replans(batch, repeats)

    tables = []
    tables.append(
        print_table(
            f"PSP transitions per second (float32, {n:,} states)",
            transitions,
            [
                ("case", "case", "s"),
                ("rate", "transitions/s", ".3g"),
                ("rate_p10", "fastest 10%", ".3g"),
                ("median_s", "median s", ".4f"),
                ("compile_s", "compile s", ".2f"),
                ("vs_baseline", "x NumPy", ".1f"),
                ("fusions", "XLA fusions", "d"),
            ],
        )
    )
    print(f"(NumPy baseline agrees with the JAX planner: max |next_state diff| {np_err:.1e})")
    print("targets: >= 5e7 transitions/s and >= 10x NumPy")
    tables.append(
        print_table(
            f"{HORIZON}-step replan latency, one jitted call from Python",
            latency,
            [
                ("case", "case", "s"),
                ("latency_us", "median us", ".1f"),
                ("p90_us", "p90 us", ".1f"),
                ("compile_s", "compile s", ".2f"),
                ("vs_baseline", "x NumPy loop", ".1f"),
            ],
        )
    )
    print("target: <= 25 us (the paper: 15 steps in < 1 ms)")
    tables.append(
        print_table(
            f"batched {HORIZON}-step replans ({batch:,} start states)",
            replans,
            [
                ("case", "case", "s"),
                ("rate", "replans/s", ".3g"),
                ("median_s", "median s", ".4f"),
                ("compile_s", "compile s", ".2f"),
                ("vs_baseline", "x NumPy", ".1f"),
                ("fusions", "XLA fusions", "d"),
            ],
        )
    )
    print("target: >= 3e6 replans/s")
    print(f"\ntotal wall time {time.perf_counter() - t_start:.1f} s")
    full = next(r for r in transitions if r["case"] == "JAX jit, full StepPlan")
    replan = next(r for r in latency if r["case"].endswith("actions -> footsteps+times"))
    batched = next(r for r in replans if r["case"].startswith("JAX"))
    targets = [
        target("PSP transitions/s (JAX, full StepPlan)", full["rate"], 5e7, "/s", at_most=False),
        target("PSP transitions, JAX over NumPy", full["vs_baseline"], 10, "x", at_most=False),
        target(f"{HORIZON}-step replan latency, one jitted call", replan["latency_us"], 25, "us"),
        target(f"batched {HORIZON}-step replans/s", batched["rate"], 3e6, "/s", at_most=False),
    ]
    write_json(
        args.json,
        "bench_planner",
        {
            "quick": args.quick,
            "transitions": transitions,
            "numpy_baseline_max_abs_diff": np_err,
            "replan_latency": latency,
            "batched_replans": replans,
        },
        tables=tables,
        targets=targets,
    )


if __name__ == "__main__":
    main()
