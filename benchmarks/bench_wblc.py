"""WBLC per control tick on Valkyrie: latency, batched throughput, a profile by stage, the
force QP's accuracy against quadprog by iteration count, what keeping the legs within
their effort limits in the force QP costs (``torque_limits_in_qp``, interleaved with the
paper's WBLC), a row per shipped robot (Valkyrie, Unitree G1, Apptronik Apollo: one call and
batch 64, compiled for one core as the closed loops and sweeps compile them, each side by
side with PlaCo), and PlaCo's C++ whole-body QP.

    python benchmarks/bench_wblc.py [--json PATH] [--quick]

The tick is the walking hierarchy in double support (``jaxloco.control.presets``), float32,
called as users call it: ``jax.jit`` of ``WBLC.__call__`` from Python; the rows "MuJoCo C's
terms" read the state's dynamics from MuJoCo C (``EngineTerms`` after ``mj_step1``), as
the C loops do, instead of computing them with MJX. Stages are timed as
separate jitted functions on the same state to show what bounds the time, and, batched
as sweeps run it, by ablation: the whole vmapped tick with its stages replaced, one more at a
time, by stand-ins of the same shapes (the force QP by an equal share of the net force, the
task hierarchy by zeros, the torque solve by the task torques), so the differences
are what each stage costs inside the real tick. The peer, when
``placo`` and ``example-robot-data`` are installed (``pip install -e .[bench]``), is
PlaCo's ``DynamicsSolver`` on the Talos humanoid (nv = 38): two foot contacts, CoM, trunk
orientation and joint posture, one ``solve(True)`` per tick.

The process runs on one core (the peer is single-threaded; sweeps run one worker per
core). The batched tick is compared with the peer side by side: one batch-64 call and 50
peer ticks per round, interleaved (each after an untimed warm-up call), so that the
machine's slow spells fall on both; the target is the median over rounds of their ratio.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
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
    interleaved,
    parse_args,
    pin_to_one_core,
    print_table,
    target,
    time_calls,
    write_json,
)

from jaxloco.control import force_qp, hierarchy  # noqa: E402
from jaxloco.control import wblc as wblc_module  # noqa: E402
from jaxloco.control.presets import walking_config  # noqa: E402
from jaxloco.control.wblc import make_wblc  # noqa: E402
from jaxloco.dynamics.engine_terms import engine_terms  # noqa: E402
from jaxloco.dynamics.model import keyframe_qpos, load_valkyrie  # noqa: E402
from jaxloco.robots import ROBOTS  # noqa: E402
from jaxloco.runtime import single_thread_compiler_options, watchdog  # noqa: E402

SWING = ("left_foot_ori", "right_foot_ori", "left_foot_pos", "right_foot_pos")


def setup():
    model = load_valkyrie()
    data = mujoco.MjData(model)
    data.qpos[:] = keyframe_qpos(model, "walk")
    mujoco.mj_forward(model, data)
    ctrl = make_wblc(model, walking_config())
    refs = ctrl.hold_references(jnp.asarray(data.qpos, jnp.float32))
    for name in SWING:
        refs[name] = refs[name].replace(weight=jnp.zeros((), jnp.float32))
    return model, data, ctrl, refs


def stage_functions(ctrl, refs):
    """The tick's stages as separate functions (same inputs), for the profile."""
    from jaxloco.control.tasks import task_terms

    cfg = ctrl.config
    gains = ctrl.default_gains()

    def snapshot(q, v):
        # The arrays the tick reads, not the whole mjx.Data (~100 buffers to return).
        return ctrl.snapshot(q, v).replace(data=None)

    def tasks(q, v):
        snap = ctrl.snapshot(q, v)
        return [
            task_terms(ctrl.mx, t, ctrl.indices[t.name], snap, refs[t.name], gains[t.name])
            for t in cfg.tasks
            if t.name in cfg.level_tasks()
        ]

    def qp_only(points, contact, com, f_lin, f_ang):
        return force_qp.solve_contact_forces(points, contact, com, f_lin, f_ang, cfg.force_qp)

    return {
        "dynamics snapshot (A, b, g, J_cm, Jdot qd)": snapshot,
        "snapshot + all tasks": tasks,
    }, qp_only


def _qp_stand_in(
    points, in_contact, com, f_lin, f_ang, params, fz_max=None, warm_start=None, torques=None
):
    n = points.shape[0]
    zero = jnp.zeros((), points.dtype)
    forces = jnp.zeros((n, 3), points.dtype) + f_lin / n
    return force_qp.ForceQPSolution(
        forces=forces,
        angular=f_ang,
        linear_residual=zero,
        primal_residual=zero,
        relaxed=zero > 0,
        infeasible=zero > 0,
        torque_excess=zero,
        warm_start=warm_start,
    )


def _hierarchy_stand_in(jacs, cmds, mass_cholesky, rtol, whiten, inverse, cholesky_inverse):
    nv = mass_cholesky.shape[0]
    # Touch every input so that nothing upstream is dead code.
    qdd = jnp.zeros((nv, cmds[0].shape[1])) + sum(jnp.sum(j) for j in jacs) * 0 + cmds[0][0]
    projector = jnp.eye(nv) * mass_cholesky[0, 0]
    return hierarchy.HierarchyResult(qdd, projector, mass_cholesky, cholesky_inverse, tuple(cmds))


def _torque_stand_in(ctrl, a_null, tau_task, rtol):
    dofs = jnp.asarray(ctrl.actuated_dofs)
    base = jnp.asarray(ctrl.unactuated_dofs)
    return wblc_module.TorqueSolution(
        tau_task[dofs] + a_null[0, 0], jnp.zeros_like(tau_task), tau_task[base]
    )


TORQUE_ROWS_TARGET = "torque rows in the force QP, batch 64, over the plain tick"


def engine_rows(model, data, ctrl, refs, v, contact, prev, rows, repeats, batch=64):
    """The tick on MuJoCo C's own terms of the state (``EngineTerms`` after ``mj_step1``),
    as the C loops and the sweeps' C backend call and compile it: one call and a batch."""
    d = mujoco.MjData(model)
    d.qpos[:], d.qvel[:] = data.qpos, np.asarray(v)
    mujoco.mj_step1(model, d)
    engine = engine_terms(d)  # numpy float64, converted at the call as the loops do

    def tick(e, p):
        snap = ctrl.snapshot(None, None, e)
        return ctrl(e.qpos, e.qvel, refs, contact, previous=p, snap=snap)

    # Compiled as the closed loops (one robot) and the sweeps' workers (a batch) compile
    # it: single-threaded, XLA's own matrix products.
    one = jax.jit(tick, compiler_options=single_thread_compiler_options())
    comp, _ = compile_seconds(one, engine, prev)
    t1 = time_calls(one, engine, prev, repeats=repeats, inner=20)
    rows.append(
        dict(
            case="WBLC tick, single jitted call, MuJoCo C's terms, as the C loops compile it",
            per_tick_us=t1["median_s"] * 1e6,
            ticks_per_s=1 / t1["median_s"],
            compile_s=comp,
        )
    )
    eb = jax.tree.map(lambda x: np.broadcast_to(x, (batch, *x.shape)).copy(), engine)
    pb = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), prev)
    batched = jax.jit(jax.vmap(tick), compiler_options=single_thread_compiler_options())
    comp_b, _ = compile_seconds(batched, eb, pb)
    tb = time_calls(batched, eb, pb, repeats=3 * repeats)
    rows.append(
        dict(
            case=f"WBLC tick, vmap batch {batch}, MuJoCo C's terms, as the C sweeps compile it",
            per_tick_us=tb["median_s"] / batch * 1e6,
            ticks_per_s=batch / tb["median_s"],
            compile_s=comp_b,
        )
    )


def torque_limits_cost(model, refs, q, batch: int, rounds: int) -> dict:
    """The batched tick without limits, with ``torque_limits_in_qp`` and with
    ``whole_body_limits`` on top, interleaved: what keeping the legs, then every joint,
    within their effort limits costs."""
    contact = jnp.ones(2, jnp.float32)
    v = jnp.asarray(np.random.default_rng(1).normal(0, 0.1, (batch, model.nv)), jnp.float32)
    qb = jnp.broadcast_to(q, (batch, model.nq))
    calls, compile_s = {}, 0.0
    settings = {
        "plain": {"torque_limits_in_qp": False},
        "limited": {"torque_limits_in_qp": True},
        "whole_body": {"torque_limits_in_qp": True, "whole_body_limits": True},
    }
    for name, flags in settings.items():
        c = make_wblc(model, walking_config(**flags))
        prev = c.initial_qp_state(jnp.float32)
        pb = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), prev)
        tick = jax.jit(jax.vmap(lambda q, v, p, c=c: c(q, v, refs, contact, previous=p)))
        seconds, compiled = compile_seconds(tick, qb, v, pb)
        compile_s = seconds if name == "limited" else compile_s
        calls[name] = (lambda compiled=compiled, pb=pb: compiled(qb, v, pb), batch)
    t = interleaved(calls, rounds)
    return dict(
        plain_us=t["plain"] * 1e6,
        limited_us=t["limited"] * 1e6,
        whole_body_us=t["whole_body"] * 1e6,
        ratio=1.0 / t["plain/limited"],
        whole_body_ratio=1.0 / t["plain/whole_body"],
        compile_s=compile_s,
        rounds=rounds,
    )


def robot_rows(peer, batch: int, repeats: int, rounds: int) -> list[dict]:
    """Per shipped robot: the walking WBLC as its walking controller builds it (the G1's
    and Apollo's with torque rows in the force QP), standing in its keyframe: one jitted
    call, and the batch-``batch`` tick interleaved with PlaCo's tick when installed, both
    compiled as the closed loops and the sweeps compile the controller for one core
    (``single_thread_compiler_options``)."""
    rows = []
    contact = jnp.ones(2, jnp.float32)
    for robot in ROBOTS.values():
        model = robot.load()
        c = make_wblc(model, walking_config(robot))
        q = jnp.asarray(robot.keyframe_qpos(model), jnp.float32)
        refs = c.hold_references(q)
        for name in SWING:
            refs[name] = refs[name].replace(weight=jnp.zeros((), jnp.float32))
        prev = c.initial_qp_state(jnp.float32)
        v = jnp.asarray(np.random.default_rng(0).normal(0, 0.1, model.nv), jnp.float32)
        one = jax.jit(
            lambda q, v, p, c=c, refs=refs: c(q, v, refs, contact, previous=p),
            compiler_options=single_thread_compiler_options(),
        )
        comp1, _ = compile_seconds(one, q, v, prev)
        t1 = time_calls(one, q, v, prev, repeats=repeats, inner=20)
        qb = jnp.broadcast_to(q, (batch, model.nq))
        vb = jnp.asarray(np.random.default_rng(1).normal(0, 0.1, (batch, model.nv)), jnp.float32)
        pb = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), prev)
        batched = jax.jit(
            jax.vmap(lambda q, v, p, c=c, refs=refs: c(q, v, refs, contact, previous=p)),
            compiler_options=single_thread_compiler_options(),
        )
        comp_b, compiled = compile_seconds(batched, qb, vb, pb)
        row = dict(
            robot=robot.name,
            nv=model.nv,
            contact_points=len(c.point_sites),
            torque_rows=c.config.torque_limits_in_qp,
            single_us=t1["median_s"] * 1e6,
            single_compile_s=comp1,
            batch_compile_s=comp_b,
        )
        if peer is not None:
            duel = head_to_head(compiled, (qb, vb, pb), batch, peer, rounds)
            row.update(
                batch_us=duel["ours_per_robot_tick_us"],
                peer_us=duel["peer_per_tick_us"],
                batch_over_peer=duel["median_ratio"],
            )
        else:
            tb = time_calls(compiled, qb, vb, pb, repeats=3 * repeats)
            row.update(batch_us=tb["median_s"] / batch * 1e6)
        rows.append(row)
    return rows


def ablation_rows(ctrl, refs, q, batch: int, repeats: int) -> list[dict]:
    """The vmapped tick with stages replaced by stand-ins, cumulatively (see module doc)."""
    from unittest import mock

    contact = jnp.ones(2, jnp.float32)
    qb = jnp.broadcast_to(q, (batch, q.shape[0]))
    vb = jnp.asarray(np.random.default_rng(1).normal(0, 0.1, (batch, ctrl.mx.nv)), jnp.float32)
    prev = ctrl.initial_qp_state(jnp.float32)
    pb = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), prev)
    patches = [
        ("force QP", mock.patch.object(wblc_module.force_qp, "solve_contact_forces", _qp_stand_in)),
        (
            "task hierarchy",
            mock.patch.object(wblc_module, "prioritized_accelerations", _hierarchy_stand_in),
        ),
        (
            "torque solve (Eq. 19)",
            mock.patch.object(wblc_module, "torque_solution", _torque_stand_in),
        ),
    ]
    rows, removed = [], []

    def measure(label):
        fn = jax.jit(jax.vmap(lambda q, v, p: ctrl(q, v, refs, contact, previous=p)))
        compile_seconds(fn, qb, vb, pb)
        t = time_calls(fn, qb, vb, pb, repeats=repeats)
        rows.append(dict(case=label, per_tick_us=t["median_s"] / batch * 1e6))

    measure(f"vmap batch {batch}: whole tick")
    with contextlib.ExitStack() as stack:
        for name, patch in patches:
            stack.enter_context(patch)
            removed.append(name)
            measure(f"vmap batch {batch}: without " + ", ".join(removed))
    snap = jax.jit(jax.vmap(ctrl.snapshot))
    compile_seconds(snap, qb, vb)
    t = time_calls(snap, qb, vb, repeats=repeats)
    rows.append(
        dict(
            case=f"vmap batch {batch}: dynamics snapshot alone",
            per_tick_us=t["median_s"] / batch * 1e6,
        )
    )
    whole = rows[0]["per_tick_us"]
    for r in rows:
        r["share_of_tick"] = r["per_tick_us"] / whole
    return rows


def qp_accuracy_table(n: int) -> list[dict]:
    """Run in a float64 subprocess: objective error and violation vs quadprog."""
    code = f"""
import json, sys, numpy as np, jax, jax.numpy as jnp
import jaxloco
jax.config.update("jax_enable_x64", True)
sys.path.insert(0, "tests")
from test_force_qp import contact_problem, reference_forces, relative_errors
from jaxloco.control.force_qp import ForceQPParams, solve_contact_forces
rng = np.random.default_rng(11)
probs = [contact_problem(rng) for _ in range({n})]
refs = [reference_forces(*p) for p in probs]
batch = [jnp.asarray(np.stack(z)) for z in zip(*probs)]
rows = []
for it in (50, 100, 200, 300, 500, 800):
    prm = ForceQPParams(iterations=it)
    sol = jax.jit(jax.vmap(lambda *a: solve_contact_forces(*a, params=prm)))(*batch)
    errs = relative_errors(probs, refs, sol)
    rows.append(dict(
        iterations=it, median_rel_obj=float(np.median(errs)),
        max_rel_obj=float(errs.max()), frac_within_1e3=float(np.mean(errs < 1e-3)),
        max_linear_residual_N=float(sol.linear_residual.max()),
        relaxed=int(sol.relaxed.sum())))
print("JSON" + json.dumps(rows))
"""
    root = Path(__file__).resolve().parent.parent
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=1200
    )
    for line in out.stdout.splitlines():
        if line.startswith("JSON"):
            import json

            return json.loads(line[4:])
    raise RuntimeError(f"QP accuracy subprocess failed:\n{out.stderr[-2000:]}")


def placo_peer():
    """PlaCo's DynamicsSolver on Talos as ``(label, tick)``, ``tick()`` solving one control
    tick; None when placo is not installed."""
    try:
        import placo
    except ImportError:
        return None
    import importlib.metadata

    try:
        files = importlib.metadata.files("example-robot-data") or []
    except importlib.metadata.PackageNotFoundError:
        return None
    urdfs = [f.locate() for f in files if str(f).endswith("talos_data/robots/talos_reduced.urdf")]
    if not urdfs:
        return None
    import re
    import tempfile

    # Geometry is irrelevant to the dynamics QP; drop meshes (their package:// paths do
    # not resolve outside ROS).
    text = re.sub(r"<(visual|collision)\b.*?</\1>", "", Path(urdfs[0]).read_text(), flags=re.S)
    urdf = Path(tempfile.mkdtemp()) / "talos_reduced_nomesh.urdf"
    urdf.write_text(text)
    robot = placo.RobotWrapper(str(urdf), placo.Flags.ignore_collisions)
    robot.update_kinematics()
    solver = placo.DynamicsSolver(robot)
    solver.dt = 0.001
    solver.mask_fbase(False)
    for frame in ("left_sole_link", "right_sole_link"):
        task = solver.add_frame_task(frame, robot.get_T_world_frame(frame))
        task.configure(frame, "hard", 1.0, 1.0)
        contact = solver.add_planar_contact(task)
        contact.length, contact.width, contact.mu = 0.2, 0.1, 0.65
    com = solver.add_com_task(robot.com_world())
    com.configure("com", "soft", 1.0)
    trunk = solver.add_orientation_task("torso_2_link", np.eye(3))
    trunk.configure("trunk", "soft", 1.0)
    posture = solver.add_joints_task()
    posture.set_joints({j: robot.get_joint(j) for j in robot.joint_names()})
    posture.configure("posture", "soft", 1e-3)

    def tick():
        solver.solve(True)
        robot.update_kinematics()

    for _ in range(10):
        tick()
    return f"PlaCo DynamicsSolver (Talos, nv={robot.model.nv})", tick


def peer_row(peer, repeats: int) -> dict:
    """The peer's tick timed alone (50 ticks per sample)."""
    label, tick = peer
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(50):
            tick()
        samples.append((time.perf_counter() - t0) / 50)
    median = float(np.median(samples))
    return dict(case=label, per_tick_us=median * 1e6, ticks_per_s=1 / median)


def head_to_head(batched, args, batch: int, peer, rounds: int) -> dict:
    """The vmapped tick and the peer's, interleaved (:func:`_common.interleaved`): one
    batched call, then 50 peer ticks, per round; per robot-tick and per peer tick."""
    label, tick = peer

    def peer_ticks():
        for _ in range(50):
            tick()

    t = interleaved({"ours": (lambda: batched(*args), batch), "peer": (peer_ticks, 50)}, rounds)
    return {
        "batch": batch,
        "rounds": rounds,
        "ours_per_robot_tick_us": t["ours"] * 1e6,
        "peer_per_tick_us": t["peer"] * 1e6,
        "ratio_of_medians": t["ours"] / t["peer"],
        "median_ratio": t["ours/peer"],
    }


def main():
    args = parse_args(__doc__.splitlines()[0])
    # Per-core figures: the peer is single-threaded C++, and sweeps run one worker per core.
    core = pin_to_one_core()
    repeats = 5 if args.quick else 21
    batches = (64,) if args.quick else (64, 256, 1024)
    model, data, ctrl, refs = setup()
    q = jnp.asarray(data.qpos, jnp.float32)
    v = jnp.asarray(np.random.default_rng(0).normal(0, 0.1, model.nv), jnp.float32)
    contact = jnp.ones(2, jnp.float32)
    prev = ctrl.initial_qp_state(jnp.float32)
    rows = []
    with watchdog(args.timeout, "bench_wblc"):

        def tick_rows(c, batch_sizes, suffix=""):
            """One jitted call, then vmapped batches, of the WBLC ``c``."""
            tick = jax.jit(lambda q, v, prev: c(q, v, refs, contact, previous=prev))
            comp, _ = compile_seconds(tick, q, v, prev)
            t1 = time_calls(tick, q, v, prev, repeats=repeats, inner=20)
            rows.append(
                dict(
                    case="WBLC tick, single jitted call" + suffix,
                    per_tick_us=t1["median_s"] * 1e6,
                    ticks_per_s=1 / t1["median_s"],
                    compile_s=comp,
                )
            )
            for b in batch_sizes:
                qb = jnp.broadcast_to(q, (b, model.nq))
                vb = jnp.asarray(
                    np.random.default_rng(1).normal(0, 0.1, (b, model.nv)), jnp.float32
                )
                pb = jax.tree.map(lambda x, b=b: jnp.broadcast_to(x, (b, *x.shape)), prev)
                batched = jax.jit(jax.vmap(lambda q, v, p: c(q, v, refs, contact, previous=p)))
                comp_b, compiled = compile_seconds(batched, qb, vb, pb)
                batched_calls[b] = (compiled, (qb, vb, pb))
                tb = time_calls(batched, qb, vb, pb, repeats=3 * repeats)
                rows.append(
                    dict(
                        case=f"WBLC tick, vmap batch {b}" + suffix,
                        per_tick_us=tb["median_s"] / b * 1e6,
                        ticks_per_s=b / tb["median_s"],
                        compile_s=comp_b,
                    )
                )

        batched_calls = {}
        tick_rows(ctrl, batches)
        engine_rows(model, data, ctrl, refs, v, contact, prev, rows, repeats)
        stages, qp_only = stage_functions(ctrl, refs)
        for name, fn in stages.items():
            jf = jax.jit(fn)
            ts = time_calls(jf, q, v, repeats=repeats, inner=20)
            rows.append(dict(case=f"stage: {name}", per_tick_us=ts["median_s"] * 1e6))
        snap = ctrl.snapshot(q, v)
        pts = snap.data.site_xpos[jnp.asarray(ctrl.point_sites)]
        qp_args = (pts, jnp.ones(8, bool), snap.com, jnp.asarray([0, 0, 1333.0]), jnp.zeros(3))
        jq = jax.jit(qp_only)
        tq = time_calls(jq, *qp_args, repeats=repeats, inner=20)
        rows.append(
            dict(
                case=f"stage: force QP (ADMM, {ctrl.config.force_qp.iterations} iterations)",
                per_tick_us=tq["median_s"] * 1e6,
            )
        )
        peer = placo_peer()
        duel = None
        if peer is not None:
            rows.append(peer_row(peer, repeats))
            fn, fn_args = batched_calls[64]
            duel = head_to_head(fn, fn_args, 64, peer, 41 if args.quick else 101)
        limits_cost = torque_limits_cost(model, refs, q, 64, 21 if args.quick else 61)
        per_robot = robot_rows(peer, 64, repeats, 21 if args.quick else 61)
        ablation = ablation_rows(ctrl, refs, q, 64, repeats)
        accuracy = qp_accuracy_table(200 if args.quick else 1000)
    base = rows[0]["per_tick_us"]
    for r in rows:
        r["vs_single_tick"] = r["per_tick_us"] / base
    if peer is not None:
        rows[0]["ours_over_peer"] = base / rows[-1]["per_tick_us"]
    tables = []
    tables.append(
        print_table(
            "WBLC on Valkyrie (walking hierarchy, double support, float32)",
            rows,
            [
                ("case", "case", "s"),
                ("per_tick_us", "us/tick", ".1f"),
                ("ticks_per_s", "ticks/s", ".0f"),
                ("compile_s", "compile s", ".1f"),
                ("vs_single_tick", "time / single tick", ".2f"),
            ],
        )
    )
    if peer is None:
        print("PlaCo not installed (pip install -e .[bench]): peer row skipped")
    else:
        print(f"one jitted call / PlaCo tick: {rows[0]['ours_over_peer']:.2f}")
        tables.append(
            print_table(
                f"Side by side on one core: vmap batch 64 and PlaCo, interleaved "
                f"({duel['rounds']} rounds; medians)",
                [duel],
                [
                    ("ours_per_robot_tick_us", "ours us/robot-tick", ".1f"),
                    ("peer_per_tick_us", "PlaCo us/tick", ".1f"),
                    ("ratio_of_medians", "ratio of medians", ".3f"),
                    ("median_ratio", "median per-round ratio", ".3f"),
                ],
            )
        )
    tables.append(
        print_table(
            "Batched tick by ablation: stages replaced by stand-ins, cumulatively (float32)",
            ablation,
            [
                ("case", "case", "s"),
                ("per_tick_us", "us/robot-tick", ".1f"),
                ("share_of_tick", "share of whole tick", ".2f"),
            ],
        )
    )
    tables.append(
        print_table(
            "Torque limits in the force QP (legs within the model's effort limits): batch 64, "
            f"interleaved ({limits_cost['rounds']} rounds; medians)",
            [limits_cost],
            [
                ("plain_us", "paper's WBLC us/robot-tick", ".1f"),
                ("limited_us", "with torque rows us/robot-tick", ".1f"),
                ("compile_s", "compile s (with rows)", ".1f"),
                ("ratio", "with rows / without (median per round)", ".3f"),
                ("whole_body_us", "rows + whole-body stage us/robot-tick", ".1f"),
                ("whole_body_ratio", "rows + stage / without", ".3f"),
            ],
        )
    )
    robot_columns = [
        ("robot", "robot", "s"),
        ("nv", "nv", "d"),
        ("contact_points", "contact points", "d"),
        ("torque_rows", "torque rows", "s"),
        ("single_us", "one call us", ".1f"),
        ("batch_us", "batch 64 us/robot-tick", ".1f"),
        ("single_compile_s", "compile s (one call)", ".1f"),
    ]
    if peer is not None:
        robot_columns += [
            ("peer_us", "PlaCo us/tick", ".1f"),
            ("batch_over_peer", "batch 64 / PlaCo (median per round)", ".3f"),
        ]
    tables.append(
        print_table(
            "Per robot: the walking WBLC as each robot's walking controller builds it "
            "(standing in its keyframe, float32)",
            [{**r, "torque_rows": "on" if r["torque_rows"] else "off"} for r in per_robot],
            robot_columns,
        )
    )
    tables.append(
        print_table(
            "Force QP vs quadprog (float64), by ADMM iterations",
            accuracy,
            [
                ("iterations", "iterations", "d"),
                ("median_rel_obj", "median rel. obj.", ".1e"),
                ("max_rel_obj", "max rel. obj.", ".1e"),
                ("frac_within_1e3", "share < 1e-3", ".4f"),
                ("max_linear_residual_N", "max net-force miss N", ".1e"),
                ("relaxed", "relaxed", "d"),
            ],
        )
    )
    targets = [
        target("one jitted call", rows[0]["per_tick_us"], 150.0, "us"),
        target(TORQUE_ROWS_TARGET, limits_cost["ratio"], 1.3, "x"),
    ]
    if peer is not None:
        targets.append(
            target(
                "vmap batch 64, per robot-tick, over PlaCo's tick (side by side, one core)",
                duel["median_ratio"],
                1.0,
                "x",
            )
        )
    g1 = next((r for r in per_robot if r["robot"] == "g1"), None)
    if peer is not None and g1 is not None:
        targets.append(
            target(
                "G1 (torque rows on), vmap batch 64, per robot-tick, over PlaCo's tick",
                g1["batch_over_peer"],
                1.0,
                "x",
            )
        )
    write_json(
        args.json,
        "bench_wblc",
        {
            "quick": args.quick,
            "rows": rows,
            "ablation": ablation,
            "qp_accuracy": accuracy,
            "torque_limits_cost": limits_cost,
            "per_robot": per_robot,
            "peer": None if peer is None else peer[0],
            "side_by_side": duel,
            "pinned_core": core,
        },
        tables=tables,
        targets=targets,
    )


if __name__ == "__main__":
    main()
