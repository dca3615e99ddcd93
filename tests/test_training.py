"""Training loop, checkpoints, the shipped planner, and the learning experiments (CI-sized)."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from cli_helpers import run_cli

from jaxloco.learning import (
    FAST,
    STEERING,
    EpisodeTurns,
    EvalConfig,
    LearnedPlanner,
    RBFGrid,
    RefineConfig,
    TrainConfig,
    init_train_state,
    load_checkpoint_config,
    load_planner,
    mean_policy,
    save_checkpoint,
    steps_survived,
    survival_basin,
    train,
)
from jaxloco.learning.checkpoint import SHIPPED_POLICIES, assets_dir, load_train_state
from jaxloco.learning.fallback import FallbackPlanner
from jaxloco.learning.starts import StartStates, uniform_states
from jaxloco.learning.training import params_fingerprint
from jaxloco.planner import PSPParams
from jaxloco.runtime import cpu_compiler_options

P = PSPParams()
SMALL = TrainConfig(
    actor_critic=dataclasses.replace(
        FAST, episodes_per_iteration=64, max_episode_steps=4, max_iterations=5
    ),
    evaluation=EvalConfig(every=2, num_states=128, num_steps=10),
    refine=RefineConfig(iterations=0),  # Algorithm 1 alone (refinement: test_refine.py)
)


@pytest.fixture(scope="module")
def small_run():
    return train(SMALL, progress=False)


def test_train_runs_evaluates_and_keeps_the_best(small_run):
    assert small_run.stop_reason == "iteration budget"
    assert [h["iteration"] for h in small_run.history] == [1, 2, 3, 4, 5]
    evaluated = [h for h in small_run.history if "basin" in h]
    assert [h["iteration"] for h in evaluated] == [2, 4, 5]
    assert not any("steering_basin" in h for h in evaluated)  # straight, as the paper
    assert small_run.best_basin == max(h["basin"] for h in evaluated)
    assert small_run.best_steering_basin is None
    assert all(np.isfinite(h["mean_return"]) for h in small_run.history)
    assert small_run.compile_seconds > 0 and small_run.train_seconds > 0


def test_steering_training_keeps_the_best_mean_of_both_basins():
    result = train(dataclasses.replace(SMALL, turns=STEERING), progress=False)
    evaluated = [h for h in result.history if "basin" in h]
    assert evaluated and all(0.0 <= h["steering_basin"] <= 1.0 for h in evaluated)
    best = max(evaluated, key=lambda h: h["basin"] + h["steering_basin"])
    assert result.best_basin == best["basin"]
    assert result.best_steering_basin == best["steering_basin"]


def test_checkpoints_keep_the_training_turns_and_old_ones_load_as_straight(tmp_path):
    config = dataclasses.replace(
        SMALL,
        turns=EpisodeTurns(max_deg=12.5, fraction=0.3),
        evaluation=dataclasses.replace(SMALL.evaluation, steering_segments=((3, 10.0),)),
    )
    params = init_train_state(config.actor_critic, config.grid).params
    path = save_checkpoint(tmp_path / "ck", params, config)
    loaded, _ = load_checkpoint_config(path)
    assert loaded == config and hash(loaded.evaluation) == hash(config.evaluation)
    # A checkpoint written before steering training existed has no "turns": it walked straight.
    meta = json.loads((path / "config.json").read_text())
    del meta["config"]["turns"]
    (path / "config.json").write_text(json.dumps(meta))
    assert load_checkpoint_config(path)[0].turns == EpisodeTurns()
    with pytest.raises(ValueError, match="turn_schedule segment 0"):
        EvalConfig(steering_segments=((3, 95.0),))


def test_spread_target_stops_training():
    cfg = dataclasses.replace(
        SMALL, actor_critic=dataclasses.replace(SMALL.actor_critic, spread_target=0.2)
    )
    result = train(cfg, progress=False)  # initial spreads are 0.1 < 0.2
    assert result.stop_reason == "every mean spread < 0.2"
    assert len(result.history) == 1


def test_resume_reproduces_an_uninterrupted_run(small_run, tmp_path):
    three = dataclasses.replace(
        SMALL, actor_critic=dataclasses.replace(SMALL.actor_critic, max_iterations=3)
    )
    first = train(three, progress=False)
    save_checkpoint(tmp_path / "ck", first.state.params, SMALL, {}, first.state)
    config, _ = load_checkpoint_config(tmp_path / "ck")
    assert config == SMALL
    resumed = train(config, progress=False, state=load_train_state(tmp_path / "ck", config))
    assert int(resumed.state.iteration) == 5
    assert params_fingerprint(resumed.state.params) == params_fingerprint(small_run.state.params)


def test_checkpoint_round_trip_and_planner_api(small_run, tmp_path):
    path = save_checkpoint(tmp_path / "ck", small_run.best_params, SMALL, {"note": 1})
    planner = load_planner(path)
    states = jnp.asarray(
        np.random.default_rng(0).uniform([-0.1, 0.1, -0.3], [0.15, 0.5, 0.3], (2, 5, 3))
    )
    want = jax.vmap(mean_policy(small_run.best_params, SMALL.grid, P))(states.reshape(-1, 3))
    got = planner.mean_action(states)
    assert got.shape == (2, 5, 3)
    np.testing.assert_allclose(got.reshape(-1, 3), want, rtol=1e-6, atol=1e-7)
    assert planner.value(states).shape == (2, 5)
    assert planner.spread(states[0, 0]).shape == (3,)
    # The planner is a pytree: it can be an argument of a jitted function.
    jitted = jax.jit(lambda pl, s: pl.mean_action(s))(planner, states)
    np.testing.assert_allclose(jitted, got, atol=1e-7)


def test_shipped_refined_and_default_planners_have_the_larger_survival_basin():
    # policy-eval's independent draw. Measured here (float64 states): 0.375 for the
    # Algorithm 1 policy and 0.498 for the refined one (0.389 and 0.503 in float32).
    states = uniform_states(jax.random.key(2024), 4096, StartStates())
    basins = {}
    for name in ("algorithm1", "refined", "default"):
        planner = load_planner(shipped=name)
        # Compiled as the learning programs compile (runtime.cpu_compiler_options): the
        # suite's level 0 (tests/conftest.py) would run these 4096 walks 3x slower.
        walks = jax.jit(
            lambda s, policy=planner.policy: steps_survived(policy, s, P, 50),
            compiler_options=cpu_compiler_options(),
        )
        basins[name] = float(jnp.mean(walks(states) == 50))
    assert basins["refined"] > 0.48 and basins["refined"] > basins["algorithm1"] + 0.08, basins
    # The default: Algorithm 1's policy with the refined one as fallback.
    assert isinstance(load_planner(), FallbackPlanner)
    assert basins["default"] >= basins["refined"] - 0.005, basins
    config, info = load_checkpoint_config(assets_dir() / SHIPPED_POLICIES["refined"])
    assert config.refine.iterations == 300 and info["actor_critic_basin"] < info["best_basin"]


def test_loading_errors_are_clear(tmp_path):
    with pytest.raises(FileNotFoundError, match="no planner checkpoint"):
        load_planner(tmp_path / "nothing")
    with pytest.raises(
        ValueError,
        match=r"shipped must be one of \['algorithm1', 'apollo', 'default', 'g1', 'refined'\]",
    ):
        load_planner(shipped="best")
    with pytest.raises(ValueError, match=r"apex states must have shape \(\.\.\., 3\)"):
        load_planner().mean_action(jnp.zeros(4))


def test_shipped_algorithm1_planner_beats_the_fixed_action():
    planner = load_planner(shipped="algorithm1")
    assert isinstance(planner, LearnedPlanner)
    assert planner.grid == RBFGrid()
    action = planner.mean_action(jnp.asarray(P.nominal_state))
    assert np.all(np.asarray(action) >= np.array(P.action_low) - 1e-7)
    assert np.all(np.asarray(action) <= np.array(P.action_high) + 1e-7)
    trained, _, _ = survival_basin(planner.policy, P, jax.random.key(5), 1024)
    fixed = lambda s: jnp.asarray([0.25, 0.2, 0.0], s.dtype)  # noqa: E731
    baseline, _, _ = survival_basin(fixed, P, jax.random.key(5), 1024)
    assert float(trained) > float(baseline) + 0.05


def test_train_planner_cli_ci_sized(tmp_path):
    proc = run_cli(
        [
            "train-planner",
            "actor_critic.max_iterations=3",
            "actor_critic.episodes_per_iteration=32",
            "actor_critic.max_episode_steps=3",
            "evaluation.every=2",
            "evaluation.num_states=64",
            "evaluation.num_steps=5",
            "refine.iterations=2",
            "refine.batch=8",
            "refine.horizon=2",
            "progress=false",
            "dpi=50",
        ],
        tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "run"
    assert (run / "learning_curve.png").stat().st_size > 0
    history = json.loads((run / "history.json").read_text())
    assert len(history["history"]) == 5 and history["info"]["iteration"] == 3
    assert history["info"]["refine"]["iterations"] == 2
    assert history["history"][-1]["stage"] == "refine"
    planner = load_planner(run / "checkpoint")
    assert planner.mean_action(jnp.asarray(P.nominal_state)).shape == (3,)


def test_policy_eval_cli_ci_sized(tmp_path):
    proc = run_cli(
        [
            "policy-eval",
            "num_states=128",
            "num_steps=10",
            "gradient_planner_horizons=[1]",
            "gradient_planner_iterations=5",
            "timing_repeats=3",
            "fig6_steps=3",
            "value_map_resolution=8",
            "dpi=50",
        ],
        tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "run"
    summary = json.loads((run / "basins.json").read_text())
    basins = summary["survival_basin"]
    assert len(basins) == 5 and all(0.0 <= v <= 1.0 for v in basins.values())
    assert any(k.startswith("gradient planner (1-step") for k in basins)
    assert all(v > 0 for v in summary["decision_time_us"].values())
    for name in ("fig6_pushed_steps.png", "value_map.png", "basins.md"):
        assert (run / name).stat().st_size > 0


def test_train_planner_cli_defaults_are_the_library_defaults():
    """``jaxloco train-planner`` with no overrides trains ``TrainConfig()``, the
    configuration ``bench_learning.py`` times against the 10 s target."""
    import importlib.util

    from omegaconf import OmegaConf

    from jaxloco.cli import experiments_dir

    spec = importlib.util.spec_from_file_location(
        "train_planner_app", experiments_dir() / "train_planner.py"
    )
    app = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(app)
    cfg = OmegaConf.structured(app.TrainPlannerConfig)
    assert app.build_config(cfg) == TrainConfig()
    assert cfg.method == "rl_psp"
    cfg.refine.iterations = 7
    assert app.build_config(cfg).refine.iterations == 7  # overrides reach the config
