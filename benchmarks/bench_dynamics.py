"""Dynamics per control tick: A, b, g and every Jacobian and J-dot q-dot of the walking
hierarchy (8 tasks) on the Valkyrie model; single call and batched.

    python benchmarks/bench_dynamics.py [--json PATH] [--quick]

The walking hierarchy (paper Section V-B) needs: CoM (J, Jdot qd), pelvis, body and both
feet as frames (J, Jdot qd; the foot position and orientation tasks share the foot frame),
centroidal momentum (J_cm, Eq. 31) and two joint-posture tasks (constant Jacobians).
Baselines in the same run: J-dot q-dot by ``jax.jvp`` of the Jacobians, and MuJoCo's C
``mj_jacDot`` (plus mj_forward) called per state from Python. float32 unless noted.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import mujoco
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
from mujoco import mjx

from jaxloco.dynamics import centroidal as C
from jaxloco.dynamics import jacobians as J
from jaxloco.dynamics.model import keyframe_qpos, load_valkyrie
from jaxloco.dynamics.terms import joint_space_terms
from jaxloco.runtime import watchdog

FRAMES = ("pelvis", "torso", "left_foot_cop", "right_foot_cop")


def make_tick(model, mx):
    sites = [(model.site(s).id, int(model.site_bodyid[model.site(s).id])) for s in FRAMES]

    def tick(d):
        d = J.smooth(mx, d)
        terms = joint_space_terms(mx, d, smoothed=True)
        motion = J.body_motion(mx, d)
        frames = [
            (
                J.frame_jacobian(mx, d, d.site_xpos[s], b),
                J.frame_jdot_qdot(mx, d, d.site_xpos[s], b, motion),
            )
            for s, b in sites
        ]
        com = (J.com_jacobian(mx, d), J.com_jdot_qdot(mx, d, motion))
        jcm = C.centroidal_momentum_matrix(mx, d)
        cam = (jcm, C.centroidal_bias(jcm, terms.mass_matrix, terms.coriolis))
        return terms, frames, com, cam

    return tick, sites


def make_jvp_jdot(model, mx, sites):
    """Jdot qd of the same frames and CoM by jax.jvp of the Jacobians (hinges + free joint)."""

    def jdot(d):
        qpos0, qvel = d.qpos, d.qvel

        def qpos_at(e):
            w = e * qvel[3:6]
            angle = jnp.sqrt(jnp.sum(w**2) + 1e-12)
            dq = jnp.concatenate([jnp.cos(angle / 2)[None], jnp.sin(angle / 2) * w / angle])
            q = qpos0[3:7]
            quat = jnp.stack(
                [
                    q[0] * dq[0] - q[1] * dq[1] - q[2] * dq[2] - q[3] * dq[3],
                    q[0] * dq[1] + q[1] * dq[0] + q[2] * dq[3] - q[3] * dq[2],
                    q[0] * dq[2] - q[1] * dq[3] + q[2] * dq[0] + q[3] * dq[1],
                    q[0] * dq[3] + q[1] * dq[2] - q[2] * dq[1] + q[3] * dq[0],
                ]
            )
            return jnp.concatenate([qpos0[:3] + e * qvel[:3], quat, qpos0[7:] + e * qvel[6:]])

        def velocities(e):
            dd = mjx.com_pos(mx, mjx.kinematics(mx, d.replace(qpos=qpos_at(e))))
            out = [J.frame_jacobian(mx, dd, dd.site_xpos[s], b) @ qvel for s, b in sites]
            return jnp.concatenate([*out, J.com_jacobian(mx, dd) @ qvel])

        return jax.jvp(velocities, (jnp.zeros((), qvel.dtype),), (jnp.ones((), qvel.dtype),))[1]

    return jdot


def main():
    args = parse_args(__doc__.splitlines()[0])
    batch = 64 if args.quick else 1024
    repeats = 5 if args.quick else 21
    model = load_valkyrie()
    mx = mjx.put_model(model)
    data = mujoco.MjData(model)
    data.qpos[:] = keyframe_qpos(model, "walk")
    rng = np.random.default_rng(0)
    data.qvel[:] = rng.normal(0, 0.5, model.nv)
    dx = mjx.put_data(model, data)
    batch_d = jax.tree.map(
        lambda x: jnp.broadcast_to(x, (batch, *x.shape)) if hasattr(x, "shape") else x, dx
    )
    batch_d = batch_d.replace(qvel=jnp.asarray(rng.normal(0, 0.5, (batch, model.nv)), jnp.float32))

    tick, sites = make_tick(model, mx)
    jvp_jdot = make_jvp_jdot(model, mx, sites)

    def ours_jdot(d):
        d = J.smooth(mx, d)
        motion = J.body_motion(mx, d)
        out = [J.frame_jdot_qdot(mx, d, d.site_xpos[s], b, motion) for s, b in sites]
        return jnp.concatenate([*out, J.com_jdot_qdot(mx, d, motion)])

    def jvp_with_smooth(d):
        return jvp_jdot(J.smooth(mx, d))

    rows = []
    with watchdog(args.timeout, "bench_dynamics"):
        for name, fn in (
            ("full walking-hierarchy tick (A, b, g, 8 tasks)", tick),
            ("J-dot q-dot: Lie group (4 frames + CoM)", ours_jdot),
            (
                "J-dot q-dot: jax.jvp of the Jacobians (baseline)",
                lambda d: jvp_jdot(J.smooth(mx, d)),
            ),
        ):
            single = jax.jit(fn)
            comp, _ = compile_seconds(single, dx)
            t1 = time_calls(single, dx, repeats=repeats, inner=20)
            batched = jax.jit(jax.vmap(fn))
            comp_b, _ = compile_seconds(batched, batch_d)
            tb = time_calls(batched, batch_d, repeats=max(3, repeats // 3))
            rows.append(
                dict(
                    case=name,
                    single_us=t1["median_s"] * 1e6,
                    batched_us_per_state=tb["median_s"] / batch * 1e6,
                    compile_s=comp,
                    compile_batched_s=comp_b,
                )
            )

        # MuJoCo C: mj_forward + mj_jacDot for the same frames and the CoM, per state.
        jdp, jdr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        qvel_np = np.asarray(batch_d.qvel, np.float64)

        def c_loop(n):
            for k in range(n):
                data.qvel[:] = qvel_np[k % batch]
                mujoco.mj_forward(model, data)
                for s, b in sites:
                    mujoco.mj_jacDot(model, data, jdp, jdr, data.site_xpos[s], b)
                    _ = jdr @ data.qvel, jdp @ data.qvel
                for b in range(1, model.nbody):
                    mujoco.mj_jacDot(model, data, jdp, None, data.xipos[b], b)

        n = 50 if args.quick else 400
        t0 = time.perf_counter()
        c_loop(n)
        c_us = (time.perf_counter() - t0) / n * 1e6
        rows.append(
            dict(
                case="J-dot q-dot: MuJoCo C mj_forward + mj_jacDot per state",
                single_us=c_us,
                batched_us_per_state=c_us,
            )
        )

    # Agreement of the three J-dot q-dot computations on one state (float32).
    ours = np.asarray(jax.jit(ours_jdot)(dx))
    by_jvp = np.asarray(jax.jit(jvp_with_smooth)(dx))
    base = rows[1]["single_us"]
    for r in rows:
        r["vs_lie_group"] = r["single_us"] / base
    tables = []
    tables.append(
        print_table(
            f"Valkyrie dynamics per control tick (batch {batch} for the batched column)",
            rows,
            [
                ("case", "case", "s"),
                ("single_us", "single call us", ".1f"),
                ("batched_us_per_state", "batched us/state", ".2f"),
                ("compile_s", "compile s", ".1f"),
                ("compile_batched_s", "compile (vmap) s", ".1f"),
                ("vs_lie_group", "time / Lie group", ".2f"),
            ],
        )
    )
    print(f"max |Lie group - jvp| (float32): {np.abs(ours - by_jvp).max():.2e}")
    lie, jvp, c_row = rows[1], rows[2], rows[3]
    targets = [
        target(
            "J-dot q-dot, one call: jax.jvp time over Lie group time",
            jvp["single_us"] / lie["single_us"], 1, "x", at_most=False,
        ),
        target(
            "J-dot q-dot, batched: jax.jvp time over Lie group time",
            jvp["batched_us_per_state"] / lie["batched_us_per_state"], 1, "x", at_most=False,
        ),
        target(
            "J-dot q-dot, batched per state: MuJoCo C time over Lie group time",
            c_row["batched_us_per_state"] / lie["batched_us_per_state"], 1, "x", at_most=False,
        ),
    ]  # fmt: skip
    print_targets(targets)
    write_json(
        args.json,
        "bench_dynamics",
        {
            "quick": args.quick,
            "batch": batch,
            "rows": rows,
            "lie_vs_jvp_max_abs": float(np.abs(ours - by_jvp).max()),
        },
        tables=tables,
        targets=targets,
    )


if __name__ == "__main__":
    main()
