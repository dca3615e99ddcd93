"""The Brax environment of the step task and the PPO baseline (CI-sized)."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.wrappers.training import wrap
from cli_helpers import run_cli

from jaxloco.learning import load_planner, steps_survived
from jaxloco.learning.brax_env import BOX_STARTS, StepEnv
from jaxloco.learning.ppo import (
    PPOConfig,
    PPOPlanner,
    init_params,
    save_ppo_checkpoint,
    train_ppo,
)
from jaxloco.learning.starts import StartStates
from jaxloco.planner import PSPParams, plan_step

P = PSPParams()
TINY = PPOConfig(
    num_timesteps=4096,
    num_envs=64,
    batch_size=32,
    num_minibatches=4,
    num_updates_per_batch=1,
    unroll_length=5,
    episode_length=10,
    policy_hidden=(8,),
    value_hidden=(8,),
    num_evals=3,
    basin_states=64,
    basin_steps=5,
)


def test_the_action_cube_maps_onto_the_action_box():
    env = StepEnv(P)
    np.testing.assert_allclose(env.to_action(-jnp.ones(3)), P.action_low, atol=1e-12)
    np.testing.assert_allclose(env.to_action(jnp.ones(3)), P.action_high, atol=1e-12)
    mid = 0.5 * (np.asarray(P.action_low) + np.asarray(P.action_high))
    np.testing.assert_allclose(env.to_action(jnp.zeros(3)), mid, atol=1e-12)
    np.testing.assert_allclose(env.to_action(5 * jnp.ones(3)), P.action_high, atol=1e-12)


def test_reset_draws_from_the_box_and_step_is_the_planner():
    env = StepEnv(P)
    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), 256))
    obs = np.asarray(states.obs)
    assert obs.shape == (256, 3)
    assert np.all(obs >= np.asarray(BOX_STARTS.box_low)) and np.all(obs <= BOX_STARTS.box_high)
    unit = jax.random.uniform(jax.random.key(1), (256, 3), minval=-1.0, maxval=1.0)
    after = jax.vmap(env.step)(states, unit)
    plan = plan_step(states.obs, env.to_action(unit), P)
    np.testing.assert_array_equal(after.reward, plan.reward)
    np.testing.assert_array_equal(after.done, plan.terminal.astype(after.done.dtype))
    term = np.asarray(plan.terminal)
    assert 0 < term.sum() < len(term)  # both kinds of step occur in this draw
    np.testing.assert_array_equal(np.asarray(after.obs)[~term], np.asarray(plan.next_state)[~term])
    np.testing.assert_array_equal(np.asarray(after.obs)[term], obs[term])
    np.testing.assert_array_equal(after.metrics["safe_steps"], 1.0 - np.asarray(after.done))


def test_brax_training_wrappers_end_and_restart_episodes():
    env = wrap(StepEnv(P), episode_length=3)
    # Brax's wrappers take raw uint32 keys (they read the batch shape off the key's shape).
    state = env.reset(jax.random.split(jax.random.PRNGKey(0), 64))
    start = np.asarray(state.obs)
    ended = np.zeros(64, bool)
    for k in range(3):
        unit = jax.random.uniform(jax.random.key(k), (64, 3), minval=-1.0, maxval=1.0)
        state = env.step(state, unit)
        done = np.asarray(state.done) > 0
        # An ended episode starts again from its first state.
        np.testing.assert_array_equal(np.asarray(state.obs)[done], start[done])
        ended |= done
    assert ended.all()  # the third step ends every episode, by a fall or the length
    assert np.any(np.asarray(state.info["truncation"]) > 0)


def test_ppo_config_names_bad_fields():
    with pytest.raises(ValueError, match=r"PPOConfig.num_envs must be a divisor"):
        PPOConfig(num_envs=100, batch_size=32, num_minibatches=4)
    with pytest.raises(ValueError, match=r"PPOConfig.policy_hidden"):
        PPOConfig(policy_hidden=())
    with pytest.raises(ValueError, match=r"PPOConfig.pushed_fraction"):
        PPOConfig(pushed_fraction=1.5)


@pytest.fixture(scope="module")
def tiny_run():
    return train_ppo(TINY, P, StartStates(), progress=False)


def test_ppo_trains_evaluates_and_keeps_the_best(tiny_run):
    rows = tiny_run.history
    assert len(rows) == TINY.num_evals
    assert rows[0]["env_steps"] == 0 and rows[-1]["env_steps"] >= TINY.num_timesteps
    assert all(0.0 <= r["basin"] <= 1.0 for r in rows)
    assert tiny_run.best_basin == max(r["basin"] for r in rows)
    assert all(np.isfinite(r["episode_reward"]) for r in rows)
    assert [r["wall_s"] for r in rows] == sorted(r["wall_s"] for r in rows)


def test_the_ppo_planner_acts_in_the_box_and_reproduces_its_basin(tiny_run):
    planner = tiny_run.planner
    states = jax.random.uniform(
        jax.random.key(TINY.basin_seed),
        (TINY.basin_states, 3),
        minval=jnp.asarray(BOX_STARTS.box_low),
        maxval=jnp.asarray(BOX_STARTS.box_high),
    )
    actions = np.asarray(planner.mean_action(states))
    assert actions.shape == (TINY.basin_states, 3)
    assert np.all(actions >= np.asarray(P.action_low) - 1e-6)
    assert np.all(actions <= np.asarray(P.action_high) + 1e-6)
    assert planner.value(states).shape == (TINY.basin_states,)
    steps = steps_survived(jax.jit(planner.policy), states, P, TINY.basin_steps)
    assert np.mean(np.asarray(steps) == TINY.basin_steps) == pytest.approx(tiny_run.best_basin)


def test_a_ppo_checkpoint_loads_with_load_planner(tiny_run, tmp_path):
    path = save_ppo_checkpoint(tmp_path / "ckpt", tiny_run.planner, {"note": "test"})
    loaded = load_planner(path)
    assert isinstance(loaded, PPOPlanner)
    assert loaded.config == TINY and loaded.psp == P
    states = jnp.asarray([P.nominal_state, (0.0, 0.4, 0.1)])
    np.testing.assert_array_equal(loaded.mean_action(states), tiny_run.planner.mean_action(states))
    np.testing.assert_array_equal(loaded.value(states), tiny_run.planner.value(states))


def test_untrained_params_have_the_trained_structure(tiny_run):
    template = init_params(TINY)
    assert jax.tree.structure(template) == jax.tree.structure(tiny_run.planner.params)
    other = dataclasses.replace(TINY, policy_hidden=(4,))
    assert jax.tree.map(jnp.shape, init_params(other)) != jax.tree.map(
        jnp.shape, tiny_run.planner.params
    )


def test_train_planner_cli_with_ppo(tmp_path):
    overrides = [
        f"ppo.{k}={list(v) if isinstance(v, tuple) else v}"
        for k, v in dataclasses.asdict(TINY).items()
    ]
    proc = run_cli(
        ["train-planner", "method=ppo", "progress=false", "dpi=50", *overrides], tmp_path
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "run"
    assert (run / "learning_curve.png").stat().st_size > 0
    history = json.loads((run / "history.json").read_text())
    assert history["info"]["method"] == "ppo"
    assert len(history["history"]) == TINY.num_evals
    planner = load_planner(run / "checkpoint")
    assert isinstance(planner, PPOPlanner) and planner.config == TINY
    (tmp_path / "bad").mkdir()
    bad = run_cli(["train-planner", "method=dqn"], tmp_path / "bad")
    assert bad.returncode != 0 and "method must be one of ['rl_psp', 'ppo']" in bad.stderr
