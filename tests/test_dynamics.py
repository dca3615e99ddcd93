"""The dynamics layer against MuJoCo's C functions, finite differences and jax.jvp (float64)."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from jaxloco.dynamics import jacobians as J
from jaxloco.dynamics.engine_terms import (
    ENGINE_FIELDS,
    dense_mass_matrix,
    engine_data,
    engine_terms,
)
from jaxloco.dynamics.model import keyframe_qpos, load_valkyrie
from jaxloco.dynamics.terms import joint_space_terms
from jaxloco.sim import run_closed_loop

SITES = ("left_foot_cop", "right_foot_contact2", "left_hand", "right_hand", "torso", "pelvis")


def random_state(model, seed, qvel_scale=1.0):
    rng = np.random.default_rng(seed)
    data = mujoco.MjData(model)
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "walk")
    data.qpos[:] = model.key_qpos[key] if key >= 0 else model.qpos0
    for j in range(model.njnt):
        adr = model.jnt_qposadr[j]
        typ = model.jnt_type[j]
        if typ in (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL):
            start = adr + (3 if typ == mujoco.mjtJoint.mjJNT_FREE else 0)
            quat = rng.normal(size=4)
            data.qpos[start : start + 4] = quat / np.linalg.norm(quat)
        else:
            data.qpos[adr] += rng.normal(0, 0.4)
    data.qvel[:] = rng.normal(0, qvel_scale, model.nv)
    mujoco.mj_forward(model, data)
    return data


def random_chain_xml(seed, floating):
    """A random kinematic tree: hinges with random axes, slides and ball joints."""
    rng = np.random.default_rng(seed)
    kinds = ["hinge", "slide", "ball", "hinge", "hinge", "ball", "hinge"]
    body = ""
    for i, kind in reversed(list(enumerate(kinds))):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        pos = rng.uniform(-0.3, 0.3, 3)
        joint = (
            f'<joint name="j{i}" type="ball"/>'
            if kind == "ball"
            else f'<joint name="j{i}" type="{kind}" axis="{axis[0]} {axis[1]} {axis[2]}"/>'
        )
        mass = rng.uniform(0.5, 3.0)
        body = (
            f'<body name="b{i}" pos="{pos[0]} {pos[1]} {pos[2]}">{joint}'
            f'<inertial pos="{rng.uniform(-0.1, 0.1)} 0.05 {rng.uniform(-0.1, 0.1)}" '
            f'mass="{mass}" diaginertia="0.02 0.03 0.04"/>'
            f'<site name="s{i}" pos="0.1 -0.05 0.2"/>{body}</body>'
        )
        if i == 2:  # a branch
            body = body.replace(
                "</body>",
                '<body name="branch" pos="0 0.2 0">'
                '<joint name="jb" type="hinge" axis="0 1 0"/>'
                '<inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>'
                '<site name="sb" pos="0.2 0 0"/></body></body>',
                1,
            )
    root = "<freejoint/>" if floating else ""
    return (
        f'<mujoco><option gravity="0 0 -9.81"/><worldbody><body name="root" pos="0 0 1">'
        f'{root}<inertial pos="0 0 0" mass="2" diaginertia="0.1 0.1 0.1"/>{body}</body>'
        f"</worldbody></mujoco>"
    )


def models():
    yield "valkyrie", load_valkyrie(), SITES
    for floating in (False, True):
        model = mujoco.MjModel.from_xml_string(random_chain_xml(3, floating))
        sites = tuple(model.site(i).name for i in range(model.nsite))
        yield f"chain-floating={floating}", model, sites


MODELS = list(models())


@pytest.fixture(scope="module")
def smooth_fn():
    return jax.jit(J.smooth)


@pytest.mark.parametrize("name,model,sites", MODELS, ids=[m[0] for m in MODELS])
@pytest.mark.parametrize("seed", [0, 1])
def test_jacobians_and_jdot_qdot_match_mujoco(name, model, sites, seed, smooth_fn):
    data = random_state(model, seed)
    mx, dx = mjx.put_model(model), mjx.put_data(model, data)
    dx = smooth_fn(mx, dx)
    motion = J.body_motion(mx, dx)
    for site in sites:
        sid = model.site(site).id
        body, point = int(model.site_bodyid[sid]), data.site_xpos[sid]
        jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jac(model, data, jacp, jacr, point, body)
        ours = J.frame_jacobian(mx, dx, jnp.asarray(point), body)
        np.testing.assert_allclose(ours, np.vstack([jacr, jacp]), atol=1e-12)
        np.testing.assert_allclose(
            J.point_jacobian(mx, dx, jnp.asarray(point), body), jacp, atol=1e-12
        )
        jdp, jdr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jacDot(model, data, jdp, jdr, point, body)
        want = np.concatenate([jdr @ data.qvel, jdp @ data.qvel])
        got = J.frame_jdot_qdot(mx, dx, jnp.asarray(point), body, motion)
        np.testing.assert_allclose(got, want, atol=1e-10, err_msg=f"{name}:{site}")
    jac_com = np.zeros((3, model.nv))
    mujoco.mj_jacSubtreeCom(model, data, jac_com, 0)
    np.testing.assert_allclose(J.com_jacobian(mx, dx), jac_com, atol=1e-12)
    # MuJoCo C's own terms, put where MJX's stages put theirs, are MJX's (ball joints too).
    de = jax.jit(engine_data)(mx, engine_terms(data))
    for field in set(ENGINE_FIELDS) - {"qpos", "qvel", "crb", "M"}:  # the derived ones
        np.testing.assert_allclose(
            getattr(de, field), getattr(dx, field), atol=1e-10, err_msg=f"{name}:{field}"
        )
    np.testing.assert_allclose(de._impl.crb, dx._impl.crb, atol=1e-10)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    dense = dense_mass_matrix(mx, jnp.asarray(data.M))
    np.testing.assert_array_equal(dense, full)
    np.testing.assert_allclose(dense, mjx.full_m(mx, dx), atol=1e-10)


def test_the_engines_terms_serve_only_a_controller_of_the_simulated_robot():
    from jaxloco.dynamics.engine_terms import check_same_dynamics

    model = load_valkyrie()
    mx = mjx.put_model(model)
    check_same_dynamics(mx, model)
    heavier = load_valkyrie()
    heavier.body_mass[model.body("pelvis").id] += 5.0
    with pytest.raises(ValueError, match="body_mass differs"):
        check_same_dynamics(mx, heavier)


def test_the_split_step_is_mj_step_and_the_controller_sees_the_state_it_acts_on():
    """``run_closed_loop(engine=True)`` (``mj_step1``, controller, ``mj_step2``) moves the
    robot exactly as ``mj_step`` does, and the terms it hands the controller are the ones
    MuJoCo computes for the state the controller acts on (not the step before's)."""
    model = load_valkyrie()
    kp, kd = 50.0, 2.0
    seen = []

    def pd(t, qpos, qvel, carry, engine=None):
        if engine is not None:
            check = mujoco.MjData(model)
            check.qpos[:], check.qvel[:] = qpos, qvel
            mujoco.mj_forward(model, check)
            seen.append(
                max(
                    np.abs(engine.site_xpos - check.site_xpos).max(),
                    np.abs(engine.qfrc_bias - check.qfrc_bias).max(),
                )
            )
        return -kp * qpos[7 : 7 + model.nu] - kd * qvel[6 : 6 + model.nu], carry, np.zeros(())

    runs = []
    for engine in (False, True):
        data = random_state(model, 3, qvel_scale=0.3)
        log, _ = run_closed_loop(model, data, pd, None, 200, engine=engine, pure=False)
        runs.append(log)
    np.testing.assert_array_equal(runs[0].qpos, runs[1].qpos)
    np.testing.assert_array_equal(runs[0].ctrl, runs[1].ctrl)
    assert len(seen) == 200 and max(seen) < 1e-12
    rk4 = load_valkyrie()
    rk4.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    with pytest.raises(ValueError, match="RK4"):
        run_closed_loop(rk4, mujoco.MjData(rk4), pd, None, 1, engine=True, pure=False)


def test_jdot_qdot_matches_finite_differences():
    model = load_valkyrie()
    data = random_state(model, 5)
    mx, dx = (
        mjx.put_model(model),
        jax.jit(J.smooth)(mjx.put_model(model), mjx.put_data(model, data)),
    )
    eps = 1e-6

    def site_jacobian(qpos, sid):
        d = mujoco.MjData(model)
        d.qpos[:] = qpos
        mujoco.mj_kinematics(model, d)
        mujoco.mj_comPos(model, d)
        jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jac(model, d, jacp, jacr, d.site_xpos[sid], model.site_bodyid[sid])
        return np.vstack([jacr, jacp])

    q_plus, q_minus = data.qpos.copy(), data.qpos.copy()
    mujoco.mj_integratePos(model, q_plus, data.qvel, eps)
    mujoco.mj_integratePos(model, q_minus, data.qvel, -eps)
    for site in SITES:
        sid = model.site(site).id
        fd = (site_jacobian(q_plus, sid) - site_jacobian(q_minus, sid)) / (2 * eps) @ data.qvel
        got = J.frame_jdot_qdot(
            mx, dx, jnp.asarray(data.site_xpos[sid]), int(model.site_bodyid[sid])
        )
        np.testing.assert_allclose(got, fd, atol=1e-8)
    # The CoM too.
    com = []
    for q in (q_plus, q_minus):
        d = mujoco.MjData(model)
        d.qpos[:] = q
        mujoco.mj_kinematics(model, d)
        mujoco.mj_comPos(model, d)
        jc = np.zeros((3, model.nv))
        mujoco.mj_jacSubtreeCom(model, d, jc, 0)
        com.append(jc)
    fd_com = (com[0] - com[1]) / (2 * eps) @ data.qvel
    np.testing.assert_allclose(J.com_jdot_qdot(mx, dx), fd_com, atol=1e-8)


def quat_mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return jnp.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def test_jdot_qdot_matches_jvp_of_the_jacobian():
    """d/de J(q (+) e qd) qd at e = 0, with the free joint integrated on its manifold."""
    model = load_valkyrie()
    data = random_state(model, 7)
    mx = mjx.put_model(model)
    dx0 = mjx.put_data(model, data)
    qpos0, qvel = jnp.asarray(data.qpos), jnp.asarray(data.qvel)
    sid = model.site("left_hand").id
    body = int(model.site_bodyid[sid])

    def qpos_at(e):
        pos = qpos0[:3] + e * qvel[:3]
        w = e * qvel[3:6]
        angle = jnp.sqrt(jnp.sum(w**2) + 1e-300)
        dq = jnp.concatenate([jnp.cos(angle / 2)[None], jnp.sin(angle / 2) * w / angle])
        quat = quat_mul(qpos0[3:7], dq)  # local angular velocity: right multiplication
        return jnp.concatenate([pos, quat, qpos0[7:] + e * qvel[6:]])

    def jacobian(e):
        d = mjx.kinematics(mx, dx0.replace(qpos=qpos_at(e)))
        d = mjx.com_pos(mx, d)
        return J.frame_jacobian(mx, d, d.site_xpos[sid], body) @ qvel

    # Jitted: op by op, the kinematics' jvp and the Lie-group terms are hundreds of compiles.
    _, jdot_qdot = jax.jit(lambda: jax.jvp(jacobian, (0.0,), (1.0,)))()
    dx = jax.jit(J.smooth)(mx, dx0)
    lie = jax.jit(lambda dx, p: J.frame_jdot_qdot(mx, dx, p, body))
    np.testing.assert_allclose(lie(dx, jnp.asarray(data.site_xpos[sid])), jdot_qdot, atol=1e-9)


def test_joint_space_terms_match_mujoco():
    model = load_valkyrie()
    mx = mjx.put_model(model)
    terms_fn = jax.jit(lambda d: joint_space_terms(mx, d))
    for seed in range(2):
        data = random_state(model, seed)
        terms = terms_fn(mjx.put_data(model, data))
        full = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, full)
        np.testing.assert_allclose(terms.mass_matrix, full, atol=1e-10)
        np.testing.assert_allclose(terms.coriolis + terms.gravity, data.qfrc_bias, atol=1e-9)
        still = mujoco.MjData(model)
        still.qpos[:] = data.qpos
        mujoco.mj_forward(model, still)
        np.testing.assert_allclose(terms.gravity, still.qfrc_bias, atol=1e-9)
        # b is quadratic in the velocities: doubling them quadruples it.
        doubled = mujoco.MjData(model)
        doubled.qpos[:], doubled.qvel[:] = data.qpos, 2 * data.qvel
        terms2 = terms_fn(mjx.put_data(model, doubled))
        np.testing.assert_allclose(terms2.coriolis, 4 * terms.coriolis, atol=1e-8)


def test_keyframe_helpers_and_batched_evaluation():
    model = load_valkyrie()
    mx = mjx.put_model(model)
    data = mujoco.MjData(model)
    data.qpos[:] = keyframe_qpos(model, "walk")
    batch = jax.tree.map(lambda x: jnp.stack([x, x]), mjx.put_data(model, data))
    terms = jax.jit(jax.vmap(lambda d: joint_space_terms(mx, d)))(batch)
    assert terms.mass_matrix.shape == (2, model.nv, model.nv)
    np.testing.assert_allclose(terms.coriolis, 0.0, atol=1e-10)  # at rest


# --- centroidal momentum and Eq. 31 ----------------------------------------------------

from jaxloco.dynamics import centroidal as C  # noqa: E402


def test_centroidal_momentum_matches_mujoco_subtree_momenta():
    model = load_valkyrie()
    mx = mjx.put_model(model)
    for seed in range(2):
        data = random_state(model, seed)
        mujoco.mj_subtreeVel(model, data)
        dx = jax.jit(J.smooth)(mx, mjx.put_data(model, data))
        h = C.centroidal_momentum_matrix(mx, dx) @ jnp.asarray(data.qvel)
        total = model.body_subtreemass[0]
        np.testing.assert_allclose(h[3:], total * data.subtree_linvel[0], atol=1e-10)
        np.testing.assert_allclose(h[:3], data.subtree_angmom[0], atol=1e-10)
        np.testing.assert_allclose(C.centre_of_mass(mx, dx), data.subtree_com[0], atol=1e-12)
        # The locked inertia maps a rigid rotation about the CoM to its angular momentum.
        i_g = np.asarray(C.centroidal_inertia(mx, dx))
        np.testing.assert_allclose(i_g, i_g.T, atol=1e-12)
        assert np.all(np.linalg.eigvalsh(i_g) > 0)


def momentum_rate_by_jvp(model, data, averaged):
    """d/dt (J(q) qd) at qdd = 0 along the manifold, with J = J_cm or I_G^-1 J_cm."""
    mx = mjx.put_model(model)
    dx0 = mjx.put_data(model, data)
    qpos0, qvel = jnp.asarray(data.qpos), jnp.asarray(data.qvel)

    def qpos_at(e):
        w = e * qvel[3:6]
        angle = jnp.sqrt(jnp.sum(w**2) + 1e-300)
        dq = jnp.concatenate([jnp.cos(angle / 2)[None], jnp.sin(angle / 2) * w / angle])
        return jnp.concatenate(
            [qpos0[:3] + e * qvel[:3], quat_mul(qpos0[3:7], dq), qpos0[7:] + e * qvel[6:]]
        )

    def momentum(e):
        d = mjx.crb(mx, mjx.com_pos(mx, mjx.kinematics(mx, dx0.replace(qpos=qpos_at(e)))))
        jcm = C.centroidal_momentum_matrix(mx, d)
        if averaged:
            jcm = jnp.linalg.solve(C.centroidal_inertia(mx, d), jcm)
        return jcm @ qvel

    # Jitted: op by op, MJX's kinematics and the jvp are hundreds of one-op compiles.
    return jax.jit(lambda: jax.jvp(momentum, (0.0,), (1.0,))[1])()


def test_eq31_holds_exactly_for_momentum_but_not_for_averaged_velocity():
    model = load_valkyrie()
    mx = mjx.put_model(model)
    data = random_state(model, 11)
    dx = jax.jit(J.smooth)(mx, mjx.put_data(model, data))

    @jax.jit  # op by op, these are hundreds of one-op compiles
    def bias_terms(dx):
        terms = joint_space_terms(mx, dx, smoothed=True)
        jcm = C.centroidal_momentum_matrix(mx, dx)
        eq31 = C.centroidal_bias(jcm, terms.mass_matrix, terms.coriolis)
        # The same by products with the Cholesky factor's inverse (as a WBLC tick does).
        chol = jnp.linalg.cholesky(terms.mass_matrix)
        chol_inv = jax.scipy.linalg.solve_triangular(chol, jnp.eye(chol.shape[0]), lower=True)
        by_inverse = C.centroidal_bias(jcm, None, terms.coriolis, mass_cholesky_inverse=chol_inv)
        return eq31, by_inverse, C.centroidal_inertia(mx, dx)

    eq31, by_inverse, i_g = bias_terms(dx)
    np.testing.assert_allclose(by_inverse, eq31, rtol=1e-9, atol=1e-9)
    # Momentum: exact, angular and linear parts alike.
    np.testing.assert_allclose(eq31, momentum_rate_by_jvp(model, data, False), atol=1e-8)
    # An averaged velocity I_G^-1 h: Eq. 31 misses the d/dt(I_G^-1) h term.
    averaged_eq31 = np.linalg.solve(np.asarray(i_g), np.asarray(eq31))
    averaged_true = momentum_rate_by_jvp(model, data, True)
    gap = np.abs(np.asarray(averaged_eq31 - averaged_true))
    assert gap[:3].max() > 1e-2  # the angular part differs...
    np.testing.assert_allclose(averaged_eq31[3:], averaged_true[3:], atol=1e-8)  # ...not CoM


def test_osc_planar_experiment_jdot_qdot_improves_tracking(tmp_path):
    """Fig. 8, CI-sized: with Jdot qd the tip tracks the 2 Hz line far better."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "experiments" / "osc_planar.py"
    spec = importlib.util.spec_from_file_location("osc_planar", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    cfg = module.OscPlanarConfig(duration=1.2, settle=0.6, dpi=50)
    summary = module.run(cfg, tmp_path)
    with_jdot = summary["results"]["with Jdot qd"]["rms_error_after_settle_m"]
    without = summary["results"]["without Jdot qd"]["rms_error_after_settle_m"]
    assert with_jdot < 0.005 and without > 3 * with_jdot
    assert (tmp_path / "osc_paths.png").stat().st_size > 0


def test_se3_identities():
    from scipy.spatial.transform import Rotation

    from jaxloco.dynamics import se3

    rng = np.random.default_rng(4)
    rot = Rotation.random(random_state=5).as_matrix()
    pos, twist, screw = rng.normal(size=3), rng.normal(size=6), rng.normal(size=6)
    w = rng.normal(size=3)
    np.testing.assert_allclose(se3.hat(w) @ pos, np.cross(w, pos), atol=1e-14)
    ad_t = np.asarray(se3.adjoint(jnp.asarray(rot), jnp.asarray(pos)))
    # Ad_T ad_V Ad_T^-1 = ad_{Ad_T V} (the adjoint is a Lie-algebra homomorphism).
    lhs = ad_t @ np.asarray(se3.ad(jnp.asarray(twist))) @ np.linalg.inv(ad_t)
    np.testing.assert_allclose(lhs, se3.ad(jnp.asarray(ad_t @ twist)), atol=1e-12)
    # ad_V S = -ad_S V, and the matrix-free form equals the matrix.
    np.testing.assert_allclose(
        se3.ad_apply(twist, screw), np.asarray(se3.ad(twist)) @ screw, atol=1e-14
    )
    np.testing.assert_allclose(
        se3.ad_apply(twist, screw), -np.asarray(se3.ad_apply(screw, twist)), atol=1e-14
    )


BOX_ON_A_FLOOR = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <geom type="plane" size="2 2 0.1"/>
    <body pos="0 0 0.12">
      <freejoint/>
      <geom type="box" size="0.1 0.08 0.05" mass="2"/>
      <body pos="0.1 0 0.05">
        <joint name="arm" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02" mass="0.3"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="arm"/></actuator>
</mujoco>
"""


def test_mjx_step_in_two_halves_is_mjx_step(integrator="Euler"):
    """The MJX loop's split step (position and velocity stages, then the controls, then the
    rest) is ``mjx.step``, contacts included (Euler, every model's integrator here; the
    others differ only in which of MJX's integrators the second half calls)."""
    from jaxloco.sim.mjx_loop import step_first_half, step_second_half

    model = mujoco.MjModel.from_xml_string(
        BOX_ON_A_FLOOR.replace('timestep="0.002"', f'timestep="0.002" integrator="{integrator}"')
    )
    mx = mjx.put_model(model)
    data = mujoco.MjData(model)
    data.qvel[:] = [0.3, -0.2, 0.0, 0.5, 0.1, -0.4, 2.0]
    d0 = mjx.put_data(model, data)
    u = jnp.asarray([0.7])

    @jax.jit
    def both(d):
        whole = mjx.step(mx, d.replace(ctrl=u))
        halves = step_second_half(mx, step_first_half(mx, d).replace(ctrl=u))
        return whole, halves

    d = d0
    for _ in range(20):
        whole, halves = both(d)
        np.testing.assert_array_equal(halves.qpos, whole.qpos)
        np.testing.assert_array_equal(halves.qvel, whole.qvel)
        d = whole
    assert int(whole._impl.ncon) > 0  # the box rests on the floor: constraints were solved
