"""Gain tuning: the parameterisation, gains files, the optax loop, the gradient step planner,
and gradients through the MJX closed loop against finite differences."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxloco.control.gains import (
    apply_gains_file,
    apply_gait_file,
    load_gains,
    load_gait,
    save_gains,
    with_gains,
)
from jaxloco.control.presets import body_shaking_config
from jaxloco.control.tasks import default_gains
from jaxloco.sim.push import PushArrays
from jaxloco.tuning.gains import GainSpace, tuned_values
from jaxloco.tuning.optimize import TuneConfig, TuningDiverged, tune


def test_gain_space_is_the_hand_set_gains_at_zero_and_positive_everywhere():
    base = default_gains(body_shaking_config("H2").tasks)
    space = GainSpace(("com.kp", "body_ori.kd"), per_row=True)
    p = space.init(base, jnp.float64)
    assert p["com.kp"].shape == (3,) and p["body_ori.kd"].shape == (3,)
    g = space.gains(p, base)
    for task in base:
        for kind in ("kp", "kd"):
            np.testing.assert_allclose(getattr(g[task], kind), getattr(base[task], kind))
    g = space.gains({"com.kp": jnp.array([-50.0, 0.0, 1.0]), "body_ori.kd": p["body_ori.kd"]}, base)
    assert np.all(np.asarray(g["com"].kp) > 0)  # clipped at exp(-3), never zero or negative
    np.testing.assert_allclose(g["com"].kp[1:], np.asarray(base["com"].kp[1:]) * [1, np.e])


def test_gain_space_rejects_bad_names():
    with pytest.raises(ValueError, match="GainSpace.tuned"):
        GainSpace(("body_ori.ki",))
    with pytest.raises(ValueError, match="GainSpace.tuned"):
        GainSpace(())
    base = default_gains(body_shaking_config("H2").tasks)
    with pytest.raises(ValueError, match="no task 'nope'"):
        GainSpace(("nope.kp",)).init(base)


def test_gain_space_bandwidth_scales_frequency_at_a_fixed_damping_ratio():
    base = default_gains(body_shaking_config("H1").tasks)
    space = GainSpace(("body_ori.bandwidth", "com.kd"))
    p = space.init(base, jnp.float64)
    assert p["body_ori.bandwidth"].shape == (1,) and space.task_gains == space.tuned
    c = 1.3
    g = space.gains(dict(p, **{"body_ori.bandwidth": jnp.array([np.log(c)])}), base)
    kp0, kd0 = np.asarray(base["body_ori"].kp), np.asarray(base["body_ori"].kd)
    kp, kd = np.asarray(g["body_ori"].kp), np.asarray(g["body_ori"].kd)
    np.testing.assert_allclose(np.sqrt(kp), c * np.sqrt(kp0))  # natural frequency x c
    np.testing.assert_allclose(kd / (2 * np.sqrt(kp)), kd0 / (2 * np.sqrt(kp0)))  # damping
    np.testing.assert_allclose(g["com"].kd, base["com"].kd)
    values = tuned_values(space, dict(p, **{"body_ori.bandwidth": jnp.array([np.log(c)])}), base)
    assert values["body_ori"]["kp"] == pytest.approx(list(c * c * kp0))
    # d kp / d s = 2 kp at s = 0, d kd / d s = kd
    dkp = jax.grad(lambda s: space.gains({**p, "body_ori.bandwidth": s}, base)["body_ori"].kp[0])
    assert float(dkp(jnp.zeros(1))[0]) == pytest.approx(2 * kp0[0])
    per_row = GainSpace(("body_ori.bandwidth",), per_row=True).init(base)
    assert per_row["body_ori.bandwidth"].shape == np.shape(base["body_ori"].kp)
    with pytest.raises(ValueError, match="already scales body_ori's kp and kd"):
        GainSpace(("body_ori.bandwidth", "body_ori.kd"))


def test_shipped_tuned_shaking_gains_load_and_keep_the_damping_ratio():
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "assets/gains/body_shaking_h1_bandwidth.json"
    config = apply_gains_file(body_shaking_config("H1"), path)
    kp, kd = np.asarray(config.task("body_ori").kp), np.asarray(config.task("body_ori").kd)
    hand = body_shaking_config("H1").task("body_ori")
    assert np.all(kp > np.asarray(hand.kp))  # tuned to a higher bandwidth
    # tuned with body_ori.bandwidth: the damping ratio is the hand-set one
    zeta = hand.kd[0] / (2 * np.sqrt(hand.kp[0]))
    np.testing.assert_allclose(kd / (2 * np.sqrt(kp)), zeta, rtol=1e-5)


def test_gain_space_tunes_replan_gamma_inside_zero_one():
    base = default_gains(body_shaking_config("H2").tasks)
    base_gait = {"replan_gamma": 0.5}  # a hand-set blend: its logit is 0
    space = GainSpace(("gait.replan_gamma", "com.kp"), per_row=True)
    p = space.init(base, jnp.float64)
    assert p["gait.replan_gamma"].shape == (1,)  # one number, whatever per_row says
    assert space.task_gains == ("com.kp",) and space.gait_numbers == ("replan_gamma",)
    assert float(space.gait_values(p, base_gait)["replan_gamma"]) == pytest.approx(0.5)
    np.testing.assert_allclose(space.gains(p, base)["com"].kp, base["com"].kp)
    for s, expected in (
        (np.log(3.0), 0.75),
        (-50.0, 1 / (1 + np.e**3)),
        (50.0, 1 / (1 + np.e**-3)),
    ):
        q = dict(p, **{"gait.replan_gamma": jnp.array([s])})
        assert float(space.gait_values(q, base_gait)["replan_gamma"]) == pytest.approx(expected)
    grad = jax.grad(
        lambda x: space.gait_values({"gait.replan_gamma": x}, base_gait)["replan_gamma"]
    )
    assert float(grad(jnp.zeros(1))[0]) == pytest.approx(0.25)  # sigmoid' at 0
    with pytest.raises(ValueError, match="tunable gait numbers"):
        GainSpace(("gait.replan_delay",))


def test_gain_space_tunes_the_replan_threshold_as_a_positive_scale():
    from jaxloco.locomotion.gait_params import GaitParams

    base_gait = {"replan_threshold": GaitParams().replan_threshold}
    space = GainSpace(("gait.replan_threshold",), max_log_scale=2.0)
    p = space.init({}, jnp.float64)
    assert space.gait_numbers == ("replan_threshold",) and space.task_gains == ()
    for s, expected in ((0.0, 0.05), (np.log(2.0), 0.1), (-50.0, 0.05 * np.exp(-2.0))):
        q = {"gait.replan_threshold": jnp.array([s])}
        value = float(space.gait_values(q, base_gait)["replan_threshold"])
        assert value == pytest.approx(expected)
    assert float(space.gait_values(p, base_gait)["replan_threshold"]) == pytest.approx(0.05)


def test_smoothed_gradient_sees_a_step_that_pathwise_derivatives_miss():
    """``loss = [x0 > 0] + x1^2``: the pathwise derivative in x0 is zero; the smoothed
    estimator gives the derivative of the Gaussian-smoothed loss, ``phi(x0 / s) / s`` and
    ``2 x1``, to its Monte Carlo error."""
    from jaxloco.tuning.optimize import value_and_grad

    def loss(p):
        x = p["x"]
        return (x[0] > 0).astype(x.dtype) + x[1] ** 2, {"x1": x[1]}

    p = {"x": jnp.array([0.05, 0.3], jnp.float64)}
    (l_fwd, _), g_fwd = jax.jit(value_and_grad(loss, "forward"))(p)
    assert float(g_fwd["x"][0]) == 0.0  # the step is invisible to derivatives
    sigma, pairs = 0.1, 20000
    (l0, aux), g = jax.jit(value_and_grad(loss, "smoothed", sigma, pairs, seed=3))(p)
    assert float(l0) == pytest.approx(1.09) == float(l_fwd) and float(aux["x1"]) == 0.3
    step_slope = np.exp(-0.5 * 0.5**2) / np.sqrt(2 * np.pi) / sigma  # phi(0.5) / 0.1 = 3.52
    np.testing.assert_allclose(np.asarray(g["x"]), [step_slope, 0.6], atol=0.1)
    # Deterministic for a given seed; another seed is another draw.
    (_, _), again = jax.jit(value_and_grad(loss, "smoothed", sigma, pairs, seed=3))(p)
    np.testing.assert_array_equal(np.asarray(again["x"]), np.asarray(g["x"]))
    with pytest.raises(ValueError, match="sigma > 0"):
        value_and_grad(loss, "smoothed", 0.0)
    with pytest.raises(ValueError, match="TuneConfig.smoothing_sigma"):
        TuneConfig(smoothing_sigma=-1.0)
    with pytest.raises(ValueError, match="TuneConfig.gradient"):
        TuneConfig(gradient="numeric")


def test_gains_file_carries_tuned_gait_numbers(tmp_path):
    from jaxloco.locomotion.gait_params import GaitParams

    path = save_gains(tmp_path / "g.json", {}, gait={"replan_gamma": np.float32(0.3)})
    assert load_gait(path) == {"replan_gamma": pytest.approx(0.3)}
    assert apply_gait_file(GaitParams(), path).replan_gamma == pytest.approx(0.3)
    assert apply_gait_file(GaitParams(), "") == GaitParams()
    plain = save_gains(tmp_path / "plain.json", {})
    assert load_gait(plain) == {} and apply_gait_file(GaitParams(), plain) == GaitParams()
    with pytest.raises(ValueError, match="replan_gamma"):  # GaitParams' own range check
        apply_gait_file(GaitParams(), save_gains(tmp_path / "b.json", {}, gait={"replan_gamma": 2}))
    with pytest.raises(ValueError, match="not GaitParams fields"):
        apply_gait_file(GaitParams(), save_gains(tmp_path / "c.json", {}, gait={"nope": 1.0}))


def test_gains_file_round_trip_into_a_controller_config(tmp_path):
    config = body_shaking_config("H2")
    base = default_gains(config.tasks)
    space = GainSpace(("body_ori.kp", "com.kd"))
    params = {"body_ori.kp": jnp.array([np.log(2.0)]), "com.kd": jnp.array([0.0])}
    path = save_gains(tmp_path / "g.json", tuned_values(space, params, base), {"loss": 1.0})
    values = load_gains(path)
    assert values["body_ori"]["kp"] == pytest.approx((200.0, 200.0, 200.0))
    tuned = apply_gains_file(config, path)
    assert tuned.task("body_ori").kp == pytest.approx((200.0,) * 3)
    assert tuned.task("com").kd == config.task("com").kd
    assert tuned.task("pelvis_ori") == config.task("pelvis_ori")
    assert apply_gains_file(config, "") is config
    with pytest.raises(ValueError, match="no task"):
        with_gains(config, {"nope": {"kp": (1.0,)}})
    with pytest.raises(FileNotFoundError):
        load_gains(tmp_path / "missing.json")
    with pytest.raises(ValueError, match="finite"):
        save_gains(tmp_path / "bad.json", {"com": {"kp": [np.nan], "kd": [1.0]}})


def test_tune_decreases_a_smooth_loss_with_adam_and_lbfgs():
    target = jnp.array([0.3, -0.2])

    def loss_fn(p):
        d = p["x"] - target
        return jnp.sum(d**2) + 0.1 * jnp.sum(d**4), {"dist": jnp.linalg.norm(d)}

    p0 = {"x": jnp.zeros(2)}
    for cfg in (
        TuneConfig(method="adam", iterations=60, learning_rate=0.05),
        TuneConfig(method="lbfgs", iterations=10),
    ):
        res = tune(loss_fn, p0, cfg, progress=False)
        assert res.best_loss < 1e-3 * res.history[0]["loss"], cfg.method
        assert res.history[0]["dist"] > res.history[-1]["dist"]
        np.testing.assert_allclose(res.params["x"], target, atol=0.03)


def test_tune_stops_with_a_clear_error_on_nan_and_on_exploding_gradients():
    def nan_after_a_while(p):
        return jnp.where(p["x"][0] > 0.5, jnp.nan, jnp.sum((p["x"] - 2.0) ** 2)), {}

    with pytest.raises(TuningDiverged, match="loss is nan at iteration") as err:
        tune(nan_after_a_while, {"x": jnp.zeros(1)}, TuneConfig(learning_rate=0.2), progress=False)
    assert float(err.value.last_good["x"][0]) <= 0.5 and err.value.history

    def steep(p):
        return 1e9 * jnp.sum(p["x"] ** 2) + 1.0, {}

    with pytest.raises(TuningDiverged, match="gradient norm"):
        tune(steep, {"x": jnp.ones(1)}, TuneConfig(max_grad_norm=1e3), progress=False)


@pytest.mark.parametrize("mode", ["forward", "reverse"])
def test_robust_gradient_leaves_out_samples_whose_gradient_explodes(mode):
    from jaxloco.tuning.optimize import robust_value_and_grad

    def sample_loss(p, s):  # the third sample's slope is 1e7: a contact-event artefact
        scale = jnp.where(s == 2.0, 1e7, 1.0)
        return scale * s * jnp.sum(p["x"] ** 2) + jnp.sum(p["x"]), {"s": s}

    samples = jnp.array([0.5, 1.0, 2.0, 3.0])
    p = {"x": jnp.array([0.2, -0.1])}
    (loss, aux), g = jax.jit(robust_value_and_grad(sample_loss, samples, mode, 100.0))(p)
    kept = [0.5, 1.0, 3.0]
    expected = np.mean([2 * s * np.asarray(p["x"]) + 1 for s in kept], axis=0)
    np.testing.assert_allclose(g["x"], expected, rtol=1e-6)
    assert float(aux["untrusted"]) == pytest.approx(0.25)
    assert float(aux["s"]) == pytest.approx(1.625)
    losses = [float(sample_loss(p, s)[0]) for s in samples]
    assert float(loss) == pytest.approx(np.mean(losses))  # the loss keeps every sample
    with pytest.raises(ValueError, match="max_sample_grad_norm"):
        robust_value_and_grad(sample_loss, samples, mode, 0.0)


def test_tune_config_validates():
    with pytest.raises(ValueError, match="TuneConfig.method"):
        TuneConfig(method="sgd")
    with pytest.raises(ValueError, match="TuneConfig.learning_rate"):
        TuneConfig(learning_rate=0.0)


def test_gradient_step_planner_takes_safe_steps_from_the_nominal_and_pushed_states():
    from jaxloco.planner import PSPParams, plan_steps
    from jaxloco.tuning.step_planner import GradientPlannerParams, make_gradient_policy

    psp = PSPParams()
    policy = make_gradient_policy(psp, GradientPlannerParams(horizon=1, iterations=30))
    starts = jnp.array([[0.056, 0.2, 0.0], [0.05, 0.39, 0.33], [0.1, 0.1, -0.2]])
    walks = jax.jit(jax.vmap(lambda s: plan_steps(s, policy, psp, num_steps=15)))(starts)
    assert np.all(np.asarray(walks.num_safe_steps) == 15)
    # The optimised first action from the nominal apex is near the nominal step.
    a = np.asarray(jax.jit(policy)(starts[0]))
    assert psp.p_x_min <= a[0] <= psp.p_x_max and abs(a[1] - psp.xd_apex_nominal) < 0.1


def test_a_start_state_tied_to_the_parameters_keeps_values_and_derivatives():
    """``depend_on`` changes no value and no derivative of a rollout (a chain of carries
    that reach the parameter one tick after another) and leaves integer leaves alone."""
    from jaxloco.tuning.rollout import depend_on

    start = {"a": jnp.zeros(2), "b": jnp.ones(2), "n": jnp.asarray(3, jnp.int32)}

    def rollout(p, tie):
        s0 = depend_on(start, {"gain": p}) if tie else start

        def tick(s, _):
            return {"a": s["a"] + p, "b": s["b"] * (1.0 + 0.1 * s["a"]), "n": s["n"] + 1}, None

        final, _ = jax.lax.scan(tick, s0, None, length=5)
        return jnp.sum(final["b"]) + final["n"]

    tied = depend_on(start, {"gain": jnp.asarray(0.3)})
    assert tied["n"].dtype == jnp.int32 and int(tied["n"]) == 3
    np.testing.assert_array_equal(tied["b"], start["b"])
    for p in (0.3, -1.2):
        plain = jax.jvp(lambda x: rollout(x, False), (jnp.asarray(p),), (jnp.asarray(1.0),))
        got = jax.jvp(lambda x: rollout(x, True), (jnp.asarray(p),), (jnp.asarray(1.0),))
        np.testing.assert_allclose(got, plain, rtol=1e-14)
        assert float(plain[1]) != 0.0
    np.testing.assert_allclose(
        jax.grad(lambda x: rollout(x, True))(0.3), jax.grad(lambda x: rollout(x, False))(0.3)
    )


def test_closed_loop_gradients_match_finite_differences_and_tuning_lowers_the_loss():
    """Forward-mode gradients through 60 ticks of WBLC + mjx.step (body shaking, float64,
    every loss term weighted, the feet's slip too) against central differences; then four
    Adam steps on the same compiled function."""
    from jaxloco.control.shaking import ShakingParams
    from jaxloco.dynamics.model import load_valkyrie
    from jaxloco.tuning.optimize import value_and_grad
    from jaxloco.tuning.problems import ShakingLossParams, shaking_loss
    from jaxloco.tuning.rollout import tuning_physics

    model = tuning_physics(load_valkyrie())
    space = GainSpace(("body_ori.kp", "body_ori.kd"))
    # Start mid-swing (no ramp) so the body error is large from the first tick.
    # One segment: a plain scan, as forward mode wants.
    problem = ShakingLossParams(horizon=0.06, segment=60, slip_weight=100.0)
    loss, p0, _ = shaking_loss(model, space, problem, ShakingParams(ramp=0.0, frequency_hz=2.0))
    pushes = PushArrays.none()
    fn = lambda p: loss(p, pushes)  # noqa: E731
    vg = jax.jit(value_and_grad(fn, "forward"))
    (l0, aux), g = vg(p0)
    assert np.isfinite(float(l0)) and float(aux["fallen"]) == 0.0
    # Standing feet barely move in 60 ticks: the slip term is there, finite and tiny.
    assert 0.0 < float(aux["slip"]) < 1e-6
    for name in p0:
        assert abs(float(g[name][0])) > 0
        eps = 1e-4
        up = float(vg({**p0, name: p0[name] + eps})[0][0])
        down = float(vg({**p0, name: p0[name] - eps})[0][0])
        fd = (up - down) / (2 * eps)
        # Measured: FD is stable from eps 1e-3 to 1e-6 and within 4e-4 relative of AD.
        np.testing.assert_allclose(float(g[name][0]), fd, rtol=2e-3, err_msg=name)
    res = tune(
        fn, p0, TuneConfig(iterations=4, learning_rate=0.2), progress=False, loss_and_grad=vg
    )
    losses = [h["loss"] for h in res.history]
    assert res.best_loss < losses[0] and losses[-1] < losses[0]


def test_shaking_reference_takes_a_traced_frequency_and_loss_frequencies_validate():
    from jaxloco.control.shaking import ShakingParams, shaking_reference
    from jaxloco.tuning.problems import ShakingLossParams

    q0 = jnp.asarray([1.0, 0.0, 0.0, 0.0])
    for got, want in zip(
        shaking_reference(ShakingParams(), q0, 0.7, jnp.asarray(2.5)),
        shaking_reference(ShakingParams(frequency_hz=2.5), q0, 0.7),
        strict=True,
    ):
        np.testing.assert_allclose(got, want, atol=1e-12)
    with pytest.raises(ValueError, match="ShakingLossParams.frequencies"):
        ShakingLossParams(frequencies=(1.0, 0.0))


def test_shaking_simulator_takes_gains_and_frequency_as_data():
    """One compiled shaking simulator serves every gains and frequency (tuning's
    validation): same run as a config carrying those gains, 50 ticks on MuJoCo C."""
    from jaxloco.control.shaking import ShakingParams
    from jaxloco.dynamics.model import load_valkyrie
    from jaxloco.sim.shaking import shaking_simulator, simulate_shaking

    model = load_valkyrie()
    config = body_shaking_config("H1", pinv_rtol=1e-2)
    tuned = with_gains(config, {"body_ori": {"kp": [150.0], "kd": [25.0]}})
    want = simulate_shaking(model, tuned, ShakingParams(ramp=0.0, frequency_hz=1.5), 0.05)
    simulate = shaking_simulator(model, config, ShakingParams(ramp=0.0))
    got = simulate(0.05, gains=default_gains(tuned.tasks), frequency_hz=1.5)
    assert len(got.time) == 50 and not got.fell
    np.testing.assert_allclose(
        got.outputs.body_error, want.outputs.body_error, rtol=1e-6, atol=1e-9
    )
    np.testing.assert_allclose(
        got.outputs.torque_norm, want.outputs.torque_norm, rtol=1e-6, atol=1e-9
    )
    plain = simulate(0.05)  # the config's own gains at its own 1 Hz
    assert np.max(np.abs(plain.outputs.torque_norm - got.outputs.torque_norm)) > 1.0
    with pytest.raises(ValueError, match="duration must be > 0"):
        simulate(0.0)


@pytest.mark.slow
def test_shaking_loss_averages_over_its_frequencies():
    """``frequencies=(a, b)`` is one batch of rollouts whose loss is the mean of the
    single-frequency losses (each built the old way, from ``ShakingParams.frequency_hz``).
    Slow: three compiles of the MJX rollout (~3 min)."""
    from jaxloco.control.shaking import ShakingParams
    from jaxloco.dynamics.model import load_valkyrie
    from jaxloco.tuning.problems import ShakingLossParams, shaking_loss
    from jaxloco.tuning.rollout import tuning_physics

    model = tuning_physics(load_valkyrie())
    space = GainSpace(("body_ori.kp",))
    pushes = PushArrays.none()

    def value(frequencies=(), frequency_hz=1.0):
        problem = ShakingLossParams(horizon=0.03, segment=30, frequencies=frequencies)
        loss, p0, _ = shaking_loss(
            model, space, problem, ShakingParams(ramp=0.0, frequency_hz=frequency_hz)
        )
        p = {k: v + 0.3 for k, v in p0.items()}
        return jax.jit(loss)(p, pushes)

    both, costs = value(frequencies=(1.5, 3.0))
    one, one_costs = value(frequency_hz=1.5)
    other, _ = value(frequency_hz=3.0)
    assert abs(float(one) - float(other)) > 1e-3 * abs(float(one))  # the frequency matters
    np.testing.assert_allclose(float(both), (float(one) + float(other)) / 2, rtol=1e-9)
    assert float(costs["track"]) > float(one_costs["track"]) > 0


@pytest.mark.slow
def test_tune_gains_cli_end_to_end(tmp_path):
    from cli_helpers import run_cli

    proc = run_cli(
        [
            "tune-gains",
            "tune.iterations=2",
            "problem.horizon=0.1",
            "validation_duration=0.2",
            "validation_every=1",
            "validation_frequencies=[]",
            "heldout_duration=0.3",
            "heldout_frequencies=[1.0]",
            "dpi=50",
        ],
        tmp_path,
        timeout=1200,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "run"
    summary = json.loads((run / "summary.json").read_text())
    assert summary["iterations"] == 2 and "1" in summary["heldout"]
    assert summary["kept"]["by"] == "validation"
    assert [r["iteration"] for r in summary["validation"]] == [0, 1]
    scores = {r["iteration"]: r["score"] for r in summary["validation"]}
    assert scores[summary["kept"]["iteration"]] == min(scores.values())
    # validation_frequencies=[]: the training frequencies
    assert set(summary["validation"][0]["runs"]) == {"0.8", "1.2"}
    assert load_gains(run / "tuned_gains.json")["body_ori"]["kp"]
    for name in ("loss_curve.png", "validation.png", "before_after.png", "history.json"):
        assert (run / name).stat().st_size > 0


def test_tune_in_dir_keeps_the_history_on_disk(tmp_path):
    from jaxloco.tuning.optimize import recorded_params, tune_in_dir

    def loss(p):
        return jnp.sum((p["x"] - 2.0) ** 2), {"dist": jnp.abs(p["x"][0] - 2.0)}

    cfg = TuneConfig(iterations=5, learning_rate=0.5)
    res = tune_in_dir(loss, {"x": jnp.zeros(1)}, cfg, tmp_path, progress=False)
    history = json.loads((tmp_path / "history.json").read_text())
    assert [h["iteration"] for h in history] == list(range(5))
    assert not (tmp_path / "history.json.partial").exists()
    s = res.summary()
    assert s["iterations"] == 5 and s["best_loss"] < s["initial_loss"] == pytest.approx(4.0)
    assert s["tuning_wall_s"] > 0 and "5 iterations" in res.describe()
    # The lowest-loss record on disk gives back the returned parameters.
    best = min(history, key=lambda h: h["loss"])
    np.testing.assert_allclose(recorded_params(best)["x"], res.params["x"], rtol=1e-6)


def test_push_loss_params_validate():
    from jaxloco.tuning.problems import PushLossParams

    for bad in (
        {"horizon": 0.0},
        {"phase": 1.5},
        {"dcm_weight": -1.0},
        {"risk_weight": -1.0},
        {"risk_threshold": 0.0},
        {"risk_temperature": 0.0},
        {"dcm_reference": "measured"},
        {"push_step": 0},
        {"apex_speed": 0.0},
    ):
        with pytest.raises(ValueError, match=f"PushLossParams.{next(iter(bad))}"):
            PushLossParams(**bad)


def test_touchdown_capture_point_matches_integrating_the_lipm():
    """The push loss's capture point at touch-down: the measured CoM state integrated
    under the LIPM about the stance foot (RK4, 1e-4 s) to the planned touch-down; its
    capture point minus the footstep."""
    from types import SimpleNamespace

    from jaxloco.tuning.problems import _touchdown_dcm_offset

    omega = float(np.sqrt(9.81 / 1.0))
    stance = np.array([0.3, -0.1])
    gait = SimpleNamespace(
        stance_pos=jnp.array([*stance, 0.0]),
        step_start=jnp.array(2.0),
        step_duration=jnp.array(0.45),
        target=jnp.array([0.75, 0.15, 0.0]),
    )
    com, vel, t = np.array([0.38, -0.05]), np.array([0.6, 0.25]), 2.17
    dcm = com + vel / omega
    got = np.asarray(_touchdown_dcm_offset(gait, jnp.asarray(dcm), t, omega))

    def f(s):
        return np.concatenate([s[2:], omega**2 * (s[:2] - stance)])

    s, dt = np.concatenate([com, vel]), 1e-4
    for _ in range(int(round((2.0 + 0.45 - t) / dt))):
        k1 = f(s)
        k2 = f(s + 0.5 * dt * k1)
        k3 = f(s + 0.5 * dt * k2)
        k4 = f(s + dt * k3)
        s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    want = s[:2] + s[2:] / omega - np.array([0.75, 0.15])
    np.testing.assert_allclose(got, want, atol=1e-9)
    # After the planned touch-down the capture point is not carried any further.
    late = np.asarray(_touchdown_dcm_offset(gait, jnp.asarray(dcm), 2.6, omega))
    np.testing.assert_allclose(late, dcm - np.array([0.75, 0.15]), atol=1e-12)


@pytest.mark.slow
def test_push_loss_gradients_while_walking_match_finite_differences():
    """Walking, pushed at 520 N from behind during single support (float64): forward-mode
    derivatives of the push loss w.r.t. replan gamma and the CoM gain against central
    differences over 0.1 s, before the next touch-down; the replan must have fired, so
    gamma's derivative is not trivially zero."""
    from jaxloco.dynamics.model import load_valkyrie
    from jaxloco.locomotion.walking import make_walking_controller
    from jaxloco.sim.mjx_loop import PhysicsParams, physics_model
    from jaxloco.tuning.optimize import value_and_grad
    from jaxloco.tuning.problems import PushLossParams, push_loss

    model = load_valkyrie()
    ctrl = make_walking_controller(model)
    space = GainSpace(("gait.replan_gamma", "com.kp"))
    loss, p0, _ = push_loss(
        physics_model(model, PhysicsParams()), ctrl, space, PushLossParams(horizon=0.1)
    )
    p0 = jax.tree.map(lambda x: x.astype(jnp.float64), p0)
    pushes = PushArrays.from_pairs([[520.0, 0.0]], 0.0, 0.1)
    fn = jax.jit(lambda p: loss(p, pushes))
    (l0, aux), g = jax.jit(value_and_grad(fn, "forward"))(p0)
    assert np.isfinite(float(l0)) and float(aux["fallen"]) == 0.0
    assert float(aux["dcm"]) > 0 and float(aux["tilt"]) > 0 and 0 < float(aux["at_risk"]) < 1
    for name in p0:
        eps = 1e-3
        up = float(fn({**p0, name: p0[name] + eps})[0])
        down = float(fn({**p0, name: p0[name] - eps})[0])
        fd = (up - down) / (2 * eps)
        assert abs(fd) > 1e-6, name  # gamma acts: a replan happened within 0.1 s
        np.testing.assert_allclose(float(g[name][0]), fd, rtol=2e-2, err_msg=name)


@pytest.mark.slow
def test_tune_push_cli_end_to_end(tmp_path):
    from cli_helpers import run_cli

    proc = run_cli(
        [
            "tune-push",
            "tune.iterations=2",
            # Both gait numbers, by smoothed gradients (the threshold has no pathwise one).
            "tuned=[gait.replan_gamma,gait.replan_threshold]",
            "tune.gradient=smoothed",
            "tune.smoothing_pairs=1",
            "problem.horizon=0.05",
            "pushes=[[520,0]]",
            "heldout.directions_deg=[90]",
            "heldout.magnitudes=[520]",
            "heldout.phases=[0.5]",
            "heldout.horizon=0.3",
            "heldout.steps_after=0",
            "validation.directions_deg=[0]",
            "validation.magnitudes=[520]",
            "validation.horizon=0.3",
            "validation.steps_after=0",
            "dpi=50",
        ],
        tmp_path,
        timeout=1800,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "run"
    summary = json.loads((run / "summary.json").read_text())
    assert summary["iterations"] == 2
    # Iterates 0 and 1 (the last) ran the validation sweep; one of them was kept.
    assert [r["iteration"] for r in summary["validation"]] == [0, 1]
    assert summary["kept"]["by"] == "validation" and summary["kept"]["iteration"] in (0, 1)
    assert (run / "validation" / "iter_01" / "manifest.json").is_file()
    assert set(summary["heldout"]) == {"hand-set", "tuned"}
    assert summary["heldout"]["tuned"]["pushes"] == 1
    assert set(summary["heldout"]["tuned"]["largest_recovered_impulse_Ns"]) == {"90"}
    assert 0 < summary["heldout_paired"]["p_value"] <= 1
    gait = load_gait(run / "tuned_gains.json")
    kept = summary["validation"][summary["kept"]["iteration"]]
    assert set(gait) == {"replan_gamma", "replan_threshold"}
    for name, value in gait.items():
        assert value == pytest.approx(kept["gait"][name])
    # The smoothed gradient moved the threshold at the first step.
    history = json.loads((run / "history.json").read_text())
    assert history[1]["params"]["gait.replan_threshold"] != [0.0]
    for name in ("loss_curve.png", "heldout.png", "history.json", "validation.png"):
        assert (run / name).stat().st_size > 0


def test_the_kept_iterate_is_the_best_validated_one_or_the_lowest_loss(caplog):
    from jaxloco.tuning.selection import (
        BY_LOSS,
        BY_VALIDATION,
        select_iterate,
        validation_iterates,
        warn_unless_held_out,
    )

    history = [
        {"iteration": i, "loss": loss, "params": {"k": [float(i)]}}
        for i, loss in enumerate([5.0, 3.0, 1.0, 2.0, 1.0, 4.0, 6.0])
    ]
    assert validation_iterates(7, 3) == [0, 3, 6]
    assert validation_iterates(1, 5) == [0]
    by_loss = select_iterate(history)
    assert (by_loss.by, by_loss.iteration, by_loss.rows) == (BY_LOSS, 2, ())  # earlier tie
    seen = []

    def validate(iteration, params):
        seen.append((iteration, float(params["k"][0])))
        return {"fell": iteration == 6, "error": {0: 0.5, 3: 0.2, 6: 0.1}[iteration]}

    kept = select_iterate(
        history, validate, score=lambda r: np.inf if r["fell"] else r["error"], every=3
    )
    assert seen == [(0, 0.0), (3, 3.0), (6, 6.0)]  # each iterate's own parameters
    assert (kept.by, kept.iteration) == (BY_VALIDATION, 3)  # 6 fell
    assert [r["iteration"] for r in kept.rows] == [0, 3, 6]
    assert kept.as_json()["rows"][1] == {"iteration": 3, "fell": False, "error": 0.2}
    hand_set = select_iterate(history, lambda i, p: {"s": 1.0}, score=lambda r: r["s"])
    assert hand_set.iteration == 0  # nothing beats the hand-set parameters
    with pytest.raises(ValueError, match="needs a score"):
        select_iterate(history, validate)
    with pytest.raises(ValueError, match="every must be >= 1"):
        validation_iterates(3, 0)
    assert warn_unless_held_out({1.0, 2.0}, {2.0, 3.0}, "frequencies") == {2.0}
    assert "held-out frequencies [2.0]" in caplog.text
