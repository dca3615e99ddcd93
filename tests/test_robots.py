"""Robot descriptions: the Valkyrie instance fits its model, a model that lacks what a
description names is refused by name, and the controller's packages name no robot."""

import dataclasses
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

from jaxloco.control.presets import robot_tasks, walking_config
from jaxloco.dynamics.model import load_valkyrie
from jaxloco.robots import (
    DEFAULT_ROBOT,
    VALKYRIE,
    Foot,
    check_model,
    effort_limits,
    robot_by_name,
)
from jaxloco.robots import valkyrie as valkyrie_names

PACKAGE = Path(__file__).resolve().parents[1] / "jaxloco"


def test_valkyrie_description_fits_its_model():
    model = VALKYRIE.load()
    check_model(VALKYRIE, model)
    assert VALKYRIE.foot_sites(model) == tuple(model.site(f.frame).id for f in VALKYRIE.feet)
    np.testing.assert_array_equal(VALKYRIE.keyframe_qpos(model), model.key("walk").qpos)
    assert robot_by_name("valkyrie") is VALKYRIE is DEFAULT_ROBOT
    with pytest.raises(ValueError, match="robot: one of"):
        robot_by_name("atlas")


def test_effort_limits_are_the_control_ranges_times_gear():
    model = load_valkyrie()
    limits = effort_limits(model)
    assert limits.shape == (model.nu,)
    left_knee = model.actuator("left_knee").id
    np.testing.assert_allclose(
        limits[left_knee],
        model.actuator_ctrlrange[left_knee, 1] * model.actuator_gear[left_knee, 0],
    )
    model.actuator_ctrllimited[left_knee] = 0
    assert np.isinf(effort_limits(model)[left_knee])


def test_tasks_follow_the_description():
    """Another robot's names flow into every task: frames, feet, joint groups, gains."""
    other = dataclasses.replace(
        VALKYRIE,
        name="renamed",
        feet=(
            Foot("left", "lf", ("lf0", "lf1")),
            Foot("right", "rf", ("rf0", "rf1")),
        ),
        base_frame="base",
        torso_frame="chest",
        gains=dataclasses.replace(
            VALKYRIE.gains, com=dataclasses.replace(VALKYRIE.gains.com, kp=(1.0, 2.0, 3.0))
        ),
    )
    tasks = {t.name: t for t in robot_tasks(other)}
    assert tasks["left_contact"].frame == "lf" and tasks["right_foot_pos"].frame == "rf"
    assert tasks["pelvis_ori"].frame == "base" and tasks["body_ori"].frame == "chest"
    assert tasks["com"].kp == (1.0, 2.0, 3.0)
    cfg = walking_config(other)
    assert cfg.feet[1].points == ("rf0", "rf1")


def _without(model_xml_edit) -> mujoco.MjModel:
    spec = mujoco.MjSpec.from_file(str(PACKAGE.parent / "assets" / "valkyrie" / "valkyrie.xml"))
    model_xml_edit(spec)
    return spec.compile()


def test_a_model_lacking_what_the_description_names_is_refused_by_name():
    def drop_site(spec):
        spec.delete(spec.site("left_foot_contact2"))

    with pytest.raises(ValueError, match="lacks: site 'left_foot_contact2' \\(left foot\\)"):
        check_model(VALKYRIE, _without(drop_site))

    def drop_key(spec):
        spec.delete(spec.key("walk"))

    with pytest.raises(ValueError, match="keyframe 'walk'"):
        check_model(VALKYRIE, _without(drop_key))

    def servo_knee(spec):
        act = spec.actuator("left_knee")
        act.set_to_position(kp=100.0)

    with pytest.raises(ValueError, match="torque motor on joint 'left_knee'"):
        check_model(VALKYRIE, _without(servo_knee))

    def no_torso_site(spec):
        spec.delete(spec.site("torso"))

    with pytest.raises(ValueError, match="site 'torso' \\(torso_frame\\)"):
        check_model(VALKYRIE, _without(no_torso_site))


def test_description_rejects_joint_groups_outside_its_joints():
    with pytest.raises(ValueError, match="arm_joints names joints not in joints"):
        dataclasses.replace(VALKYRIE, arm_joints=("left_wrist",))
    with pytest.raises(ValueError, match="fall_height must be > 0"):
        dataclasses.replace(VALKYRIE, fall_height=0.0)


def test_controller_packages_name_no_robot():
    """control/, locomotion/ and sweep/ are built from a description: none of the shipped
    robot's joint, site, frame or keyframe names appears there as a string, nor its name."""
    names = {
        *VALKYRIE.joints,
        *(f.frame for f in VALKYRIE.feet),
        *(p for f in VALKYRIE.feet for p in f.points),
        VALKYRIE.base_frame,
        VALKYRIE.torso_frame,
        VALKYRIE.keyframe,
    }
    names |= set(valkyrie_names.LEG_JOINTS + valkyrie_names.ARM_JOINTS)
    literals = "|".join(re.escape(n) for n in sorted(names))
    pattern = re.compile(rf"[\"']({literals})[\"']|valkyrie", re.IGNORECASE)
    found = []
    for package in ("control", "locomotion", "sweep"):
        for path in sorted((PACKAGE / package).glob("*.py")):
            for number, line in enumerate(path.read_text().splitlines(), 1):
                if pattern.search(line):
                    found.append(f"{path.name}:{number}: {line.strip()}")
    assert not found, "\n".join(found)
