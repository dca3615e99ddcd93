"""Cost of a gradient through the closed loop, against a forward rollout of the same horizon.

    python benchmarks/bench_tuning.py [--json PATH] [--quick]

The body-shaking tuning problem (:func:`jaxloco.tuning.problems.shaking_loss`: WBLC H2 +
``mjx.step`` with one solver iteration, float32), four gains (body and pelvis orientation
kp and kd), one rollout (no push), horizon 1000 ticks = 1 s (``--quick``: 200). In the
same run:

- **forward**: the loss alone (the baseline);
- **grad (forward mode)**: :func:`jaxloco.tuning.optimize.value_and_grad` with
  ``"forward"``: one ``jvp`` tangent per parameter, vmapped;
- **grad (reverse mode)**: ``jax.value_and_grad`` with every tick checkpointed (segment 1);
- **grad (forward mode), 1 parameter**: the default ``tune-gains`` parameterisation, the
  body task's bandwidth (kp and kd together), one tangent.

Per row: compile time (AOT ``lower().compile()``, split into JAX's tracing, lowering and
XLA's compile, with the seconds the persistent cache saved), steady-state time per call, the
ratio to the forward rollout, and XLA's buffer sizes for the compiled call
(``memory_analysis``: temporaries, the peak working memory, and arguments + outputs).
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
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
    time_calls,
    write_json,
)

from jaxloco.dynamics.model import load_valkyrie  # noqa: E402
from jaxloco.runtime import enable_compilation_cache, watchdog  # noqa: E402
from jaxloco.sim.push import PushArrays  # noqa: E402
from jaxloco.tuning.gains import GainSpace  # noqa: E402
from jaxloco.tuning.optimize import value_and_grad  # noqa: E402
from jaxloco.tuning.problems import ShakingLossParams, shaking_loss  # noqa: E402
from jaxloco.tuning.rollout import tuning_physics  # noqa: E402

TUNED = ("body_ori.kp", "body_ori.kd", "pelvis_ori.kp", "pelvis_ori.kd")


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    enable_compilation_cache()
    steps = 200 if args.quick else 1000
    repeats = 2 if args.quick else 3
    model = tuning_physics(load_valkyrie())
    space = GainSpace(TUNED)
    problem = ShakingLossParams(horizon=steps * model.opt.timestep, segment=1)
    loss, p0, _ = shaking_loss(model, space, problem)
    pushes = PushArrays.none(dtype=np.float32)

    def fn(p):
        return loss(p, pushes)

    space1 = GainSpace(("body_ori.bandwidth",))
    loss1, p1, _ = shaking_loss(model, space1, problem)

    def fn1(p):
        return loss1(p, pushes)

    variants = {
        "forward": (jax.jit(lambda p: fn(p)[0]), p0),
        "grad (forward mode)": (jax.jit(value_and_grad(fn, "forward")), p0),
        "grad (reverse mode)": (jax.jit(value_and_grad(fn, "reverse")), p0),
        "grad (forward mode), 1 parameter": (jax.jit(value_and_grad(fn1, "forward")), p1),
    }
    rows = []
    with watchdog(args.timeout, "bench_tuning"):
        for name, (jitted, params) in variants.items():
            with compile_split() as split:
                compile_s, compiled = compile_seconds(jitted, params)
            mem = compiled.memory_analysis()
            t = time_calls(compiled, params, repeats=repeats, warmup=1)
            row = {
                "variant": name,
                "ticks": steps,
                "params": len(params),
                "compile_s": compile_s,
                **split,
                "time_s": t["median_s"],
                "ms_per_tick": 1e3 * t["median_s"] / steps,
                "temp_MB": getattr(mem, "temp_size_in_bytes", 0) / 1e6 if mem else None,
                "args_out_MB": (
                    (mem.argument_size_in_bytes + mem.output_size_in_bytes) / 1e6 if mem else None
                ),
                "timing": t,
            }
            rows.append(row)
            print(f"{name}: compile {compile_s:.0f} s, {t['median_s']:.2f} s per call", flush=True)
    base = rows[0]["time_s"]
    for r in rows:
        r["ratio_to_forward"] = r["time_s"] / base
    tables = []
    tables.append(
        print_table(
            f"Gradient cost vs forward rollout (body shaking, {steps} ticks, 1 robot, float32)",
            rows,
            [
                ("variant", "variant", "s"),
                ("params", "params", "d"),
                ("compile_s", "compile s", ".1f"),
                ("trace_s", "trace s", ".1f"),
                ("lower_s", "lower s", ".1f"),
                ("xla_compile_s", "XLA compile s", ".1f"),
                ("cache_saved_s", "saved by the cache s", ".1f"),
                ("time_s", "s/call", ".3f"),
                ("ms_per_tick", "ms/tick", ".2f"),
                ("ratio_to_forward", "x forward", ".2f"),
                ("temp_MB", "temp MB", ".1f"),
                ("args_out_MB", "args+out MB", ".2f"),
            ],
        )
    )
    by = {r["variant"]: r for r in rows}
    gradients = ("grad (forward mode), 1 parameter", "grad (reverse mode)")
    # A gradient should cost a few rollouts, not one rollout per parameter, and compile in
    # well under a minute.
    targets = [
        target(f"{name}, time over the forward rollout", by[name]["ratio_to_forward"], 4, "x")
        for name in gradients
    ] + [target(f"{name}, compile seconds", by[name]["compile_s"], 45, "s") for name in gradients]
    print_targets(targets)
    write_json(
        args.json,
        "tuning",
        {"ticks": steps, "params": list(TUNED), "rows": rows},
        tables=tables,
        targets=targets,
    )


if __name__ == "__main__":
    main()
