"""plan_step: against numerical integration, fixed point, properties, gradients, batching."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads
from scipy.integrate import solve_ivp

from jaxloco.planner import (
    INFEASIBLE,
    PSPParams,
    Reason,
    describe_reason,
    plan_from_com_state,
    plan_step,
    safety_margins,
    smooth_reward,
)

P = PSPParams()
W = P.omega
STATE_LOW, STATE_HIGH = np.array([-0.14, 0.03, -0.55]), np.array([0.20, 0.61, 0.55])  # Eq. 1
ACTION_LOW, ACTION_HIGH = np.array(P.action_low), np.array(P.action_high)  # Eq. 2


def feasible_cases(n, seed=0, min_time=0.05):
    """Random (state, action) pairs from the boxes of Eq. 1-2 whose equations have a solution
    with both times comfortably positive (they may still be terminal by Eq. 4)."""
    rng = np.random.default_rng(seed)
    states = rng.uniform(STATE_LOW, STATE_HIGH, (20 * n, 3))
    actions = rng.uniform(ACTION_LOW, ACTION_HIGH, (20 * n, 3))
    plan = plan_step(states, actions, P)
    ok = (
        ((np.asarray(plan.reason) & int(INFEASIBLE)) == 0)
        & (np.asarray(plan.t_switch) > min_time)
        & (np.asarray(plan.t_apex) > min_time)
    )
    idx = np.flatnonzero(ok)[:n]
    assert len(idx) == n, "not enough feasible random cases"
    return states[idx], actions[idx]


def lipm_rhs(pivot):
    px, py = pivot

    def rhs(_, s):
        x, xd, y, yd = s
        return [xd, W**2 * (x - px), yd, W**2 * (y - py)]

    return rhs


def integrate(s0, pivot, t_end, event):
    event.terminal = True
    sol = solve_ivp(
        lipm_rhs(pivot),
        (0.0, t_end),
        s0,
        method="DOP853",
        rtol=1e-13,
        atol=1e-14,
        events=event,
        dense_output=True,
    )
    assert sol.status == 1, "event not reached"
    t_event = sol.t_events[0][0]
    return t_event, sol.y_events[0][0]


CASES = list(zip(*feasible_cases(40), strict=True))


@pytest.mark.parametrize("state,action", CASES)
def test_plan_matches_numerical_integration(state, action):
    """Switch and apex times, switching state, p_y and the next apex state match an
    independent integration of the LIPM that detects the switch and apex by events."""
    plan = plan_step(state, action, P)
    y0, xd0, yd0 = state
    p_x, v_next, yd_next = action

    # Stance 1 (foot at the origin) until the CoM reaches the next foot's orbit through
    # its apex: xd^2 - w^2 (x - p_x)^2 - v_next^2 changes sign there.
    def on_next_orbit(_, s):
        return s[1] ** 2 - W**2 * (s[0] - p_x) ** 2 - v_next**2

    t_sw, s_sw = integrate([0.0, xd0, y0, yd0], (0.0, 0.0), 5.0, on_next_orbit)
    np.testing.assert_allclose(float(plan.t_switch), t_sw, atol=1e-8)
    np.testing.assert_allclose(
        [plan.x_switch, plan.xd_switch, plan.y_switch, plan.yd_switch], s_sw, atol=1e-8
    )

    # Stance 2 (the planned foot) until the sagittal apex x = p_x.
    def at_apex(_, s):
        return s[0] - p_x

    t_ap, s_ap = integrate(s_sw, (p_x, float(plan.p_y)), 5.0, at_apex)
    np.testing.assert_allclose(float(plan.t_apex), t_ap, atol=1e-8)
    # The planned p_y produces the requested apex velocities...
    np.testing.assert_allclose([s_ap[1], s_ap[3]], [v_next, yd_next], atol=1e-8)
    # ...and the next apex state, mirrored into the new foot's frame, matches.
    expected = [-(s_ap[2] - float(plan.p_y)), s_ap[1], -s_ap[3]]
    np.testing.assert_allclose(plan.next_state, expected, atol=1e-8)


@pytest.mark.parametrize("p_x", [0.15, 0.25, 0.318, 0.45])
def test_nominal_gait_is_a_fixed_point(p_x):
    nominal = jnp.asarray(P.nominal_state)
    plan = plan_step(nominal, jnp.array([p_x, P.xd_apex_nominal, 0.0]), P)
    np.testing.assert_allclose(plan.next_state, nominal, atol=1e-12)
    # A symmetric step: switch half way in space and in time.
    assert float(plan.x_switch) == pytest.approx(p_x / 2, abs=1e-12)
    assert float(plan.t_switch) == pytest.approx(float(plan.t_apex), abs=1e-12)


def test_reward_matches_eq3():
    plan = plan_step(jnp.array([0.056, 0.2, 0.0]), jnp.array([0.3, 0.25, 0.1]), P)
    assert not bool(plan.terminal)
    expected = -((0.2 - 0.25) ** 2) - 15 * (0.3 - float(plan.p_y)) ** 2 - 0.1**2
    assert float(plan.reward) == pytest.approx(expected, abs=1e-14)


@pytest.mark.parametrize(
    "state,action,reason",
    [
        ([0.056, 0.2, 0.0], [0.0, 0.2, 0.0], Reason.NO_SWITCH_STATE),
        ([0.056, 0.0, 0.0], [0.3, 0.2, 0.0], Reason.SWITCH_UNREACHABLE),
        ([0.056, -0.3, 0.0], [0.3, 0.2, 0.0], Reason.SWITCH_UNREACHABLE),
        ([0.056, 0.2, 0.0], [0.3, 0.0, 0.0], Reason.APEX_UNREACHABLE),
        ([0.056, 0.2, 0.0], [0.3, -0.2, 0.0], Reason.APEX_UNREACHABLE),
        ([0.056, 0.6, 0.0], [0.1, 0.05, 0.0], Reason.SWITCH_TOO_SOON),
        ([0.056, 0.05, 0.0], [0.1, 0.6, 0.0], Reason.APEX_TOO_SOON),
        ([0.15, 0.2, 0.3], [0.3, 0.2, 0.0], Reason.P_Y_OUT_OF_RANGE),
        ([0.056, 0.2, 0.0], [0.05, 0.2, 0.1], Reason.STRIDE_OUT_OF_RANGE),
        ([np.nan, 0.2, 0.0], [0.3, 0.2, 0.0], Reason.INVALID_INPUT),
        ([0.056, 0.2, 0.0], [0.3, np.inf, 0.0], Reason.INVALID_INPUT),
        ([0.056, 0.2, 0.0], [0.3, 2e3, 0.0], Reason.INVALID_INPUT),
    ],
)
def test_infeasible_inputs_are_flagged_with_finite_fields(state, action, reason):
    plan = plan_step(jnp.array(state), jnp.array(action), P)
    assert bool(plan.terminal)
    assert int(plan.reason) & reason.value, describe_reason(int(plan.reason))
    assert float(plan.reward) == P.terminal_reward
    for leaf in jax.tree.leaves(plan):
        assert bool(jnp.all(jnp.isfinite(leaf)))
    if reason in (Reason.INVALID_INPUT,):
        assert int(plan.reason) == reason.value
        assert not any(bool(v) for v in jax.tree.leaves(plan.valid))


def test_safety_margins_agree_with_the_terminal_bits_and_smooth_reward_with_eq3():
    rng = np.random.default_rng(3)
    states = rng.uniform(STATE_LOW, STATE_HIGH, (4000, 3))
    actions = rng.uniform(ACTION_LOW, ACTION_HIGH, (4000, 3))
    plan = plan_step(states, actions, P)
    solvable = np.asarray(plan.valid.next_state) & (
        (np.asarray(plan.reason) & int(INFEASIBLE)) == 0
    )
    margins = np.asarray(safety_margins(plan, P))
    assert margins.shape == (4000, 6)
    safety_bits = int(
        Reason.SWITCH_TOO_SOON
        | Reason.APEX_TOO_SOON
        | Reason.P_Y_OUT_OF_RANGE
        | Reason.STRIDE_OUT_OF_RANGE
    )
    unsafe = (np.asarray(plan.reason) & safety_bits) != 0
    # Among solvable steps: a step is flagged unsafe exactly when some margin is <= 0 (the
    # stride bounds are inclusive, so a margin of exactly 0 there is still safe; random
    # draws never hit it).
    assert (
        solvable.sum() > 1000 and unsafe[solvable].sum() > 100 and (~unsafe[solvable]).sum() > 100
    )
    np.testing.assert_array_equal(unsafe[solvable], (margins[solvable] <= 0).any(axis=1))
    reward = np.asarray(smooth_reward(plan, actions, P))
    safe = solvable & ~unsafe
    np.testing.assert_allclose(reward[safe], np.asarray(plan.reward)[safe], rtol=1e-12)
    # Where Eq. 3's reward switches to the terminal one, the smooth reward does not.
    assert np.all(reward[unsafe & solvable] != P.terminal_reward)


def test_describe_reason():
    assert describe_reason(0) == []
    code = Reason.SWITCH_TOO_SOON | Reason.P_Y_OUT_OF_RANGE
    assert describe_reason(int(code)) == ["SWITCH_TOO_SOON", "P_Y_OUT_OF_RANGE"]


def test_general_state_plan_agrees_with_apex_plan():
    """Starting from a later point on the same orbit gives the same step, shifted in time."""
    state, action = np.array([0.05, 0.3, 0.12]), np.array([0.3, 0.25, 0.05])
    apex_plan = plan_step(state, action, P)
    dt = 0.1
    x, xd = np.sinh(W * dt) * state[1] / W, np.cosh(W * dt) * state[1]
    y = state[0] * np.cosh(W * dt) + state[2] / W * np.sinh(W * dt)
    yd = state[0] * W * np.sinh(W * dt) + state[2] * np.cosh(W * dt)
    later = plan_from_com_state(jnp.array([x, xd, y, yd]), action, P)
    assert float(later.t_switch) == pytest.approx(float(apex_plan.t_switch) - dt, abs=1e-12)
    for f in ("x_switch", "t_apex", "p_y", "next_state"):
        np.testing.assert_allclose(getattr(later, f), getattr(apex_plan, f), atol=1e-12)


# --- properties (hypothesis) ---------------------------------------------------------

states = st.tuples(st.floats(-0.14, 0.20), st.floats(0.03, 0.61), st.floats(-0.55, 0.55)).map(
    np.array
)
actions = st.tuples(st.floats(0.1, 0.5), st.floats(0.03, 0.37), st.floats(-0.25, 0.25)).map(
    np.array
)


@settings(max_examples=200, deadline=None)
@given(states, actions)
def test_mirror_symmetry(state, action):
    """Mirroring the lateral axis mirrors p_y and the next apex state; times are unchanged."""
    flip = np.array([-1.0, 1.0, -1.0])  # (y, xd, yd)
    flip_action = np.array([1.0, 1.0, -1.0])  # (p_x, xd_next, yd_next)
    a = plan_step(state, action, P)
    b = plan_step(state * flip, action * flip_action, P)
    np.testing.assert_allclose(b.p_y, -a.p_y, atol=1e-12)
    np.testing.assert_allclose(b.next_state, a.next_state * flip, atol=1e-12)
    for f in ("t_switch", "t_apex", "x_switch", "xd_switch"):
        np.testing.assert_allclose(getattr(b, f), getattr(a, f), atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(states, actions)
def test_time_signs_follow_switch_position(state, action):
    """The switch lies ahead of the apex exactly when t_switch > 0, and the next apex lies
    ahead of the switch exactly when t_apex > 0."""
    plan = plan_step(state, action, P)
    if not (bool(plan.valid.t_switch) and bool(plan.valid.t_apex)):
        return
    x_sw, p_x = float(plan.x_switch), action[0]
    if abs(x_sw) > 1e-9:
        assert (float(plan.t_switch) > 0) == (x_sw > 0)
    if abs(p_x - x_sw) > 1e-9:
        assert (float(plan.t_apex) > 0) == (x_sw < p_x)
    if not bool(plan.terminal):
        assert float(plan.t_switch) > P.t_switch_min and float(plan.t_apex) > P.t_apex_min


@settings(max_examples=100, deadline=None)
@given(states, st.floats(0.1, 0.5), st.floats(-0.25, 0.25))
def test_t_apex_decreases_with_next_apex_velocity(state, p_x, yd_next):
    """A faster next apex is reached sooner from the switch, and the switch comes later."""
    v = np.linspace(0.03, 0.37, 12)
    acts = np.stack([np.full_like(v, p_x), v, np.full_like(v, yd_next)], -1)
    plan = plan_step(np.broadcast_to(state, acts.shape), acts, P)
    ok = np.asarray(plan.valid.t_apex) & np.asarray(plan.valid.t_switch)
    t_ap, t_sw = np.asarray(plan.t_apex)[ok], np.asarray(plan.t_switch)[ok]
    assert np.all(np.diff(t_ap) < 0)
    assert np.all(np.diff(t_sw) > 0)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=7, max_size=7))
def test_any_input_gives_finite_output(values):
    plan = plan_step(np.array(values[:3]), np.array(values[3:6]), P)
    for leaf in jax.tree.leaves(plan):
        assert bool(jnp.all(jnp.isfinite(leaf)))
    if int(plan.reason) & int(INFEASIBLE):
        assert bool(plan.terminal)


# --- gradients, jit, vmap, dtypes ----------------------------------------------------

GRAD_FIELDS = ("x_switch", "xd_switch", "t_switch", "t_apex", "p_y", "next_state", "reward")


@pytest.mark.parametrize("case", range(4))
def test_check_grads(case):
    state, action = (jnp.asarray(a) for a in CASES[case])

    def outputs(s, a):
        plan = plan_step(s, a, P)
        return [getattr(plan, f) for f in GRAD_FIELDS]

    check_grads(outputs, (state, action), order=2, modes=("fwd", "rev"), eps=1e-6)


def test_gradients_are_finite_on_infeasible_inputs():
    def loss(s, a):
        plan = plan_step(s, a, P)
        return sum(jnp.sum(getattr(plan, f)) for f in GRAD_FIELDS)

    for s, a in (([0.05, 0.0, 0.0], [0.3, 0.2, 0.0]), ([0.05, 0.2, 0.0], [0.0, 0.0, 0.0])):
        gs = jax.grad(loss, argnums=(0, 1))(jnp.array(s), jnp.array(a))
        assert all(bool(jnp.all(jnp.isfinite(g))) for g in gs)


def test_jit_and_vmap_match_unbatched_calls():
    """vmap and broadcasting run the same elementwise ops: bit-identical. Under jit, XLA
    fuses and may reorder float operations: equal to within a few ulps of the inputs."""
    states, acts = feasible_cases(64, seed=3)
    step = lambda s, a: plan_step(s, a, P)  # noqa: E731
    vmapped = jax.vmap(step)(states, acts)
    broadcast = step(states, acts)
    jitted = jax.jit(jax.vmap(step))(states, acts)
    for i in range(len(states)):
        single = step(states[i], acts[i])
        jit_single = jax.jit(step)(states[i], acts[i])
        leaves = zip(
            jax.tree.leaves(single),
            jax.tree.leaves(vmapped),
            jax.tree.leaves(broadcast),
            jax.tree.leaves(jitted),
            jax.tree.leaves(jit_single),
            strict=True,
        )
        for want, got_v, got_b, got_jv, got_j in leaves:
            np.testing.assert_array_equal(got_v[i], want)
            np.testing.assert_array_equal(got_b[i], want)
            np.testing.assert_allclose(got_jv[i], want, rtol=0, atol=1e-12)
            np.testing.assert_allclose(got_j, got_jv[i], rtol=0, atol=1e-12)


def test_float32_stays_float32_and_compiles_once():
    # Count traces, not the C++ dispatch cache: that cache's size depends on
    # which fast path the process happens to take and has read 0 under xdist.
    traces = []

    def plan(s, a):
        traces.append(s.dtype)
        return plan_step(s, a, P)

    f = jax.jit(plan)
    s = jnp.asarray([0.056, 0.2, 0.0], jnp.float32)
    a = jnp.asarray([0.3, 0.2, 0.0], jnp.float32)
    out = f(s, a)
    assert out.t_switch.dtype == jnp.float32 and out.next_state.dtype == jnp.float32
    f(s + 0.001, a)
    f(np.asarray([0.05, 0.21, 0.0], np.float32), a)
    assert len(traces) == 1


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match=r"state must have shape \(\.\.\., 3\)"):
        plan_step(jnp.zeros(4), jnp.zeros(3), P)
    with pytest.raises(ValueError, match=r"action must have shape"):
        plan_step(jnp.zeros(3), jnp.zeros(2), P)


# --- parameters ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "change,match",
    [
        (dict(h=0.0), r"PSPParams\.h must be > 0"),
        (dict(h=-1.0), r"PSPParams\.h must be > 0"),
        (dict(g=0.0), r"PSPParams\.g must be > 0"),
        (dict(p_y_min=0.5, p_y_max=0.1), r"PSPParams\.p_y_min must be < p_y_max"),
        (dict(stride_min=1.0), r"PSPParams\.stride_min must be < stride_max"),
        (dict(p_x_min=0.5, p_x_max=0.5), r"PSPParams\.p_x_min must be < p_x_max"),
        (dict(t_switch_min=-0.1), r"PSPParams\.t_switch_min must be >= 0"),
        (dict(h=float("nan")), r"PSPParams\.h must be finite"),
    ],
)
def test_invalid_params_raise_naming_the_field(change, match):
    with pytest.raises(ValueError, match=match):
        PSPParams(**change)


def test_params_reject_non_numbers():
    with pytest.raises(TypeError, match=r"PSPParams\.h must be a number"):
        PSPParams(h="1.0")


def test_params_defaults_are_the_papers():
    assert P.h == 1.005294 and P.g == 9.81
    assert P.nominal_state == (0.056, 0.2, 0.0)
    assert (P.t_switch_min, P.t_apex_min, P.p_y_min, P.p_y_max) == (0.12, 0.12, 0.1, 0.5)
    assert P.action_low == (0.1, 0.03, -0.25) and P.action_high == (0.5, 0.37, 0.25)
    assert hash(P) == hash(dataclasses.replace(P))
