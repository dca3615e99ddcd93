"""Robots from the model package (MuJoCo Menagerie's Unitree G1 and Apptronik Apollo): the
code edits keep the model's own limits, the added sites sit where they should, H1 is
refused with the reason, Froude scaling keeps plans alike, and the G1 stands and walks on
MuJoCo C."""

import dataclasses
import json
import subprocess
import sys
import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from cli_helpers import run_cli

from jaxloco.control.presets import (
    CLOSED_LOOP_QP,
    CLOSED_LOOP_TORQUE_QP,
    body_shaking_config,
    walking_config,
)
from jaxloco.control.tasks import frame_quat, task_index
from jaxloco.control.wblc import make_wblc
from jaxloco.learning import load_planner
from jaxloco.learning.checkpoint import SHIPPED_POLICIES
from jaxloco.learning.evaluation import steps_survived
from jaxloco.learning.loading import checkpoint_digest, load_scaled_planner, save_scaled_checkpoint
from jaxloco.learning.scaled import ScaledPlanner, scale_box
from jaxloco.learning.starts import StartStates, uniform_states
from jaxloco.locomotion import GaitParams, make_walking_controller
from jaxloco.locomotion.walking import robot_gait, robot_planner
from jaxloco.planner import FroudeScale, PSPParams, plan_step, scale_psp
from jaxloco.robots import (
    APOLLO,
    G1,
    ROBOTS,
    VALKYRIE,
    check_model,
    com_height,
    effort_limits,
    robot_scale,
)
from jaxloco.robots.description import model_foot_friction
from jaxloco.robots.h1 import H1
from jaxloco.robots.model_source import package_root
from jaxloco.runtime import assets_dir
from jaxloco.sim import run_closed_loop
from jaxloco.sim.push import Push
from jaxloco.sim.scenarios import simulate_walk

PACKAGED = (G1, APOLLO)


@pytest.fixture(scope="module")
def models():
    return {robot.name: robot.load() for robot in PACKAGED}


@pytest.mark.parametrize("robot", PACKAGED, ids=lambda r: r.name)
def test_each_packaged_robot_loads_and_fits_its_description(models, robot):
    model = models[robot.name]
    check_model(robot, model)
    assert ROBOTS[robot.name] is robot
    assert model.nu == len(robot.joints) == model.nv - 6
    assert (package_root() / robot.model.folder / "LICENSE").exists()


def _mjcf_effort_limits(robot) -> dict[str, float]:
    """Each joint's effort limit read from the shipped MJCF text: the joint's
    ``actuatorfrcrange``, else its actuator's ``forcerange``."""
    root = ET.parse(package_root() / robot.model.folder / f"{_robot_file(robot)}").getroot()
    limits = {}
    for joint in root.iter("joint"):
        if "actuatorfrcrange" in joint.attrib:
            lo, hi = (float(x) for x in joint.attrib["actuatorfrcrange"].split())
            limits[joint.attrib["name"]] = max(abs(lo), abs(hi))
    for actuator in root.find("actuator"):
        joint = actuator.attrib["joint"]
        if joint not in limits and "forcerange" in actuator.attrib:
            lo, hi = (float(x) for x in actuator.attrib["forcerange"].split())
            limits[joint] = max(abs(lo), abs(hi))
    return limits


def _robot_file(robot) -> str:
    return {"unitree_g1": "g1.xml", "apptronik_apollo": "apptronik_apollo.xml"}[robot.model.folder]


@pytest.mark.parametrize("robot", PACKAGED, ids=lambda r: r.name)
def test_servos_become_torque_motors_at_the_models_own_limits(models, robot):
    """Every actuator is a torque motor (fixed gain, no bias, gear 1) whose control range is
    the joint's effort limit as the MJCF file states it; nothing else about the physics
    changes (masses, joint ranges, friction loss against the file as MuJoCo reads it)."""
    model = models[robot.name]
    expected = _mjcf_effort_limits(robot)
    limits = effort_limits(model)
    for a in range(model.nu):
        joint = model.joint(model.actuator_trnid[a, 0]).name
        assert limits[a] == pytest.approx(expected[joint]), joint
        assert model.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
        assert model.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_NONE
        assert model.actuator_gear[a, 0] == 1.0
    shipped = mujoco.MjModel.from_xml_path(str(robot.model.path))
    np.testing.assert_array_equal(model.body_mass, shipped.body_mass)
    np.testing.assert_array_equal(model.jnt_range, shipped.jnt_range)
    np.testing.assert_array_equal(model.dof_frictionloss, shipped.dof_frictionloss)
    np.testing.assert_array_equal(model.geom_friction, shipped.geom_friction)
    assert model.opt.timestep == (robot.model.timestep or shipped.opt.timestep)


@pytest.mark.parametrize("robot", PACKAGED, ids=lambda r: r.name)
def test_added_sites_stand_on_the_floor_and_are_level_in_the_keyframe(models, robot):
    model = models[robot.name]
    data = mujoco.MjData(model)
    data.qpos[:] = robot.keyframe_qpos(model)
    mujoco.mj_kinematics(model, data)
    for foot in robot.feet:
        points = [model.site(p).id for p in foot.points]
        frame = model.site(foot.frame).id
        assert np.min(data.site_xpos[points, 2]) == pytest.approx(0.0, abs=1e-9)
        np.testing.assert_allclose(data.site_xpos[points, 2], 0.0, atol=1e-4)  # a flat sole
        np.testing.assert_allclose(
            data.site_xpos[frame, :2], data.site_xpos[points, :2].mean(axis=0), atol=1e-9
        )
        np.testing.assert_allclose(data.site_xmat[frame].reshape(3, 3), np.eye(3), atol=1e-9)
    for name in (robot.base_frame, robot.torso_frame):
        np.testing.assert_allclose(
            data.site_xmat[model.site(name).id].reshape(3, 3), np.eye(3), atol=1e-9
        )


def test_orientation_tasks_read_a_tilted_sites_frame(models):
    """Apollo's foot frames are rotated in their bodies: the task's orientation is the
    site's, as MuJoCo computes it, not the body's."""
    model = models["apollo"]
    ctrl = make_wblc(model, walking_config(APOLLO))
    data = mujoco.MjData(model)
    data.qpos[:] = APOLLO.keyframe_qpos(model)
    data.qpos[7:] += np.random.default_rng(0).normal(0, 0.1, model.nq - 7)
    mujoco.mj_kinematics(model, data)
    snap = jax.jit(ctrl.snapshot)(jnp.asarray(data.qpos), jnp.zeros(model.nv))
    spec = next(t for t in ctrl.config.tasks if t.name == "left_foot_ori")
    index = task_index(model, spec)
    assert index.site_quat is not None
    expected = np.empty(4)
    mujoco.mju_mat2Quat(expected, data.site_xmat[index.site])
    got = np.asarray(frame_quat(snap.data, index))
    assert min(np.abs(got - expected).max(), np.abs(got + expected).max()) < 1e-9
    # Set-up's references from MuJoCo C turn the site the same way.
    held = ctrl.hold_references_at(model, data.qpos)["left_foot_ori"].pos
    np.testing.assert_allclose(held, got, atol=1e-9)


def test_h1_is_refused_with_the_reason():
    with pytest.raises(ValueError, match="6 joints between the base and the left foot \\(it has 5"):
        H1.load()
    assert "h1" not in ROBOTS


def test_robot_scale_is_the_com_height_ratio(models):
    """Valkyrie is the reference (scale 1, its CoM height the reference height); the G1 and
    Apollo scale by their CoM heights in their keyframes."""
    valkyrie = VALKYRIE.load()
    assert robot_scale(VALKYRIE, valkyrie).length == 1.0
    from jaxloco.robots.description import REFERENCE_COM_HEIGHT

    assert com_height(VALKYRIE, valkyrie) == pytest.approx(REFERENCE_COM_HEIGHT, abs=1e-12)
    for robot in PACKAGED:
        model = models[robot.name]
        derived = com_height(robot, model) / REFERENCE_COM_HEIGHT
        assert robot_scale(robot, model).length == pytest.approx(derived, abs=1e-4)
        unset = robot_scale(dataclasses.replace(robot, length_scale=None), model)
        assert unset.length == pytest.approx(derived, rel=1e-12)
    # The G1's default gains are Valkyrie's at its size (Apollo keeps Valkyrie's).
    scale = robot_scale(G1, models["g1"])
    assert G1.gains.com.kp[2] == pytest.approx(VALKYRIE.gains.com.kp[2] / scale.length)
    assert G1.gains.com.kd[0] == pytest.approx(VALKYRIE.gains.com.kd[0] / scale.time)
    assert G1.gains.cam.kp[0] == pytest.approx(VALKYRIE.gains.cam.kp[0] / scale.time)
    assert G1.gains.contact.kp == (0.0,) and APOLLO.gains == VALKYRIE.gains


def test_gait_numbers_scale_as_lengths_times_and_speeds():
    base = GaitParams()
    assert base.scaled(FroudeScale(1.0)) is base
    s = FroudeScale(0.64)
    g = base.scaled(s)
    assert g.com_height == pytest.approx(0.64 * base.com_height)
    assert g.step_y_range == pytest.approx(tuple(0.64 * x for x in base.step_y_range))
    assert g.min_step_duration == pytest.approx(0.8 * base.min_step_duration)
    assert g.max_apex_speed == pytest.approx(0.8 * base.max_apex_speed)
    assert g.arm_return_rate == pytest.approx(base.arm_return_rate / 0.8)
    assert (g.replan, g.replan_gamma, g.first_stance) == (
        base.replan,
        base.replan_gamma,
        base.first_stance,
    )
    with pytest.raises(ValueError, match="FroudeScale.length must be > 0"):
        FroudeScale(0.0)


def test_a_scaled_plan_is_the_reference_plan_in_scaled_units():
    """Froude similarity (float64): the PSP's plan at size L from the scaled state and the
    scaled action is the reference plan, its lengths times L and its times times sqrt(L)."""
    psp, scale = PSPParams(), FroudeScale(0.63)
    small = scale_psp(psp, scale)
    state = jnp.array([0.06, 0.25, 0.1])
    action = jnp.array([0.3, 0.3, -0.05])
    ref = plan_step(state, action, psp)
    got = plan_step(scale.from_reference(state), scale.from_reference(action), small)
    np.testing.assert_allclose(got.p_y, ref.p_y * scale.length, rtol=1e-10)
    np.testing.assert_allclose(got.t_switch, ref.t_switch * scale.time, rtol=1e-10)
    np.testing.assert_allclose(got.t_apex, ref.t_apex * scale.time, rtol=1e-10)
    np.testing.assert_allclose(
        got.next_state, scale.from_reference(ref.next_state), rtol=1e-9, atol=1e-12
    )
    np.testing.assert_allclose(got.reward, ref.reward * scale.length, rtol=1e-9)
    assert bool(got.terminal) == bool(ref.terminal)


def test_a_scaled_policy_survives_as_far_as_the_reference_on_the_scaled_box():
    planner = load_planner(shipped="algorithm1")
    scale = FroudeScale(0.63)
    scaled = ScaledPlanner(planner, scale)
    spec = StartStates()
    states = uniform_states(jax.random.PRNGKey(5), 512, spec)
    ref = steps_survived(planner.policy, states, planner.psp, 20)
    box = scale_box(spec, scale)
    small = states * jnp.asarray(scale.state_units)
    assert np.all(np.asarray(small) >= np.asarray(box.box_low) - 1e-12)
    got = steps_survived(scaled.policy, small, scaled.psp, 20)
    assert np.mean(np.asarray(got) == np.asarray(ref)) > 0.99  # float rounding at the edges


def test_the_shipped_robot_policies_are_the_default_at_the_robots_sizes(models, tmp_path):
    for robot in PACKAGED:
        assert robot.planner == robot.name and robot.name in SHIPPED_POLICIES
        planner = load_planner(shipped=robot.name)
        assert isinstance(planner, ScaledPlanner)
        assert planner.scale.length == pytest.approx(robot_scale(robot, models[robot.name]).length)
        assert robot_planner(robot, models[robot.name]).scale == planner.scale
    meta = json.loads((assets_dir() / SHIPPED_POLICIES["g1"] / "scaled.json").read_text())
    assert meta["reference"] == "../rl_psp_fallback"
    # A saved scaled checkpoint loads back, and its digest follows its scale.
    path = save_scaled_checkpoint(
        tmp_path / "g1", assets_dir() / SHIPPED_POLICIES["algorithm1"], FroudeScale(0.5), "g1"
    )
    back = load_scaled_planner(path)
    assert back.scale == FroudeScale(0.5)
    other = save_scaled_checkpoint(
        tmp_path / "other", assets_dir() / SHIPPED_POLICIES["algorithm1"], FroudeScale(0.6)
    )
    assert checkpoint_digest(path) != checkpoint_digest(other)
    with pytest.raises(FileNotFoundError):
        save_scaled_checkpoint(tmp_path / "bad", tmp_path / "nothing", FroudeScale(0.5))


def test_g1_stands_under_wblc_at_its_limits(models):
    """One second (500 ticks) standing in the walking hierarchy, torque rows on, on
    MuJoCo C: the CoM stays within 2 mm, no relaxed friction cone, no torque over the G1's
    limits."""
    model = models["g1"]
    ctrl = make_wblc(model, walking_config(G1))
    assert ctrl.config.torque_limits_in_qp
    q0 = jnp.asarray(G1.keyframe_qpos(model))
    refs = jax.jit(ctrl.hold_references)(q0)
    gains = ctrl.default_gains()

    @jax.jit
    def tick(q, v, prev):
        out = ctrl(q, v, refs, jnp.ones(2), gains, prev)
        return out.torques, out.qp_state, out.diagnostics

    data = mujoco.MjData(model)
    data.qpos[:] = G1.keyframe_qpos(model)
    mujoco.mj_forward(model, data)
    log, _ = run_closed_loop(
        model,
        data,
        lambda t, q, v, p: tick(jnp.asarray(q), jnp.asarray(v), p),
        ctrl.initial_qp_state(),
        500,
        stop=lambda d: d.qpos[2] < G1.fall_height,
    )
    assert not log.fell and len(log.time) == 500
    assert np.linalg.norm(log.outputs.task_errors["com"], axis=1).max() < 0.002
    assert not log.outputs.qp_relaxed.any()
    assert np.all(np.abs(log.ctrl) <= effort_limits(model) + 1e-6)


def test_g1_walks_three_steps_pushed_with_the_whole_body_within_its_limits(models):
    """From its keyframe, at the G1's own effort limits, with the Froude-scaled gait and its
    shipped step policy, the whole-body limit stage on and a 4 N s push from the side
    during the second step: three steps begun, no fall, no failed plan; every torque the
    controller commands within its joint's limit, the stage acting on some ticks and
    reporting which tasks gave way there (and none elsewhere); the feet in contact held."""
    model = models["g1"]
    ctrl = make_walking_controller(
        model, config=walking_config(G1, whole_body_limits=True), robot=G1
    )
    assert ctrl.gait_params == robot_gait(G1, model)
    assert ctrl.psp.h == pytest.approx(ctrl.gait_params.com_height)
    push = Push(magnitude=40.0, direction_deg=90.0, start=1.3, duration=0.1)
    run = simulate_walk(model, ctrl, 4.0, max_steps=3, pushes=(push,))
    assert not run.fell and run.steps_taken > 3
    o = run.log.outputs
    assert int(o.failed_plans[-1]) == 0
    feet = np.asarray(o.feet)
    assert feet[-1, :, 0].max() > 0.2  # it went forward
    assert np.all(np.abs(run.log.ctrl) <= effort_limits(model) * (1 + 1e-5))
    limited = np.asarray(o.limited)
    assert 0 < limited.sum() < len(limited)
    relaxation = np.asarray(o.relaxation.values)
    assert np.all(relaxation[~limited] == 0.0)
    assert np.all(relaxation[limited].max(axis=1) > 0.0)
    # The feet in contact are held: their relaxation is small next to the others'.
    contact = np.stack([o.relaxation[n][:, 0] for n in o.relaxation.names if "contact" in n])
    assert contact.max() < 0.05 * relaxation.max()


@pytest.mark.slow  # ~140 s in the suite; CI keeps the G1's configs and its pushed walk
def test_a_ci_sized_limit_search_on_the_g1(tmp_path):
    """`jaxloco push-sweep robot=g1`: one cell, one round, one replica, a short horizon. The
    G1's defaults follow the robot (its effort limits, MuJoCo's solver, its fall height, a
    bracket of the same velocity change as Valkyrie's 0-256 N s) and the report gives the
    limit in m/s against the paper's push at the G1's mass."""
    args = [
        "push-sweep",
        "robot=g1",
        "search.directions_deg=[90]",
        "search.phases=[0.5]",
        "search.replan=[true]",
        "search.rounds=1",
        "search.replicas=1",
        "search.min_recovered=1",
        "search.push_step=2",  # CI-sized: pushed early, watched briefly
        "search.horizon=1.5",
        "search.steps_after=1",
        "workers=1",
        "chunk_size=1",  # one push: a chunk of 16 would step 15 padding robots (84 -> 69 s)
    ]
    proc = run_cli(args, tmp_path, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "run"
    summary = json.loads((run / "summary.json").read_text())
    mass = summary["robot_mass_kg"]
    assert mass == pytest.approx(33.34, abs=0.01)
    assert summary["paper_impulse_Ns"] == pytest.approx(52.0 * mass / 135.9, abs=0.01)
    assert summary["search"]["impulse_range"] == [0.0, 64.0]
    assert summary["search"]["fall_height"] == G1.fall_height
    (cell,) = summary["cells"]
    assert cell["tested_Ns"] == [32.0]
    assert cell["limit_mps"] == pytest.approx(cell["limit_Ns"] / mass)
    manifest = json.loads((run / "round_00" / "manifest.json").read_text())
    assert manifest["settings"]["robot"] == "g1"
    physics = manifest["settings"]["physics"]
    assert (physics["iterations"], physics["ls_iterations"]) == (100, 50)
    assert physics["torque_limit"] == "model"
    assert "m/s" in (run / "summary.md").read_text()
    assert summary["torque_limit"] == "model"
    assert "each joint's own effort limit" in (run / "summary.md").read_text()


EXPECTED_DEFAULTS = {
    "valkyrie": {"torque_limit": 500.0, "iterations": 2, "ls_iterations": 4,
                 "fall_height": 0.7, "impulse_range": [0.0, 256.0]},
    "g1": {"torque_limit": "model", "iterations": 100, "ls_iterations": 50,
           "fall_height": 0.45, "impulse_range": [0.0, 64.0]},
    "apollo": {"torque_limit": "model", "iterations": 100, "ls_iterations": 50,
               "fall_height": 0.6, "impulse_range": [0.0, 160.0]},
}  # fmt: skip


def test_robot_defaults_of_the_experiment_configs():
    """The values configs take from their ``robot``: Valkyrie's stay the paper's (what `make
    run` searches with); the others get their own limits, MuJoCo's solver, their fall height
    and a bracket of the same velocity change as Valkyrie's 0-256 N s."""
    from jaxloco.app import _robot_value

    for robot, expected in EXPECTED_DEFAULTS.items():
        got = {f: _robot_value(robot, f) for f in expected if f != "impulse_range"}
        got["impulse_range"] = [0.0, _robot_value(robot, "impulse_high")]
        assert got == expected, robot
    with pytest.raises(ValueError, match="robot: one of"):
        _robot_value("nao", "fall_height")
    for robot, (mu, mu_relaxed) in EXPECTED_FRICTION_PYRAMIDS.items():
        got = (_robot_value(robot, "mu"), _robot_value(robot, "mu_relaxed"))
        assert got == pytest.approx((mu, mu_relaxed), rel=1e-12), robot


# The walking force QP's (mu, mu_relaxed): the paper's 0.65 and 1.75 on Valkyrie's 0.8 floor,
# in proportion on the G1's 0.6 feet and Apollo's 2.0 contact pairs.
EXPECTED_FRICTION_PYRAMIDS = {
    "valkyrie": (0.65, 1.75),
    "g1": (0.65 * 0.75, 1.75 * 0.75),
    "apollo": (0.65 * 2.5, 1.75 * 2.5),
}


@pytest.mark.parametrize("robot", [VALKYRIE, G1, APOLLO], ids=lambda r: r.name)
def test_each_robot_states_its_models_foot_friction_and_the_qp_follows_it(models, robot):
    """The stated friction is the model's (MuJoCo's rule: contact pairs, else priority,
    else the larger); the walking and shaking configs' pyramids follow it; a description
    that misstates it is refused with the model's value."""
    model = VALKYRIE.load() if robot is VALKYRIE else models[robot.name]
    assert model_foot_friction(robot, model) == pytest.approx(robot.foot_friction, abs=1e-9)
    mu, mu_relaxed = EXPECTED_FRICTION_PYRAMIDS[robot.name]
    for config in (walking_config(robot), body_shaking_config("H2", robot)):
        assert (config.force_qp.mu, config.force_qp.mu_relaxed) == pytest.approx(
            (mu, mu_relaxed), rel=1e-12
        )
    # The warm-started solver settings: with torque rows for the robots that keep them.
    qp = CLOSED_LOOP_TORQUE_QP if robot.torque_limits_in_qp else CLOSED_LOOP_QP
    got = walking_config(robot).force_qp
    assert (got.iterations, got.rho, got.torque_rho) == (qp.iterations, qp.rho, qp.torque_rho)
    wrong = dataclasses.replace(robot, foot_friction=robot.foot_friction + 0.1)
    with pytest.raises(ValueError, match=f"state foot_friction={robot.foot_friction:g}"):
        check_model(wrong, model)
    with pytest.raises(ValueError, match="foot_friction must be in"):
        dataclasses.replace(robot, foot_friction=0.0)


def test_foot_friction_follows_mujocos_rule_for_colliding_geoms():
    """Without contact pairs: the higher-priority geom's friction, the larger at equal
    priority; feet that cannot touch the floor have none."""
    spec = mujoco.MjSpec()
    floor = spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.1])
    floor.friction = [0.9, 0.005, 0.0001]
    foot = spec.worldbody.add_body(name="foot", pos=[0, 0, 0.1])
    foot.add_freejoint()
    sole = foot.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.01, 0, 0])
    sole.friction = [0.5, 0.005, 0.0001]
    foot.add_site(name="sole")
    robot = dataclasses.replace(
        VALKYRIE, feet=(dataclasses.replace(VALKYRIE.feet[0], frame="sole"),) * 2
    )
    assert model_foot_friction(robot, spec.compile()) == pytest.approx(0.9)
    sole.priority = 1
    assert model_foot_friction(robot, spec.compile()) == pytest.approx(0.5)
    sole.contype, sole.conaffinity = 0, 0
    assert model_foot_friction(robot, spec.compile()) is None


@pytest.mark.parametrize("robot", ["valkyrie", "g1"])
def test_push_sweep_config_resolves_the_robots_defaults(tmp_path, robot):
    """`jaxloco push-sweep robot=... --cfg job --resolve`: the defaults above, in the
    search, the grid sweep and the physics nodes."""
    import yaml

    proc = subprocess.run(
        [sys.executable, "-m", "jaxloco.cli", "push-sweep", f"robot={robot}", "--cfg", "job",
         "--resolve"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    cfg = yaml.safe_load(proc.stdout)
    physics, search = cfg["physics"], cfg["search"]
    got = {
        "torque_limit": physics["torque_limit"],
        "iterations": physics["iterations"],
        "ls_iterations": physics["ls_iterations"],
        "fall_height": search["fall_height"],
        "impulse_range": search["impulse_range"],
    }
    assert got == EXPECTED_DEFAULTS[robot]
    assert cfg["sweep"]["fall_height"] == EXPECTED_DEFAULTS[robot]["fall_height"]
    pyramids = (cfg["force_qp"]["mu"], cfg["force_qp"]["mu_relaxed"])
    assert pyramids == pytest.approx(EXPECTED_FRICTION_PYRAMIDS[robot], rel=1e-12)
    qp = CLOSED_LOOP_TORQUE_QP if ROBOTS[robot].torque_limits_in_qp else CLOSED_LOOP_QP
    got = cfg["force_qp"]
    assert (got["iterations"], got["rho"], got["torque_rho"]) == pytest.approx(
        (qp.iterations, qp.rho, qp.torque_rho), rel=1e-12
    )
