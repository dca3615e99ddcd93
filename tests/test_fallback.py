"""A step policy with a fallback (jaxloco.learning.fallback)."""

import dataclasses
import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxloco.learning import load_planner, steps_survived
from jaxloco.learning.checkpoint import SHIPPED_POLICIES, assets_dir
from jaxloco.learning.fallback import FallbackPlanner, make_fallback_planner
from jaxloco.learning.loading import checkpoint_digest, save_fallback_checkpoint
from jaxloco.learning.starts import StartStates, uniform_states
from jaxloco.planner import Planner


@pytest.fixture(scope="module")
def policies():
    return load_planner(shipped="algorithm1"), load_planner(shipped="refined")


def test_the_fallback_acts_where_the_primarys_look_ahead_fails(policies):
    primary, fallback = policies
    states = uniform_states(jax.random.key(3), 256, StartStates())
    # The look-aheads, computed independently: each policy's own walk of 3 steps.
    primary_holds = np.asarray(steps_survived(primary.policy, states, primary.psp, 3) == 3)
    fallback_holds = np.asarray(steps_survived(fallback.policy, states, primary.psp, 3) == 3)
    assert 0.1 < primary_holds.mean() < 0.9  # both kinds of state are in the draw
    both_fail = ~primary_holds & ~fallback_holds
    assert both_fail.any()
    for strict, switch in ((False, ~primary_holds), (True, ~primary_holds & fallback_holds)):
        planner = make_fallback_planner(primary, fallback, steps=3, strict=strict)
        np.testing.assert_array_equal(np.asarray(planner.uses_fallback(states)), switch)
        # Jitted against eager: equal up to float32 round-off.
        actions = np.asarray(jax.jit(planner.mean_action)(states))
        mine = np.asarray(primary.mean_action(states))
        np.testing.assert_allclose(actions[~switch], mine[~switch], rtol=0, atol=1e-6)
        theirs = np.asarray(fallback.mean_action(states))
        np.testing.assert_allclose(actions[switch], theirs[switch], rtol=0, atol=1e-6)
        assert np.abs(mine - theirs)[switch].max() > 1e-2  # the two policies differ there
        values = np.asarray(planner.value(states))
        np.testing.assert_array_equal(values[switch], np.asarray(fallback.value(states))[switch])
    # The look-ahead runs in the planner's own parameters (the walking height on the robot).
    lower = planner.replace(psp=dataclasses.replace(planner.psp, h=0.9))
    expected = np.asarray(steps_survived(primary.policy, states, lower.psp, 3) != 3)
    expected = expected & np.asarray(steps_survived(fallback.policy, states, lower.psp, 3) == 3)
    np.testing.assert_array_equal(np.asarray(lower.uses_fallback(states)), expected)
    assert not np.array_equal(expected, switch)


def test_fallback_checkpoints_round_trip_and_refuse_bad_input(tmp_path, policies):
    shipped = assets_dir()
    primary_dir = shutil.copytree(shipped / SHIPPED_POLICIES["algorithm1"], tmp_path / "a1")
    fallback_dir = shutil.copytree(shipped / SHIPPED_POLICIES["refined"], tmp_path / "ref")
    path = save_fallback_checkpoint(tmp_path / "both", primary_dir, fallback_dir, steps=5)
    meta = json.loads((path / "fallback.json").read_text())
    assert meta["primary"] == "../a1" and meta["steps"] == 5  # moves with its neighbours
    planner = load_planner(path)
    assert isinstance(planner, FallbackPlanner) and (planner.steps, planner.strict) == (5, True)
    states = uniform_states(jax.random.key(4), 64, StartStates())
    direct = make_fallback_planner(*policies, steps=5)
    np.testing.assert_array_equal(planner.mean_action(states), direct.mean_action(states))
    digest = checkpoint_digest(path)
    assert checkpoint_digest(save_fallback_checkpoint(tmp_path / "b", primary_dir,
                                                      fallback_dir, steps=5)) == digest  # fmt: skip
    assert checkpoint_digest(save_fallback_checkpoint(tmp_path / "c", primary_dir,
                                                      fallback_dir, steps=6)) != digest  # fmt: skip
    lenient = save_fallback_checkpoint(tmp_path / "d", primary_dir, fallback_dir, 5, strict=False)
    assert checkpoint_digest(lenient) != digest and not load_planner(lenient).strict

    with pytest.raises(ValueError, match=r"FallbackPlanner.steps must be an int >= 1"):
        make_fallback_planner(*policies, steps=0)
    other = policies[1].replace(psp=dataclasses.replace(policies[1].psp, h=0.9))
    with pytest.raises(ValueError, match="different planner parameters"):
        make_fallback_planner(policies[0], other)
    shutil.rmtree(fallback_dir)
    with pytest.raises(FileNotFoundError, match="its fallback .* is missing"):
        load_planner(path)


def test_a_fallback_planner_serves_plan_steps_under_jit(policies):
    planner = make_fallback_planner(*policies)
    from jaxloco.planner import plan_steps

    walk = jax.jit(lambda s: plan_steps(s, planner.policy, planner.psp, num_steps=12))(
        jnp.asarray(planner.psp.nominal_state)
    )
    assert int(walk.num_safe_steps) == 12


def test_every_shipped_policy_is_a_planner():
    """Every kind a checkpoint loads as (learned, fallback, scaled) states the
    :class:`Planner` protocol the walking controller relies on, and acts through it."""
    state = jnp.asarray([0.05, 0.3, 0.0])
    for name in SHIPPED_POLICIES:
        planner = load_planner(shipped=name)
        assert isinstance(planner, Planner), name
        action = planner.policy(state)
        assert action.shape == (3,) and np.all(np.isfinite(action)), name
        np.testing.assert_allclose(planner.mean_action(state[None])[0], action, rtol=1e-5)
    assert not isinstance(object(), Planner)
