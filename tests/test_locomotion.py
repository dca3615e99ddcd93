"""Locomotion: swing splines, quaternion slerp, the gait's references, walking and pushes
on MuJoCo, and MJX against MuJoCo's C engine."""

import dataclasses
import json
import re

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx
from scipy.integrate import solve_ivp
from scipy.interpolate import BSpline
from scipy.spatial.transform import Rotation, Slerp

from jaxloco.dynamics import se3
from jaxloco.dynamics.engine_terms import engine_terms
from jaxloco.dynamics.model import keyframe_qpos, load_valkyrie
from jaxloco.learning.loading import load_planner
from jaxloco.locomotion import (
    GaitOverrides,
    GaitParams,
    WalkingController,
    make_swing,
    make_walking_controller,
    retarget_swing,
    step_timing,
)
from jaxloco.locomotion import gait as gait_lib
from jaxloco.locomotion.swing import KNOTS, Motion, basis_derivatives
from jaxloco.planner import PSPParams
from jaxloco.planner.psp import Reason
from jaxloco.sim import mjx_loop
from jaxloco.sim.push import Push, PushArrays, apply_push_c, body_index, push_force
from jaxloco.sim.scenarios import simulate_walk

# --- swing splines ----------------------------------------------------------------------


def test_swing_from_rest_lands_at_rest_through_mid_height():
    start, target = jnp.array([0.0, 0.1, 0.0]), jnp.array([0.35, 0.25, 0.02])
    s = make_swing(start, target, t0=1.0, duration=0.5, mid_height=0.12)
    p0, v0, a0 = s.evaluate(1.0)
    p1, v1, a1 = s.evaluate(1.5)
    np.testing.assert_allclose(p0, start, atol=1e-12)
    np.testing.assert_allclose(p1, target, atol=1e-12)
    for x in (v0, a0, v1, a1):
        np.testing.assert_allclose(x, 0.0, atol=1e-9)
    mid, _, _ = s.evaluate(1.25)
    assert mid[2] == pytest.approx(0.12, abs=1e-12)
    np.testing.assert_allclose(mid[:2], 0.5 * (start[:2] + target[:2]), atol=1e-12)


def test_swing_replanned_midair_continues_without_jump():
    old = make_swing(jnp.zeros(3), jnp.array([0.3, 0.0, 0.0]), 0.0, 0.6, 0.1)
    t = 0.27
    pos, vel, acc = old.evaluate(t)
    new = make_swing(pos, jnp.array([0.45, 0.1, 0.0]), t, 0.25, 0.1, vel, acc)
    p, v, a = new.evaluate(t)
    np.testing.assert_allclose(p, pos, atol=1e-12)
    np.testing.assert_allclose(v, vel, atol=1e-9)
    np.testing.assert_allclose(a, acc, atol=1e-7)
    np.testing.assert_allclose(new.evaluate(t + 0.25)[0], [0.45, 0.1, 0.0], atol=1e-12)


def test_retargeted_swing_is_time_consistent_and_does_not_compound():
    swing = make_swing(jnp.zeros(3), jnp.array([0.5, 0.0, 0.0]), 0.0, 0.6, 0.1)
    ts = jnp.linspace(0.3, 0.6, 50)
    # Re-planned to the same target and landing time: the same ground path.
    same = retarget_swing(swing, 0.3, swing.target, 0.3, 0.1)
    for a, b in zip(jax.vmap(swing.evaluate)(ts), jax.vmap(same.evaluate)(ts), strict=True):
        np.testing.assert_allclose(a[:, :2], b[:, :2], atol=1e-12)
    # Re-planned every 20 ms towards a target a little further on, as after a push. The
    # B-spline refit this replaced (with halved end derivatives) doubled the speed at each
    # replan.
    # The height: continuing the lift-off's upward acceleration over each new swing took it
    # to 5.4 m before the height's control points were bounded; now it stays below twice
    # the swing's 0.1 m, and only its vertical velocity and acceleration give way.
    t, target, peak = 0.15, 0.5, 0.0
    for _ in range(6):
        pos, vel, acc = swing.evaluate(t)
        target += 0.04
        new = retarget_swing(swing, t, jnp.array([target, 0.0, 0.0]), 0.6 - t, 0.1)
        got_pos, got_vel, got_acc = new.evaluate(t)
        np.testing.assert_allclose(got_pos, pos, atol=1e-9)
        np.testing.assert_allclose(got_vel[:2], vel[:2], atol=1e-9)
        np.testing.assert_allclose(got_acc[:2], acc[:2], atol=1e-9)
        xs, vs, _ = jax.vmap(new.evaluate)(jnp.linspace(t, 0.6, 200))
        assert float(jnp.max(xs[:, 0])) <= target + 1e-9  # never past the target
        assert float(jnp.max(xs[:, 2])) < 0.2
        peak = max(peak, float(jnp.max(vs[:, 0])))
        swing, t = new, t + 0.02
    np.testing.assert_allclose(swing.evaluate(0.6)[0], [target, 0.0, 0.0], atol=1e-12)
    # Within 20% of the min-jerk peak of one swing over the final distance (measured 2.45).
    assert peak < 1.2 * 1.875 * target / 0.6


def test_swing_replanned_during_lift_off_stays_below_twice_its_height():
    """A foot 2 cm up and still accelerating up (a G1 swing's lift-off, 63 mm swings)
    re-planned to land 0.4 s later: continuing its vertical acceleration over the longer
    swing took the reference 0.77 m up after a sideways push; bounded, the height stays
    below twice the swing's, and the position and vertical velocity continue."""
    pos = jnp.array([0.33, -0.13, 0.02])
    vel, acc = jnp.array([0.4, 0.0, 0.6]), jnp.array([2.0, 0.0, 25.0])
    target = jnp.array([0.66, 0.02, 0.0])
    new = make_swing(pos, target, 2.6, 0.4, 0.063, vel, acc)
    p, v, _ = jax.vmap(new.evaluate)(jnp.linspace(2.6, 3.0, 400))
    assert float(jnp.max(p[:, 2])) < 2 * 0.063
    np.testing.assert_allclose(p[0], pos, atol=1e-12)
    np.testing.assert_allclose(p[-1], target, atol=1e-12)
    np.testing.assert_allclose(v[0], vel, atol=1e-9)
    unbounded_h2 = (25.0 * 0.4**2) / 2.0  # the acceleration's control point alone, ~2 m
    assert float(new.height_points[2]) < unbounded_h2 / 10


def test_swing_replanned_while_landing_never_goes_below_the_floor():
    """A foot about to land (2 cm up, coming down at 1.5 m/s) re-planned to land 0.22 s
    later: continuing its vertical velocity and acceleration would take the height below
    the floor, so they give way; the ground path still continues without a jump."""
    pos = jnp.array([1.14, 0.1, 0.02])
    vel, acc = jnp.array([0.3, 0.0, -1.5]), jnp.array([0.1, 0.0, -20.0])
    target = jnp.array([1.36, -0.12, 0.0])
    new = make_swing(pos, target, 0.5, 0.22, 0.02, vel, acc)
    p, v, a = jax.vmap(new.evaluate)(jnp.linspace(0.5, 0.72, 400))
    assert float(jnp.min(p[:, 2])) >= -1e-12
    np.testing.assert_allclose(p[0], pos, atol=1e-12)
    np.testing.assert_allclose(p[-1], target, atol=1e-12)
    np.testing.assert_allclose(v[0, :2], vel[:2], atol=1e-9)
    np.testing.assert_allclose(a[0, :2], acc[:2], atol=1e-7)
    # The clamp binds: the z velocity is not continued (1.09 m/s down, not 1.5).
    assert float(v[0, 2]) > 0.8 * float(vel[2])
    # A foot coming down slowly keeps its velocity and acceleration (the clamp is idle).
    slow = make_swing(pos, target, 0.5, 0.22, 0.05, vel.at[2].set(-0.05), acc.at[2].set(0.0))
    _, v_slow, a_slow = slow.evaluate(0.5)
    assert float(v_slow[2]) == pytest.approx(-0.05, abs=1e-9)
    assert float(a_slow[2]) == pytest.approx(0.0, abs=1e-7)


def test_basis_and_its_derivatives_match_scipys_b_spline_including_the_ends():
    us = np.concatenate([[0.0, 1e-9, 0.25, 0.5, 0.75, 1.0 - 1e-9, 1.0], np.linspace(0, 1, 37)])
    got = np.stack([np.asarray(basis_derivatives(jnp.asarray(u))) for u in us])
    for i, unit in enumerate(np.eye(len(KNOTS) - 4)):
        spline = BSpline(KNOTS, unit, 3)
        for order in range(3):
            want = spline.derivative(order)(us) if order else spline(us)
            np.testing.assert_allclose(got[:, order, i], want, atol=1e-9)
    # Partition of unity, and beyond the ends the values of the ends.
    np.testing.assert_allclose(got[:, 0].sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(basis_derivatives(jnp.asarray(1.5)), got[6], atol=1e-12)


def test_a_swing_starts_with_the_velocity_and_acceleration_it_was_given():
    """Just after its start (not only at it), a swing moves as commanded: the height's
    first control points come from the basis's true derivatives at ``u = 0``."""
    vel, acc = jnp.array([0.3, -0.1, 0.4]), jnp.array([1.0, 0.5, -2.0])
    s = make_swing(jnp.array([0.0, 0.0, 0.05]), jnp.array([0.3, 0.0, 0.0]), 0.0, 0.4, 0.1, vel, acc)
    h = 1e-6
    p0, _, _ = s.evaluate(0.0)
    p1, v1, _ = s.evaluate(h)
    p2, v2, _ = s.evaluate(2 * h)
    np.testing.assert_allclose((p1 - p0) / h, vel, atol=1e-4)
    np.testing.assert_allclose((v2 - v1) / h, acc, atol=1e-3)


def test_swing_is_acceleration_continuous_and_derivatives_match_differences():
    s = make_swing(jnp.zeros(3), jnp.array([0.4, -0.1, 0.0]), 0.0, 1.0, 0.1)
    for knot in np.unique(KNOTS[(KNOTS > 0) & (KNOTS < 1)]):
        _, _, a_lo = s.evaluate(knot - 1e-9)
        _, _, a_hi = s.evaluate(knot + 1e-9)
        np.testing.assert_allclose(a_lo, a_hi, atol=1e-5)
    h = 1e-6
    for t in (0.1, 0.37, 0.8):
        p_m, v_m, _ = s.evaluate(t - h)
        p_p, v_p, _ = s.evaluate(t + h)
        _, v, a = s.evaluate(t)
        np.testing.assert_allclose((p_p - p_m) / (2 * h), v, atol=1e-6)
        np.testing.assert_allclose((v_p - v_m) / (2 * h), a, atol=1e-4)


# --- orientations -----------------------------------------------------------------------


def test_quat_slerp_matches_scipy():
    rng = np.random.default_rng(0)
    for _ in range(5):
        r = Rotation.random(2, random_state=rng)
        q_xyzw = r.as_quat()
        wxyz = np.roll(q_xyzw, 1, axis=1)
        ref = Slerp([0.0, 1.0], r)
        for s in (0.0, 0.3, 0.75, 1.0):
            got = np.asarray(se3.quat_slerp(jnp.asarray(wxyz[0]), jnp.asarray(wxyz[1]), s))
            want = np.roll(ref([s]).as_quat()[0], 1)
            assert min(np.abs(got - want).max(), np.abs(got + want).max()) < 1e-9
    q = se3.yaw_quat(0.3)
    near = se3.quat_slerp(q, q, 0.5)
    assert np.all(np.isfinite(near)) and np.allclose(near, q)


def test_yaw_quat_rotates_about_z():
    q = np.asarray(se3.yaw_quat(0.7))
    mat = Rotation.from_quat(np.roll(q, -1)).as_matrix()
    np.testing.assert_allclose(mat, Rotation.from_euler("z", 0.7).as_matrix(), atol=1e-12)


# --- gait -------------------------------------------------------------------------------


def test_gait_params_reject_bad_values():
    with pytest.raises(ValueError, match="replan_gamma"):
        GaitParams(replan_gamma=1.5)
    with pytest.raises(ValueError, match="contact_blend"):
        GaitParams(contact_blend=0.0)
    with pytest.raises(ValueError, match="Push.duration"):
        Push(duration=0.0)
    with pytest.raises(ValueError, match=r"com_height must be in \[0.1, 3\]"):
        GaitParams(com_height=3.5)


def test_quintic_meets_its_boundary_conditions():
    p, v, a = gait_lib.quintic(0.1, 0.0, 0.0, 0.3, 0.2, 1.5, 0.8, 0.8)
    assert (p, v, a) == pytest.approx((0.3, 0.2, 1.5))
    p, v, a = gait_lib.quintic(0.1, 0.0, 0.0, 0.3, 0.2, 1.5, 0.8, 0.0)
    assert (p, v, a) == pytest.approx((0.1, 0.0, 0.0))


def test_walking_com_reference_is_the_lipm_and_contacts_blend():
    """During a step the CoM reference follows the LIPM about the stance foot (checked by
    numerical integration) and the contact weights ramp over ``contact_blend``."""
    psp = PSPParams()
    params = GaitParams()
    feet = jnp.array([[0.0, 0.14, 0.0], [0.0, -0.14, 0.0]])
    state = gait_lib.init_gait(params, psp, jnp.array([0.0, 0.0, 1.06]), feet)
    # A stand-in policy: the nominal action everywhere.
    policy = lambda s: jnp.array([0.25, 0.2, 0.0])  # noqa: E731
    t_lift = params.start_duration
    com = jnp.zeros(3)
    state = gait_lib.advance(state, params, psp, policy, t_lift, com, com, feet, 1e-3)
    assert int(state.phase) == gait_lib.WALK and int(state.step) == 1
    w = psp.omega
    p0, v0, _ = gait_lib.com_reference(state, params, psp, t_lift)
    pivot = np.asarray(state.stance_pos[:2])

    def lipm(_, x):
        return np.concatenate([x[2:], w**2 * (x[:2] - pivot)])

    sol = solve_ivp(lipm, (0, 0.3), np.concatenate([p0[:2], v0[:2]]), rtol=1e-11, atol=1e-12)
    p1, v1, a1 = gait_lib.com_reference(state, params, psp, t_lift + 0.3)
    np.testing.assert_allclose(p1[:2], sol.y[:2, -1], atol=1e-8)
    np.testing.assert_allclose(v1[:2], sol.y[2:, -1], atol=1e-8)
    np.testing.assert_allclose(a1[:2], w**2 * (p1[:2] - pivot), atol=1e-10)
    # Contacts: the swing foot's bound ramps out over contact_blend, then its tasks switch on.
    mid = gait_lib.references(state, params, psp, t_lift + params.contact_blend / 2, com, com)
    after = gait_lib.references(state, params, psp, t_lift + params.contact_blend, com, com)
    swing = int(mid.swing_foot)
    assert float(mid.contact[swing]) == pytest.approx(0.5)
    assert float(after.contact[swing]) == 0.0 and float(after.swinging[swing]) == 1.0
    assert float(after.contact[1 - swing]) == 1.0


def test_replan_threshold_is_per_robot_data():
    """Eq. 33's trigger comes from the gait state: the same 8 cm CoM error replans a robot
    whose threshold is 5 cm and not one whose threshold is 20 cm."""
    psp, params = PSPParams(), GaitParams()
    feet = jnp.array([[0.0, 0.14, 0.0], [0.0, -0.14, 0.0]])
    policy = lambda s: jnp.array([0.25, 0.2, 0.0])  # noqa: E731
    t_lift, dt = params.start_duration, 1e-3
    replans = {}
    for threshold in (0.05, 0.2):
        overrides = GaitOverrides.of(params, replan_threshold=threshold)
        state = gait_lib.init_gait(
            params, psp, jnp.array([0.0, 0.0, 1.06]), feet, overrides=overrides
        )
        assert float(state.overrides.replan_threshold) == threshold
        zero = jnp.zeros(3)
        state = gait_lib.advance(state, params, psp, policy, t_lift, zero, zero, feet, dt)
        step = jax.jit(
            lambda s, t, c, v: gait_lib.advance(s, params, psp, policy, t, c, v, feet, dt)
        )
        for k in range(50, 100):
            t = t_lift + k * dt
            pos, vel, _ = gait_lib.com_reference(state, params, psp, t)
            state = step(state, t, pos + jnp.array([0.08, 0.0, 0.0]), vel)
        replans[threshold] = int(state.replans)
    assert replans[0.05] >= 1 and replans[0.2] == 0, replans


def test_replan_delay_behind_replans_a_com_behind_its_reference_sooner():
    """The same 8 cm error for 12 ms: with ``replan_delay_behind`` 5 ms the CoM behind its
    reference (along the heading) is replanned and the CoM ahead of it is not (20 ms);
    without it neither is."""
    replans = {}
    for behind_delay in (0.005, None):
        params = GaitParams(replan_delay_behind=behind_delay)
        psp, policy, feet, state, t_lift, dt = _lifted_off(params)
        ahead = jnp.array([jnp.cos(state.heading), jnp.sin(state.heading), 0.0])
        fixed = (params, psp, policy)

        @jax.jit
        def step(s, t, c, v, fixed=fixed, feet=feet, dt=dt):
            return gait_lib.advance(s, *fixed, t, c, v, feet, dt)

        for sign in (-1.0, 1.0):
            s = state
            for k in range(50, 63):
                t = t_lift + k * dt
                pos, vel, _ = gait_lib.com_reference(s, params, psp, t)
                s = step(s, t, pos + sign * 0.08 * ahead, vel)
            replans[behind_delay, sign] = int(s.replans)
    assert replans.pop((0.005, -1.0)) >= 1, replans
    assert replans == {(0.005, 1.0): 0, (None, -1.0): 0, (None, 1.0): 0}
    with pytest.raises(ValueError, match="replan_delay_behind"):
        GaitParams(replan_delay_behind=-0.01)


def _lifted_off(params):
    """A gait at its first lift-off (feet at y = +-0.14, the nominal action everywhere):
    ``(psp, policy, feet, state, t_lift, dt)``."""
    psp = PSPParams()
    feet = jnp.array([[0.0, 0.14, 0.0], [0.0, -0.14, 0.0]])
    policy = lambda s: jnp.array([0.25, 0.2, 0.0])  # noqa: E731
    t_lift, dt = params.start_duration, 1e-3
    state = gait_lib.init_gait(params, psp, jnp.array([0.0, 0.0, 1.06]), feet)
    zero = jnp.zeros(3)
    state = gait_lib.advance(state, params, psp, policy, t_lift, zero, zero, feet, dt)
    return psp, policy, feet, state, t_lift, dt


def _pushed_after_lift_off(params, direction, offset, speed):
    """The gait 40-80 ms after its first lift-off, fed a CoM ``offset`` m off its reference
    and ``speed`` m/s faster along ``direction(state)`` (a unit 3-vector) every tick."""
    psp, policy, feet, state, t_lift, dt = _lifted_off(params)
    d = direction(state)

    # One compile. Op by op these ticks took minutes; the pytest worker that ran them then
    # aborted in a later test's XLA compile, and op-by-op runs outside pytest logged "LLVM
    # compilation error: Cannot allocate memory".
    @jax.jit
    def tick(state, t):
        pos, vel, _ = gait_lib.com_reference(state, params, psp, t)
        return gait_lib.advance(
            state, params, psp, policy, t, pos + offset * d, vel + speed * d, feet, dt
        )

    for k in range(40, 80):
        state = tick(state, jnp.asarray(t_lift + k * dt))
    return state


def test_a_foot_landing_late_does_not_lift_the_next_steps():
    """At the planned touch-down the landing foot is still 5 cm up (it lands late after a
    push): the new stance frame keeps the planned landing height, so the next footstep and
    the CoM reference stay on the floor; the measured x, y are kept."""
    params = GaitParams()
    psp, policy, feet, state, t_lift, dt = _lifted_off(params)
    landing = 1 - int(state.stance)
    t_down = t_lift + float(state.step_duration)
    target = state.target
    assert float(target[2]) == 0.0
    late = feet.at[landing].set(target + jnp.array([0.01, -0.02, 0.05]))
    t_switch = t_down + params.max_touchdown_delay  # it never came down: switches anyway
    pos, vel, _ = gait_lib.com_reference(state, params, psp, t_switch)
    new = gait_lib.advance(state, params, psp, policy, t_switch, pos, vel, late, dt)
    assert int(new.step) == 2 and int(new.stance) == landing
    np.testing.assert_allclose(new.stance_pos, late[landing].at[2].set(0.0), atol=1e-12)
    assert float(new.target[2]) == 0.0
    com_z = gait_lib.com_reference(new, params, psp, t_switch + 0.1)[0][2]
    assert float(com_z) == pytest.approx(psp.h, abs=1e-9)


def test_a_touchdown_far_off_the_reference_plans_from_eq34s_blend():
    """A push that ends as the foot lands: the measured CoM is 8 cm behind its reference
    and 0.3 m/s slower at the touch-down. With ``replan_at_touchdown`` the new step's plan
    and CoM reference start from Eq. 34's blend; without it, or with replanning off, from
    the reference."""
    gamma = GaitParams().replan_gamma
    starts = {}
    for at_touchdown, replan in ((True, True), (False, True), (True, False)):
        params = GaitParams(replan_at_touchdown=at_touchdown, replan=replan)
        psp, policy, feet, state, t_lift, dt = _lifted_off(params)
        landing = 1 - int(state.stance)
        t_down = t_lift + float(state.step_duration)
        landed = feet.at[landing].set(state.target)
        pos, vel, _ = gait_lib.com_reference(state, params, psp, t_down)
        off = jnp.array([-0.08, 0.0, 0.0]), jnp.array([-0.3, 0.0, 0.0])
        new = gait_lib.advance(
            state, params, psp, policy, t_down, pos + off[0], vel + off[1], landed, dt
        )
        assert int(new.step) == 2
        starts[at_touchdown, replan] = (new.com_pos0, new.com_vel0, new.target)
        blend = (pos[:2] + (1 - gamma) * off[0][:2], vel[:2] + (1 - gamma) * off[1][:2])
        want = blend if (at_touchdown and replan) else (pos[:2], vel[:2])
        np.testing.assert_allclose(new.com_pos0, want[0], atol=1e-12)
        np.testing.assert_allclose(new.com_vel0, want[1], atol=1e-12)
    # The blended start, slower, plans another footstep.
    assert not np.allclose(starts[True, True][2], starts[False, True][2])
    np.testing.assert_allclose(starts[True, False][2], starts[False, True][2], atol=1e-12)


def test_touchdown_waits_for_a_late_foot_and_presses_it_down():
    """At the planned touch-down the landing foot is 3 cm up: the stance does not switch,
    the swing reference goes ``late_landing_depth`` below the target; it switches as soon
    as the foot is down, or after ``max_touchdown_delay`` if it never is."""
    params = GaitParams(max_touchdown_delay=0.1)
    psp, policy, feet, state, t_lift, dt = _lifted_off(params)
    zero = jnp.zeros(3)
    landing = 1 - int(state.stance)
    t_down = t_lift + float(state.step_duration)
    up = feet.at[landing].set(state.target + jnp.array([0.0, 0.0, 0.03]))
    down = feet.at[landing].set(state.target + jnp.array([0.0, 0.0, 0.004]))

    def tick(s, t, f):
        pos, vel, _ = gait_lib.com_reference(s, params, psp, t)
        return gait_lib.advance(s, params, psp, policy, t, pos, vel, f, dt)

    waiting = tick(state, t_down, up)
    assert int(waiting.step) == 1
    ref = gait_lib.references(waiting, params, psp, t_down + 0.01, zero, zero)
    assert float(ref.swing.pos[2]) == pytest.approx(
        float(state.target[2]) - params.late_landing_depth, abs=1e-12
    )
    assert float(ref.contact[landing]) == 0.0
    assert int(tick(waiting, t_down + 0.02, down).step) == 2  # down: switches
    assert int(tick(waiting, t_down + 0.05, up).step) == 1  # still up: waits
    late = t_down + params.max_touchdown_delay
    assert int(tick(waiting, late, up).step) == 2  # up, but waited long enough


def test_step_timing_adaptation_bounds_the_lateral_dcm_at_touchdown():
    """``dcm_time_limit`` is when the LIPM's lateral DCM reaches ``max_lateral_dcm``
    (checked by numerical integration), and a replan after a lateral push lands then,
    flagged ``STEP_SHORTENED``."""
    psp, params = PSPParams(), GaitParams()
    w = psp.omega
    for rel, vel in (((0.0, 0.05), (0.3, 0.4)), ((0.0, 0.02), (0.3, -0.5))):
        rel, vel = jnp.asarray(rel), jnp.asarray(vel)
        t_max = float(step_timing.dcm_time_limit(params, w, rel, vel))
        sol = solve_ivp(
            lambda _, x: [x[1], w**2 * x[0]], (0, t_max), [rel[1], vel[1]], rtol=1e-11, atol=1e-12
        )
        xi = sol.y[0, -1] + sol.y[1, -1] / w
        bound = params.max_lateral_dcm[1] if xi > 0 else params.max_lateral_dcm[0]
        assert abs(xi) == pytest.approx(bound, rel=1e-7)
    # Walking: a CoM 8 cm off its reference and running sideways at 0.8 m/s replans.
    nominal = float(_lifted_off(params)[3].step_duration)
    state = _pushed_after_lift_off(
        params, lambda s: s.lateral_sign * jnp.array([0.0, 1.0, 0.0]), 0.08, 0.8
    )
    assert int(state.replans) >= 1
    assert int(state.last_reason) & int(Reason.STEP_SHORTENED)
    assert float(state.step_duration) < nominal


def test_step_timing_adaptation_bounds_the_com_lead():
    """``com_lead_time_limit`` is when the LIPM's CoM runs ``max_com_lead`` ahead of the
    stance foot (checked by numerical integration: the crossing is outward), 0 when it is out
    and leaving, never when it does not diverge forward; a replan after a forward push is
    shortened by it, with the lateral bound out of the way."""
    psp = PSPParams()
    # The walking case below is set up for Eq. 34's even blend (the measured state half of
    # the re-plan's); at the default 0.2 its re-plan is not the shortened one.
    params = GaitParams(max_lateral_dcm=(4.9, 4.9), max_com_lead=0.2, replan_gamma=0.5)
    w, lead = psp.omega, params.max_com_lead
    for x0, v0 in ((0.0, 0.8), (-0.1, 0.9), (0.25, -0.5), (0.3, -0.8)):
        rel, vel = jnp.asarray([x0, 0.0]), jnp.asarray([v0, 0.0])
        t_max = float(step_timing.com_lead_time_limit(params, w, rel, vel))
        assert 0 < t_max < params.max_step_duration
        sol = solve_ivp(
            lambda _, x: [x[1], w**2 * x[0]], (0, t_max), [x0, v0], rtol=1e-11, atol=1e-12
        )
        assert sol.y[0, -1] == pytest.approx(lead, rel=1e-6)
        assert sol.y[1, -1] > 0  # crossing outwards
    out = step_timing.com_lead_time_limit(
        params, w, jnp.asarray([0.25, 0.0]), jnp.asarray([0.1, 0])
    )
    assert float(out) == 0.0
    back = step_timing.com_lead_time_limit(
        params, w, jnp.asarray([-0.3, 0.0]), jnp.asarray([0.5, 0])
    )
    assert float(back) == params.max_step_duration
    # Gradients stay finite in every branch (crossing, staying out, never reaching).
    for x0, v0 in ((0.0, 0.8), (0.25, -0.5), (-0.3, 0.5)):
        g = jax.grad(lambda r, v: step_timing.com_lead_time_limit(params, w, r, v), (0, 1))(
            jnp.asarray([x0, 0.0]), jnp.asarray([v0, 0.0])
        )
        assert all(bool(jnp.all(jnp.isfinite(x))) for x in g)
    # Walking: a CoM 3 cm ahead of its reference and 0.3 m/s fast replans; with the bound
    # lowered to 8 cm that replan is shortened, with the default it is not.
    touchdown = {}
    for bound in (GaitParams().max_com_lead, 0.08):
        params = dataclasses.replace(params, max_com_lead=bound)
        ahead = lambda s: jnp.array([jnp.cos(s.heading), jnp.sin(s.heading), 0.0])  # noqa: E731
        state = _pushed_after_lift_off(params, ahead, 0.03, 0.3)
        assert int(state.replans) >= 1
        shortened = bool(int(state.last_reason) & int(Reason.STEP_SHORTENED))
        assert shortened == (bound == 0.08)
        touchdown[bound] = float(state.step_start + state.step_duration)
    assert touchdown[0.08] < touchdown[GaitParams().max_com_lead] - 0.03
    with pytest.raises(ValueError, match="max_com_lead"):
        GaitParams(max_com_lead=0.0)


# --- pushes -----------------------------------------------------------------------------


def test_push_force_window_and_direction():
    pushes = PushArrays.of([Push(100.0, 90.0, 1.0, 0.1), Push(50.0, 180.0, 1.08, 0.1)])
    assert pushes.magnitude.shape == (2,)
    force = lambda t: np.asarray(push_force(pushes, t))  # noqa: E731
    np.testing.assert_allclose(force(0.99), 0.0)
    np.testing.assert_allclose(force(1.05), [[0.0, 100.0, 0.0], [0.0, 0.0, 0.0]], atol=1e-6)
    np.testing.assert_allclose(force(1.09), [[0.0, 100.0, 0.0], [-50.0, 0.0, 0.0]], atol=1e-5)
    np.testing.assert_allclose(force(1.1)[0], 0.0)
    model = load_valkyrie()
    data = mujoco.MjData(model)
    pelvis = body_index(model, "pelvis")
    for t in (0.99, 1.05, 1.09, 1.2):
        data.time = t
        apply_push_c(model, data, pushes, pelvis)
        np.testing.assert_allclose(data.xfrc_applied[pelvis, :3], force(t).sum(0), atol=1e-5)


def test_push_arrays_from_config_pairs():
    pushes = PushArrays.from_pairs([[150, 90], [0, -45]], 0.3, 0.1, np.float32)
    np.testing.assert_allclose(pushes.direction, np.radians([90, -45]), rtol=1e-6)
    np.testing.assert_allclose(pushes.start, 0.3)
    assert pushes.magnitude.dtype == np.float32
    for bad, field in (([], "pushes:"), ([[10]], "pushes[0]"), ([[1, 0], [-5, 0]], "pushes[1]")):
        with pytest.raises(ValueError, match=re.escape(field)):
            PushArrays.from_pairs(bad, 0.0, 0.1)
    with pytest.raises(ValueError, match="duration must be > 0"):
        PushArrays.from_pairs([[1, 0]], 0.0, 0.0)


def test_physics_params_torque_limit_clips_every_actuator():
    model = load_valkyrie()
    own = mjx_loop.physics_model(model, mjx_loop.PhysicsParams(torque_limit="model"))
    np.testing.assert_array_equal(own.actuator_ctrlrange, model.actuator_ctrlrange)
    authors = mjx_loop.physics_model(model, mjx_loop.PhysicsParams(torque_limit=500.0))
    np.testing.assert_allclose(authors.actuator_ctrlrange, [[-500.0, 500.0]] * model.nu)
    assert model.actuator_ctrlrange[:, 1].max() < 500  # the model itself is untouched
    data = mujoco.MjData(authors)
    data.ctrl[:] = 1e4
    mujoco.mj_forward(authors, data)
    np.testing.assert_allclose(data.actuator_force, 500.0)
    with pytest.raises(ValueError, match="torque_limit"):
        mjx_loop.PhysicsParams(torque_limit=0.0)
    with pytest.raises(ValueError, match="torque_limit must be > 0 N m, or 'model'"):
        mjx_loop.PhysicsParams(torque_limit="modle")
    # One spelling per setting, so equal settings give equal sweep digests.
    assert mjx_loop.PhysicsParams(torque_limit=None).torque_limit == "model"
    assert mjx_loop.PhysicsParams(torque_limit=300).torque_limit == 300.0


# --- closed loop ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def walker():
    model = load_valkyrie()
    return model, make_walking_controller(model)


def test_walks_a_few_steps_and_recovers_a_push_ci_sized(walker):
    """End to end on MuJoCo: start, four steps, a 250 N x 0.1 s lateral push mid-swing."""
    model, ctrl = walker
    push = Push(250.0, 90.0, 2.0, 0.1)
    res = simulate_walk(model, ctrl, 3.8, pushes=(push,))
    o = res.log.outputs
    assert not res.fell, res.fall_time
    assert res.steps_taken >= 3
    assert int(o.failed_plans[-1]) == 0
    before = res.log.time < 2.0
    assert np.max(o.com_error[before]) < 0.02  # the CoM follows the LIPM reference
    assert np.max(o.com_error[~before]) > np.max(o.com_error[before])  # the push is felt
    # Upright: the CoM keeps its reference height (the pelvis itself bobs by +-3 cm a step).
    assert np.max(np.abs(o.com[:, 2] - o.com_ref[:, 2])) < 0.02
    walking = res.log.time > ctrl.gait_params.start_duration + 0.5
    np.testing.assert_allclose(o.com_ref[walking, 2], ctrl.gait_params.com_height, atol=0.01)
    assert np.min(res.log.qpos[:, 2]) > 0.9


def test_a_frontal_push_that_reverses_the_com_gets_a_backward_step_ci_sized(walker):
    """An 85 N s push from the front mid-swing (the paper's torque bound) sends the CoM
    backwards: the PSP has no apex for a CoM moving back, so the plans fall back to the
    capture step, which lands the swing foot well behind the stance foot, and the robot
    stands on it."""
    model, ctrl = walker
    res = simulate_walk(model, ctrl, 3.8, pushes=(Push(850.0, 180.0, 2.0, 0.1),))
    o = res.log.outputs
    t = res.log.time
    assert np.min(o.com_vel[:, 0]) < -0.2  # the push reversed the walk
    step, stance, feet = np.asarray(o.step), np.asarray(o.stance), np.asarray(o.feet)
    landed = np.flatnonzero(np.diff(step) > 0) + 1  # the tick each swing foot lands
    # Along x (the walk goes straight along x): the landed foot against the stance foot it
    # stepped from.
    advance = feet[landed, stance[landed], 0] - feet[landed - 1, stance[landed - 1], 0]
    back = landed[advance < -0.05]
    assert len(back), advance
    k = back[0]
    swing = (t > 2.0) & (step == step[k] - 1)  # the step's plans, from the push on
    assert np.any(np.asarray(o.reason)[swing] & int(Reason.NO_APEX))  # capture steps
    assert res.fall_time is None or res.fall_time > t[k] + 0.5, res.fall_time


def test_walking_controller_plans_at_the_gait_com_height(walker):
    """``GaitParams.com_height`` replaces the planner's LIPM height; None keeps the height
    the policy was trained at."""
    model, ctrl = walker
    trained = load_planner()
    assert ctrl.psp.h == GaitParams().com_height != trained.psp.h
    assert ctrl.psp.omega == pytest.approx(np.sqrt(9.81 / GaitParams().com_height))
    kept = make_walking_controller(model, gait=GaitParams(com_height=None), planner=trained)
    assert kept.psp == trained.psp


def test_cam_reference_is_the_momentum_of_the_commanded_turn_and_the_arm_return(walker):
    """The walking CAM reference equals the centroidal angular momentum A_G qd of (a) the
    whole robot turning rigidly at the commanded yaw rate (checks the free joint's local
    angular velocity convention) plus (b) the arms moving back to their posture."""
    from jaxloco.locomotion.walking import ARM_TASK, _cam_reference

    model, ctrl = walker
    q = np.array(keyframe_qpos(model, "walk"), dtype=np.float64)
    q[3:7] = Rotation.from_euler("zyx", [2.3, 0.1, -0.05]).as_quat(scalar_first=True)
    arms = ctrl.wblc.indices[ARM_TASK]
    q[list(arms.qpos)] += np.linspace(-0.2, 0.3, len(arms.qpos))  # arms off their posture
    yaw_rate, rate = 0.7, ctrl.gait_params.arm_return_rate
    R = Rotation.from_quat(q[3:7], scalar_first=True).as_matrix()
    qd = np.zeros(model.nv)
    qd[3:6] = R.T @ np.array([0.0, 0.0, yaw_rate])  # world-z turn, in the base frame
    qd[list(arms.dof)] = rate * (np.asarray(ctrl.posture[ARM_TASK].pos) - q[list(arms.qpos)])
    # Jitted: op by op, the snapshot alone is hundreds of small compiles.
    snap = jax.jit(type(ctrl.wblc).snapshot)(
        ctrl.wblc, jnp.asarray(q, jnp.float32), jnp.zeros(model.nv, jnp.float32)
    )
    body = gait_lib.yaw_reference(Motion(jnp.float32(2.3), jnp.float32(yaw_rate), jnp.float32(0.4)))
    ref = jax.jit(_cam_reference)(ctrl, snap, jnp.asarray(q, jnp.float32), body)
    expected = np.asarray(snap.centroidal_matrix[:3]) @ qd
    assert np.linalg.norm(expected) > 1.0  # a real momentum, not a trivial match
    np.testing.assert_allclose(ref.pos, expected, rtol=1e-4, atol=1e-3)
    # The feed-forward rate is the turn's: A_G of the yaw axis times the yaw acceleration.
    qd_acc = np.zeros(model.nv)
    qd_acc[3:6] = R.T @ np.array([0.0, 0.0, 0.4])
    np.testing.assert_allclose(
        ref.acc, np.asarray(snap.centroidal_matrix[:3]) @ qd_acc, rtol=1e-4, atol=1e-4
    )


def test_mjx_and_mujoco_c_agree_through_liftoff(walker):
    """The same controller on both backends, same solver settings, float64: the CoM
    agrees within 1 mm and the feet within 5 mm (the swing foot moves at up to ~1 m/s; measured
    1.7 mm) over 1.3 s: standing, weight shift, lift-off and swing."""
    model, ctrl = walker
    steps = 1300
    physics = mjx_loop.physics_model(model, mjx_loop.PhysicsParams())
    q0 = keyframe_qpos(model, "walk")
    pushes = PushArrays.none()
    mx = mjx.put_model(physics)
    data = mujoco.MjData(physics)
    data.qpos[:] = q0
    mujoco.mj_forward(physics, data)
    cstate = jax.jit(WalkingController.init)(ctrl, jnp.asarray(q0), engine=engine_terms(data))
    state = mjx_loop.loop_state_from_c(mx, physics, data, cstate)  # nothing to compile
    roll = jax.jit(lambda s: mjx_loop.rollout(mx, ctrl.step, s, pushes, 1, steps, 100))
    final, logs = roll(state)
    assert not bool(final.fell)

    from jaxloco.sim import run_closed_loop

    # Each backend hands the controller its own engine's terms of each state.
    log, _ = run_closed_loop(physics, data, jax.jit(ctrl.step), cstate, steps, engine=True)
    # MJX logs the controller's view of the last tick of every 100.
    c_com = log.outputs.com[99::100]
    c_feet = log.outputs.feet[99::100]
    mjx_log = logs.last.controller
    assert np.abs(np.asarray(mjx_log.com) - c_com).max() < 1e-3
    assert np.abs(np.asarray(mjx_log.feet) - c_feet).max() < 5e-3
    assert int(mjx_log.phase[-1]) == gait_lib.WALK
    # ... and the state after those 100 ticks: the base's position.
    np.testing.assert_allclose(np.asarray(logs.qpos)[:-1, :3], log.qpos[100::100, :3], atol=5e-3)


# --- experiments, CI-sized ---------------------------------------------------------------


def test_walk_steer_experiment_ci_sized(tmp_path):
    from cli_helpers import run_cli

    proc = run_cli(
        [
            "walk-steer",
            "segments=[[2,10.0]]",
            "extra_steps=0",
            "video_fps=4",
            "pushes=[{magnitude:150,direction_deg:90,start:1.8,duration:0.1}]",
        ],
        tmp_path,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "run"
    summary = json.loads((run / "walk_steer.json").read_text())
    assert summary["completed"] and not summary["fell"]
    assert summary["final_heading_deg"] == pytest.approx(20.0, abs=1e-3)
    assert (run / "walk_steer.png").stat().st_size > 10_000
    assert (run / "walk_steer.gif").stat().st_size > 10_000


@pytest.mark.slow  # 2.6 min (three runs, two controllers); the walk+push test covers CI
def test_push_recovery_experiment_ci_sized(tmp_path):
    from cli_helpers import run_cli

    proc = run_cli(
        [
            "push-recovery",
            "directions_deg=[90]",
            "magnitude=150",
            "push_time=1.8",
            "duration=4.2",
            "steps_after=2",
            "videos=false",
        ],
        tmp_path,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "run"
    summary = json.loads((run / "push_recovery.json").read_text())
    assert set(summary["results"]) == {"replan", "no_replan"}
    assert summary["results"]["replan"]["90"]["recovered"]
    assert summary["replanning_15_steps"]["median_ms"] > 0
    assert "| replan | 90 |" in (run / "push_recovery.md").read_text()
    assert (run / "push_recovery.png").exists()


@pytest.mark.slow  # ~4 min: 23 s of simulated walking
def test_walk_steer_paper_schedule_completes(tmp_path):
    """Fig. 11 in full: 12 steps at +18.8 deg, 5 straight, 12 at -18.8, then 2 straight."""
    from cli_helpers import run_cli

    proc = run_cli(["walk-steer", "video=false"], tmp_path, timeout=1500)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((tmp_path / "run" / "walk_steer.json").read_text())
    assert summary["completed"] and not summary["fell"]
    assert summary["max_heading_deg"] == pytest.approx(225.6, abs=0.1)
    assert summary["final_heading_deg"] == pytest.approx(0.0, abs=1e-3)
    assert summary["max_com_error_m"] < 0.05


@pytest.mark.parametrize("experiment", ["walk-steer", "push-recovery"])
def test_walking_experiments_load_a_gains_file(tmp_path, experiment):
    """The gains file's gait section reaches GaitParams (whose range check then refuses a
    gamma of 2) before anything is simulated."""
    from cli_helpers import run_cli

    from jaxloco.control.gains import save_gains

    path = save_gains(tmp_path / "g.json", {}, gait={"replan_gamma": 2.0})
    proc = run_cli([experiment, f"gains_file={path}"], tmp_path, timeout=300)
    assert proc.returncode != 0
    assert "GaitParams.replan_gamma must be in [0, 1]" in proc.stderr, proc.stderr[-2000:]


def test_render_gif_twice_headless_falls_back_without_aborting(tmp_path):
    """Without a display or a headless GL backend, MuJoCo's GLFW renderer fails, and a
    second attempt in the same process has aborted it: ``auto`` must draw stick figures."""
    import os
    import subprocess
    import sys

    script = (
        "import numpy as np, sys\n"
        "from jaxloco.dynamics.model import keyframe_qpos, load_valkyrie\n"
        "from jaxloco.sim.render import render_gif\n"
        "m = load_valkyrie(); q = np.tile(keyframe_qpos(m, 'walk'), (3, 1))\n"
        "for k in range(2):\n"
        "    render_gif(m, q, f'{sys.argv[1]}/run{k}.gif', width=64, height=48)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "MUJOCO_GL")}
    done = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path)], env=env, capture_output=True, timeout=300
    )
    assert done.returncode == 0, done.stderr.decode()[-2000:]
    assert (tmp_path / "run0.gif").stat().st_size > 0 and (tmp_path / "run1.gif").exists()
