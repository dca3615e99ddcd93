"""Multi-step planning and steering: world-frame consistency against integration."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.integrate import solve_ivp

from jaxloco.planner import (
    PSPParams,
    Reason,
    make_lookahead_policy,
    plan_step,
    plan_steps,
    sample_com_trajectory,
    steering,
    turn_schedule,
)

P = PSPParams()
W = P.omega
NOMINAL = jnp.asarray(P.nominal_state)
FIG11 = turn_schedule([(12, 18.8), (5, 0.0), (12, -18.8)])


@pytest.fixture(scope="module")
def lookahead():
    return make_lookahead_policy(P)


@pytest.fixture(scope="module")
def fig11_walk(lookahead):
    plan_fn = jax.jit(lambda s: plan_steps(s, lookahead, P, num_steps=len(FIG11), turns=FIG11))
    return plan_fn(NOMINAL)


def test_straight_walk_with_an_action_sequence():
    actions = jnp.tile(jnp.array([0.3, 0.2, 0.0]), (6, 1))
    plan = plan_steps(NOMINAL, actions, P)
    assert bool(jnp.all(plan.alive))
    np.testing.assert_allclose(plan.apex_states, jnp.tile(NOMINAL, (6, 1)), atol=1e-12)
    np.testing.assert_allclose(np.diff(plan.footsteps[:, 0]), 0.3, atol=1e-12)
    # Alternate sides: the next foot is to the left, then to the right, ...
    np.testing.assert_allclose(plan.footsteps[1::2, 1], float(plan.steps.p_y[0]), atol=1e-12)
    np.testing.assert_allclose(plan.footsteps[2::2, 1], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.diff(plan.t_apex), np.diff(plan.t_apex)[0], atol=1e-12)
    np.testing.assert_allclose(plan.apex_shift, 0.0, atol=0)


def test_each_step_starts_where_the_last_one_ended():
    rng = np.random.default_rng(1)
    actions = rng.uniform(P.action_low, P.action_high, (8, 3))
    plan = plan_steps(jnp.array([0.06, 0.25, 0.05]), actions, P)
    for k in range(7):
        single = plan_step(plan.apex_states[k], actions[k], P)
        np.testing.assert_allclose(plan.apex_states[k + 1], single.next_state, atol=1e-12)


def test_policy_function_and_action_array_agree(lookahead):
    by_policy = plan_steps(NOMINAL, lookahead, P, num_steps=10, turns=FIG11[:10])
    by_array = plan_steps(NOMINAL, by_policy.actions, P, turns=FIG11[:10])
    for a, b in zip(jax.tree.leaves(by_policy), jax.tree.leaves(by_array), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_terminal_step_masks_the_rest():
    actions = jnp.array([[0.3, 0.2, 0.0], [0.0, 0.2, 0.0], [0.3, 0.2, 0.0]])
    plan = plan_steps(NOMINAL, actions, P)
    assert plan.alive.tolist() == [True, False, False]
    assert int(plan.reason[1]) & Reason.NO_SWITCH_STATE
    assert int(plan.num_safe_steps) == 1
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(plan))


def test_fig11_steering_walk_survives_and_turns(fig11_walk):
    plan = fig11_walk
    assert bool(jnp.all(plan.alive)), plan.reason
    np.testing.assert_allclose(plan.headings[12], np.deg2rad(12 * 18.8), atol=1e-12)
    np.testing.assert_allclose(plan.headings[-1], 0.0, atol=1e-12)
    # The path turns left (CCW) first: the walking direction swings through +y.
    direction = np.diff(np.asarray(plan.footsteps[::2]), axis=0)
    cross = direction[:-1, 0] * direction[1:, 1] - direction[:-1, 1] * direction[1:, 0]
    assert np.all(cross[:4] > 0) and np.all(cross[-4:] < 0)


def test_sampled_com_is_continuous_across_switches_and_turns(fig11_walk):
    traj = sample_com_trajectory(fig11_walk, P, samples_per_phase=16)
    t = np.asarray(traj.t).reshape(-1)
    pos = np.asarray(traj.position).reshape(-1, 2)
    vel = np.asarray(traj.velocity).reshape(-1, 2)
    # Phase boundaries repeat a time instant: the state there must agree from both sides.
    same_t = np.flatnonzero(np.abs(np.diff(t)) < 1e-12)
    assert len(same_t) == 2 * len(FIG11) - 1
    np.testing.assert_allclose(pos[same_t], pos[same_t + 1], atol=1e-10)
    np.testing.assert_allclose(vel[same_t], vel[same_t + 1], atol=1e-10)
    assert np.all(np.diff(t) >= -1e-12)


def test_world_trajectory_matches_integration_with_the_footstep_schedule(fig11_walk):
    """Integrate the 2-D LIPM in the world frame about each planned footstep between the
    planned switch times and compare with the sampled CoM at every sample. Each segment
    starts from the sampled state at its start (integrating all 29 steps in one go would
    amplify the integrator's 1e-12 errors by the unstable LIPM's e^{wt}); the joins are
    checked by the continuity test above."""
    plan = fig11_walk
    traj = sample_com_trajectory(plan, P, samples_per_phase=8)
    feet = np.asarray(plan.footsteps)
    switches = np.asarray(plan.t_switch)
    t_all = np.asarray(traj.t).reshape(-1)
    pos_all = np.asarray(traj.position).reshape(-1, 2)
    vel_all = np.asarray(traj.velocity).reshape(-1, 2)

    t0 = 0.0
    boundaries = list(switches) + [float(t_all[-1])]
    for k, t1 in enumerate(boundaries):
        foot = feet[k]

        def rhs(_, s, foot=foot):
            return [s[2], s[3], W**2 * (s[0] - foot[0]), W**2 * (s[1] - foot[1])]

        mask = (t_all >= t0) & (t_all <= t1)
        first = np.flatnonzero(mask)[0]
        state = np.concatenate([pos_all[first], vel_all[first]])
        sol = solve_ivp(
            rhs, (t0, t1), state, method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True
        )
        ref = sol.sol(t_all[mask]).T
        np.testing.assert_allclose(ref[:, :2], pos_all[mask], atol=1e-8)
        np.testing.assert_allclose(ref[:, 2:], vel_all[mask], atol=1e-8)
        t0 = t1


def test_plan_steps_from_a_mid_step_com_state():
    """Starting part-way along the apex orbit gives the same footsteps, earlier switches."""
    dt = 0.1
    x, xd = np.sinh(W * dt) * 0.2 / W, np.cosh(W * dt) * 0.2
    y, yd = 0.056 * np.cosh(W * dt), 0.056 * W * np.sinh(W * dt)
    actions = jnp.tile(jnp.array([0.3, 0.2, 0.0]), (3, 1))
    ref = plan_steps(NOMINAL, actions, P)
    mid = plan_steps(jnp.array([x, xd, y, yd]), actions, P)
    np.testing.assert_allclose(mid.apex_shift[0], -dt, atol=1e-12)
    np.testing.assert_allclose(mid.footsteps, ref.footsteps, atol=1e-12)
    np.testing.assert_allclose(mid.t_switch, ref.t_switch - dt, atol=1e-12)


def test_reprojection_round_trip_and_frames():
    com = jnp.array([0.02, 0.3, -0.05, 0.1])
    there = steering.reproject_com_state(com, 0.3, 1.0, -0.4, -1.0)
    back = steering.reproject_com_state(there, -0.4, -1.0, 0.3, 1.0)
    np.testing.assert_allclose(back, com, atol=1e-14)
    # Mirroring flips only the lateral components.
    np.testing.assert_allclose(
        steering.reproject_com_state(com, 0.0, 1.0, 0.0, -1.0), com * jnp.array([1, 1, -1, -1])
    )
    v = jnp.array([1.0, 2.0])
    np.testing.assert_allclose(
        steering.world_to_local(steering.local_to_world(v, 0.7, -1.0), 0.7, -1.0), v, atol=1e-14
    )


def test_turn_schedule():
    turns = turn_schedule([(2, 10.0), (1, 0.0), (3, -5.0)])
    np.testing.assert_allclose(np.rad2deg(turns), [10, 10, 0, -5, -5, -5])
    with pytest.raises(ValueError, match="segment 0: num_steps"):
        turn_schedule([(-1, 5.0)])
    with pytest.raises(ValueError, match=r"segment 1: degrees_per_step must be in \(-90, 90\)"):
        turn_schedule([(1, 5.0), (1, 95.0)])


def test_gradient_of_footsteps_wrt_actions():
    actions = jnp.array([[0.3, 0.22, 0.02], [0.28, 0.2, -0.03], [0.31, 0.19, 0.0]])
    turns = jnp.array([0.1, -0.05, 0.0])

    def final_foot(a):
        return plan_steps(NOMINAL, a, P, turns=turns).footsteps[-1]

    check_grads(final_foot, (actions,), order=1, modes=("fwd", "rev"), eps=1e-6)


def test_bad_arguments_raise(lookahead):
    with pytest.raises(ValueError, match="num_steps is required"):
        plan_steps(NOMINAL, lookahead, P)
    with pytest.raises(ValueError, match=r"start must be an apex state \(3,\)"):
        plan_steps(jnp.zeros((2, 3)), jnp.zeros((2, 3)), P)
    with pytest.raises(ValueError, match=r"turns must have shape \(2,\)"):
        plan_steps(NOMINAL, jnp.zeros((2, 3)), P, turns=jnp.zeros(3))
    with pytest.raises(ValueError, match="num_steps=3 but 2 actions"):
        plan_steps(NOMINAL, jnp.zeros((2, 3)), P, num_steps=3)
    with pytest.raises(ValueError, match="samples_per_phase must be >= 2"):
        sample_com_trajectory(plan_steps(NOMINAL, jnp.zeros((1, 3)), P), P, 1)


def test_lookahead_policy_picks_safe_actions_in_the_box(lookahead):
    rng = np.random.default_rng(2)
    for state in rng.uniform([-0.05, 0.1, -0.2], [0.15, 0.4, 0.2], (10, 3)):
        action = np.asarray(lookahead(jnp.asarray(state)))
        assert np.all(action >= np.array(P.action_low) - 1e-12)
        assert np.all(action <= np.array(P.action_high) + 1e-12)
    walk = plan_steps(NOMINAL, lookahead, P, num_steps=50)
    assert bool(jnp.all(walk.alive))


def test_turn_local_frame_is_reprojection_with_same_sign():
    com = jnp.array([0.03, 0.25, -0.06, 0.12])
    for sigma in (1.0, -1.0):
        for turn in (0.33, -0.2):
            want = steering.reproject_com_state(com, 0.5, sigma, 0.5 + turn, sigma)
            got = steering.turn_local_frame(com, sigma, np.cos(turn), np.sin(turn))
            np.testing.assert_allclose(got, want, atol=1e-14)
