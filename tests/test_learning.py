"""The RL-PSP learning core: features, policy, batched Algorithm 1, start states, basin."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.stats import truncnorm

from jaxloco.learning import policy as pol
from jaxloco.learning import rbf
from jaxloco.learning.actor_critic import (
    ActorCriticConfig,
    Rollout,
    init_train_state,
    make_train_iteration,
    rollout,
    step_sizes,
    td_errors,
    update_direction,
)
from jaxloco.learning.evaluation import mean_policy, survival_basin, value_function
from jaxloco.learning.starts import (
    EpisodeTurns,
    StartStates,
    episode_turns,
    push_apex_state,
    pushed_states,
    training_starts,
)
from jaxloco.planner import PSPParams, plan_steps

P = PSPParams()
LOW, HIGH = jnp.asarray(P.action_low), jnp.asarray(P.action_high)
RNG = np.random.default_rng(0)


def dense_from_local(grid, feats):
    """The window's features placed in a dense (num_centres,) vector (no truncation change)."""
    table = jnp.zeros((*grid.table_shape, 1))
    table = rbf.scatter_add(table, jax.tree.map(lambda x: x[None], feats), jnp.ones((1, 1)))
    return rbf.unpad(grid, table).reshape(-1)


# --- features ------------------------------------------------------------------------


def test_grid_matches_the_paper():
    grid = rbf.RBFGrid()
    assert grid.counts == (18, 30, 56) and grid.num_centres == 30240
    np.testing.assert_allclose(grid.high, (0.20, 0.61, 0.55), atol=1e-12)


@pytest.mark.parametrize("radius,tolerance", [(2, 0.5), (3, 0.03), (4, 5e-4)])
def test_local_evaluation_matches_dense_within_truncation(radius, tolerance):
    grid = rbf.RBFGrid(radius=radius)
    table = jnp.asarray(RNG.normal(size=(*grid.table_shape, 2)))
    worst, worst_single = 0.0, 0.0
    for s in RNG.uniform([-0.2, 0.0, -0.6], [0.26, 0.65, 0.6], (100, 3)):
        s = jnp.asarray(s)
        feats = rbf.local_features(grid, s)
        local = rbf.evaluate(table, jnp.zeros(2), feats)
        dense_phi = rbf.dense_features(grid, s)
        dense = dense_phi @ rbf.unpad(grid, table).reshape(-1, 2)
        worst = max(worst, float(jnp.max(jnp.abs(local - dense))))
        dropped = dense_phi - dense_from_local(grid, feats)
        assert float(jnp.min(dropped)) > -1e-12  # the window holds exact features
        worst_single = max(worst_single, float(jnp.max(dropped)))
    assert worst < tolerance
    assert worst_single <= grid.truncation_bound() * (1 + 1e-9)


def test_features_never_touch_padding_and_scatter_matches_outer_products():
    grid = rbf.RBFGrid(radius=3)
    states = jnp.asarray(RNG.uniform([-0.3, -0.1, -0.8], [0.4, 0.8, 0.8], (40, 3)))
    feats = jax.vmap(lambda s: rbf.local_features(grid, s))(states)
    coef = jnp.asarray(RNG.normal(size=(40, 3)))
    table = rbf.scatter_add(jnp.zeros((*grid.table_shape, 3)), feats, coef)
    # Nothing lands in the padding.
    total = float(jnp.sum(jnp.abs(table)))
    assert float(jnp.sum(jnp.abs(rbf.unpad(grid, table)))) == pytest.approx(total)
    # Equal to the sum of outer products of dense (window) features and coefficients.
    dense = jnp.stack(
        [dense_from_local(grid, jax.tree.map(lambda x, i=i: x[i], feats)) for i in range(40)]
    )
    want = jnp.einsum("bc,bo->co", dense, coef)
    np.testing.assert_allclose(rbf.unpad(grid, table).reshape(-1, 3), want, atol=1e-12)


def test_invalid_grid_raises():
    with pytest.raises(ValueError, match=r"RBFGrid\.sigma must be > 0"):
        rbf.RBFGrid(sigma=0.0)
    with pytest.raises(ValueError, match=r"RBFGrid\.radius must be an int >= 0"):
        rbf.RBFGrid(radius=-1)


# --- policy --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "mean,log_spread",
    [
        ([0.3, 0.2, 0.0], [0.0, 0.0, 0.0]),
        ([0.3, 0.2, 0.0], [-3.0, -3.0, -3.0]),
        ([5.0, -3.0, 0.1], [-3.0, -2.0, -4.0]),  # far in the tails
        ([0.45, 0.05, 0.24], [-1.0, -2.5, -1.5]),
    ],
)
def test_log_prob_matches_scipy_truncnorm(mean, log_spread):
    mean, log_spread = jnp.asarray(mean), jnp.asarray(log_spread)
    spread = jnp.exp(log_spread)
    for a in RNG.uniform(P.action_low, P.action_high, (5, 3)):
        a = jnp.asarray(a)
        ref = jnp.sum(
            truncnorm.logpdf(a, (LOW - mean) / spread, (HIGH - mean) / spread, mean, spread)
        )
        assert float(pol.log_prob(a, mean, log_spread, LOW, HIGH)) == pytest.approx(
            float(ref), rel=1e-10, abs=1e-9
        )
        d_mean, d_log_spread = pol.score(a, mean, log_spread, LOW, HIGH)
        assert bool(jnp.all(jnp.isfinite(d_mean)) & jnp.all(jnp.isfinite(d_log_spread)))


def test_sparse_score_matches_grad_of_a_dense_reference_network():
    """grad_theta log pi from (score x local features) equals jax.grad of a reference policy
    written densely over all centres with jax.scipy's truncnorm."""
    grid = rbf.RBFGrid(low=(-0.06, 0.1, -0.1), counts=(5, 6, 7), radius=2)
    state = jnp.asarray([0.0, 0.16, 0.02])
    action = jnp.asarray([0.28, 0.21, 0.05])
    feats = rbf.local_features(grid, state)
    phi = dense_from_local(grid, feats)  # the same features, in dense form
    theta = jnp.asarray(RNG.normal(scale=0.1, size=(phi.shape[0], 6)))
    bias = jnp.asarray([0.3, 0.2, 0.0, -2.0, -2.0, -2.0])

    def reference_log_pi(theta):
        out = phi @ theta + bias
        mean, spread = out[:3], jnp.exp(out[3:])
        lo, hi = (LOW - mean) / spread, (HIGH - mean) / spread
        return jnp.sum(truncnorm.logpdf(action, lo, hi, mean, spread))

    want = jax.grad(reference_log_pi)(theta)
    out = phi @ theta + bias
    d_mean, d_log_spread = pol.score(action, out[:3], out[3:], LOW, HIGH)
    got = jnp.outer(phi, jnp.concatenate([d_mean, d_log_spread]))
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


def test_samples_lie_in_the_box_and_follow_the_truncated_normal():
    mean, log_spread = jnp.asarray([0.45, 0.1, 0.0]), jnp.log(jnp.asarray([0.1, 0.2, 0.05]))
    keys = jax.random.split(jax.random.key(0), 20000)
    samples = jax.vmap(lambda k: pol.sample(k, mean, log_spread, LOW, HIGH))(keys)
    assert bool(jnp.all((samples >= LOW) & (samples <= HIGH)))
    spread = jnp.exp(log_spread)
    lo, hi = (LOW - mean) / spread, (HIGH - mean) / spread
    from scipy.stats import truncnorm as sp_truncnorm

    want = sp_truncnorm.mean(np.asarray(lo), np.asarray(hi), np.asarray(mean), np.asarray(spread))
    np.testing.assert_allclose(jnp.mean(samples, axis=0), want, atol=3e-3)
    # Far in a tail the sample is the nearest bound, not NaN.
    far = pol.sample(jax.random.key(1), jnp.asarray([9.0, -9.0, 0.0]), log_spread, LOW, HIGH)
    assert bool(jnp.all(jnp.isfinite(far)))


# --- batched Algorithm 1 -------------------------------------------------------------

SMALL_GRID = rbf.RBFGrid(low=(-0.04, 0.12, -0.12), counts=(6, 8, 9), radius=2)


def small_rollout(cfg, num_episodes=12, num_steps=4, seed=0, noise=0.03):
    state = init_train_state(cfg, SMALL_GRID, jax.random.key(seed))
    key_s, key_r = jax.random.split(jax.random.key(seed + 1))
    starts = pushed_states(key_s, num_episodes, P, StartStates(noise=noise, impulses=(5.0,)))
    ro = rollout(state.params, key_r, starts, SMALL_GRID, P, num_steps)
    return state.params, ro


def sequential_algorithm1(params, ro: Rollout, cfg, online: bool):
    """Algorithm 1 as printed, one episode after another, dense traces over all centres.

    ``online=False`` applies each episode's accumulated update at its end with the weights
    fixed during the episode (what the batched form computes, summed over episodes).
    """
    num_steps, num_episodes = ro.reward.shape
    feats_dense = np.zeros((num_steps, num_episodes, SMALL_GRID.num_centres + 1))
    for t in range(num_steps):
        for b in range(num_episodes):
            f = jax.tree.map(lambda x, t=t, b=b: x[t, b], ro.features)
            feats_dense[t, b, :-1] = dense_from_local(SMALL_GRID, f)
            feats_dense[t, b, -1] = 1.0  # bias
    last = jax.vmap(lambda s: rbf.local_features(SMALL_GRID, s))(ro.final_state)
    weights = np.concatenate(
        [
            np.asarray(rbf.unpad(SMALL_GRID, params.table)).reshape(-1, 7),
            np.asarray(params.bias)[None],
        ]
    )
    total = np.zeros_like(weights)
    lr = np.asarray(step_sizes(cfg))
    for b in range(num_episodes):
        w = weights.copy()
        e = np.zeros_like(weights)  # traces: column 0 value, columns 1-6 policy
        episode_update = np.zeros_like(weights)
        discount = 1.0
        for t in range(num_steps):
            if not bool(ro.active[t, b]):
                break
            phi = feats_dense[t, b]
            value = phi @ w[:, 0]
            if bool(ro.terminal[t, b]):
                next_value = 0.0
            elif t + 1 < num_steps:
                next_value = feats_dense[t + 1, b] @ w[:, 0]
            else:
                f_last = jax.tree.map(lambda x, b=b: x[b], last)
                phi_last = np.append(np.asarray(dense_from_local(SMALL_GRID, f_last)), 1.0)
                next_value = phi_last @ w[:, 0]
            delta = float(ro.reward[t, b]) + cfg.gamma * next_value - value
            grad = np.zeros_like(weights)
            grad[:, 0] = phi
            score = np.concatenate([np.asarray(ro.d_mean[t, b]), np.asarray(ro.d_log_spread[t, b])])
            grad[:, 1:] = np.outer(phi, score)
            e[:, :1] = cfg.lambda_w * e[:, :1] + discount * grad[:, :1]
            e[:, 1:] = cfg.lambda_theta * e[:, 1:] + discount * grad[:, 1:]
            step = lr * delta * e
            if online:
                w += step
            else:
                episode_update += step
            discount *= cfg.gamma
        total += (w - weights) if online else episode_update
    return total


def batched_update(params, ro, cfg):
    direction, _ = update_direction(params, ro, cfg)
    lr = step_sizes(cfg)
    table = np.asarray(rbf.unpad(SMALL_GRID, direction.table)).reshape(-1, 7)
    return np.concatenate([table, np.asarray(direction.bias)[None]]) * np.asarray(lr)


def test_batched_update_equals_sequential_algorithm1_with_episode_updates():
    cfg = ActorCriticConfig(alpha=3e-5, beta=3e-5, initial_spread=0.02)
    params, ro = small_rollout(cfg)
    # The case must exercise terminations and bootstrapping at the step cap.
    assert bool(jnp.any(ro.terminal & ro.active))
    assert bool(jnp.any(ro.active[-1] & ~ro.terminal[-1]))
    want = sequential_algorithm1(params, ro, cfg, online=False)
    assert np.max(np.abs(want)) > 1e-8
    got = batched_update(params, ro, cfg)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-15)


def test_online_algorithm1_differs_by_order_alpha_squared():
    diffs = []
    for lr in (1e-3, 1e-4):
        cfg = ActorCriticConfig(alpha=lr, beta=lr, initial_spread=0.02)
        params, ro = small_rollout(cfg)
        online = sequential_algorithm1(params, ro, cfg, online=True)
        offline = batched_update(params, ro, cfg)
        diffs.append(np.max(np.abs(online - offline)) / np.max(np.abs(offline)))
    # Relative difference ~ alpha: 10x smaller steps, ~10x closer (O(alpha^2) absolute).
    assert diffs[1] < diffs[0] / 5


def test_td_errors_stop_at_termination_and_bootstrap_at_the_cap():
    cfg = ActorCriticConfig(initial_spread=0.08)
    _, ro = small_rollout(cfg, num_steps=4)
    delta = np.asarray(td_errors(ro, cfg.gamma))
    assert np.all(delta[~np.asarray(ro.active)] == 0.0)


def test_turning_rollout_follows_plan_steps_and_zero_turns_change_nothing():
    """The batched episodes with heading changes walk exactly what plan_steps plans for the
    same actions and turn schedule (re-projection, apex shift, SWITCH_IN_PAST, NO_APEX)."""
    cfg = ActorCriticConfig(initial_spread=0.15)
    # float64: the suite's default (conftest)
    state = init_train_state(cfg, SMALL_GRID, jax.random.key(0), dtype=jnp.float64)
    n, steps = 48, 6
    starts = pushed_states(jax.random.key(1), n, P, StartStates(noise=0.03, impulses=(5.0,)))
    turns = jnp.linspace(-0.45, 0.45, n)  # up to 26 deg a step, both ways
    key = jax.random.key(2)
    ro = rollout(state.params, key, starts, SMALL_GRID, P, steps, turns)
    plans = jax.jit(jax.vmap(lambda s, a, t: plan_steps(s, a, P, turns=jnp.full((steps,), t))))(
        starts, jnp.swapaxes(ro.action, 0, 1), turns
    )
    for b in range(n):
        active = np.asarray(ro.active[:, b])
        np.testing.assert_allclose(ro.state[active, b], plans.apex_states[b, active], atol=1e-9)
        # A step ends the episode exactly where plan_steps marks it (or the next step
        # has no apex, which plan_steps flags on that next step).
        alive = np.asarray(plans.alive[b])
        ended = np.asarray(ro.terminal[:, b] & ro.active[:, b])
        if ended.any():
            k = int(np.argmax(ended))
            assert alive[:k].all() and not alive[min(k + 1, steps - 1)]
        else:
            assert alive.all()
    assert bool(jnp.any(ro.terminal & ro.active))  # the sharp turns do end some episodes
    straight = rollout(state.params, key, starts, SMALL_GRID, P, steps)
    zero = rollout(state.params, key, starts, SMALL_GRID, P, steps, jnp.zeros(n))
    np.testing.assert_allclose(zero.state, straight.state, atol=1e-12)
    np.testing.assert_array_equal(zero.terminal, straight.terminal)
    with pytest.raises(ValueError, match=r"turns must have shape \(48,\)"):
        rollout(state.params, key, starts, SMALL_GRID, P, steps, jnp.zeros(3))


def test_episode_turns_draws_and_validation():
    spec = EpisodeTurns(max_deg=20.0, fraction=0.25)
    t = np.asarray(episode_turns(jax.random.key(0), 4000, spec))
    assert np.all(np.abs(t) <= np.deg2rad(20.0))
    assert 0.2 < np.mean(t != 0.0) < 0.3 and t.min() < -0.3 and t.max() > 0.3
    assert not EpisodeTurns().enabled and spec.enabled
    with pytest.raises(ValueError, match=r"EpisodeTurns\.max_deg must be in \[0, 90\)"):
        EpisodeTurns(max_deg=95.0)
    with pytest.raises(ValueError, match=r"EpisodeTurns\.fraction must be in \[0, 1\]"):
        EpisodeTurns(fraction=-0.1)


def test_training_iteration_is_reproducible_and_finite():
    cfg = ActorCriticConfig(
        episodes_per_iteration=64,
        max_episode_steps=4,
        optimizer="adam",
        alpha=1e-3,
        beta=1e-2,
        initial_spread=0.1,
    )
    it = make_train_iteration(cfg, SMALL_GRID, P)
    runs = []
    for _ in range(2):
        state = init_train_state(cfg, SMALL_GRID)
        for i in range(3):
            state, stats = it(state, jax.random.key(i))
        runs.append(state)
    for a, b in zip(jax.tree.leaves(runs[0].params), jax.tree.leaves(runs[1].params), strict=True):
        np.testing.assert_array_equal(a, b)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(runs[0].params))
    assert int(runs[0].iteration) == 3


def test_config_validation():
    with pytest.raises(ValueError, match=r"ActorCriticConfig\.gamma must be in \[0, 1\]"):
        ActorCriticConfig(gamma=1.5)
    with pytest.raises(ValueError, match=r"ActorCriticConfig\.optimizer must be one of"):
        ActorCriticConfig(optimizer="rmsprop")
    with pytest.raises(ValueError, match=r"episodes_per_iteration must be an int >= 1"):
        ActorCriticConfig(episodes_per_iteration=0)


# --- start states and evaluation -----------------------------------------------------


def test_push_of_zero_impulse_is_the_nominal_state_and_pushes_act_as_expected():
    spec = StartStates()
    state, ok = push_apex_state(0.0, 0.0, P, spec)
    assert bool(ok)
    np.testing.assert_allclose(state, P.nominal_state, atol=1e-12)
    forward, _ = push_apex_state(30.0, 0.0, P, spec)
    side, _ = push_apex_state(30.0, np.pi / 2, P, spec)
    assert float(forward[1]) > P.xd_apex_nominal + 0.1  # faster forward
    assert float(side[2]) > 0.15 and float(side[1]) == pytest.approx(P.xd_apex_nominal)
    starts = training_starts(jax.random.key(0), 512, P, spec)
    assert starts.shape == (512, 3) and bool(jnp.all(jnp.isfinite(starts)))
    with pytest.raises(ValueError, match=r"StartStates\.pushed_fraction must be in \[0, 1\]"):
        dataclasses.replace(spec, pushed_fraction=2.0)


def test_survival_basin_of_the_fixed_nominal_action():
    """A reference figure: a fixed action (0.25, 0.2, 0) survives ~21% of the box."""
    fixed = lambda s: jnp.asarray([0.25, 0.2, 0.0], s.dtype)  # noqa: E731
    fraction, states, steps = jax.jit(lambda k: survival_basin(fixed, P, k, 4096))(
        jax.random.key(0)
    )
    assert 0.18 < float(fraction) < 0.25
    assert states.shape == (4096, 3) and int(jnp.max(steps)) == 50


def test_mean_policy_and_value_are_jittable_and_batched():
    cfg = ActorCriticConfig(initial_spread=0.1)
    grid = rbf.RBFGrid()
    state = init_train_state(cfg, grid)
    policy = jax.jit(jax.vmap(mean_policy(state.params, grid, P)))
    value = jax.jit(jax.vmap(value_function(state.params, grid)))
    states = jnp.asarray(RNG.uniform([-0.14, 0.03, -0.55], [0.2, 0.61, 0.55], (8, 3)))
    actions = policy(states)
    np.testing.assert_allclose(actions, jnp.tile(jnp.asarray(cfg.mean_bias), (8, 1)), atol=1e-12)
    assert value(states).shape == (8,)
