"""Facts of the Valkyrie-like model, pinned so nobody changes them by accident."""

import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest

from jaxloco.dynamics.model import (
    assets_dir,
    keyframe_qpos,
    load_model,
    load_valkyrie,
)
from jaxloco.robots.valkyrie import CONTACT_SITES, COP_SITES, VALKYRIE_JOINTS

EFFORT = {
    "hipYaw": 190,
    "hipRoll": 350,
    "hipPitch": 350,
    "knee": 350,
    "anklePitch": 205,
    "ankleRoll": 205,
    "torsoYaw": 190,
    "torsoPitch": 150,
    "torsoRoll": 150,
    "shoulderPitch": 190,
    "shoulderRoll": 190,
    "shoulderYaw": 65,
    "elbowPitch": 65,
    "forearmYaw": 26,
    "lowerNeckPitch": 26,
    "neckYaw": 26,
    "upperNeckPitch": 26,
}


@pytest.fixture(scope="module")
def model():
    return load_valkyrie()


def at_key(model, name):
    data = mujoco.MjData(model)
    data.qpos[:] = keyframe_qpos(model, name)
    mujoco.mj_forward(model, data)
    return data


def test_sizes_mass_and_joint_order(model):
    assert (model.nq, model.nv, model.nu) == (35, 34, 28)
    assert model.body_subtreemass[1] == pytest.approx(135.9, abs=1e-9)
    names = [model.joint(i).name for i in range(1, model.njnt)]
    assert tuple(names) == VALKYRIE_JOINTS
    assert model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    assert model.opt.timestep == pytest.approx(0.001)


def test_group_masses(model):
    def subtree(body):
        return model.body_subtreemass[model.body(body).id]

    assert subtree("left_hipYaw_link") == pytest.approx(24.855)
    assert subtree("right_hipYaw_link") == pytest.approx(24.855)
    assert subtree("left_shoulderPitch_link") == pytest.approx(15.041)
    assert subtree("lowerNeckPitch_link") == pytest.approx(7.818)
    assert model.body_mass[model.body("pelvis").id] == pytest.approx(8.22)


def test_limits_and_motors(model):
    for i, name in enumerate(VALKYRIE_JOINTS):
        base = name.split("_", 1)[-1]
        assert model.actuator(i).name == name
        np.testing.assert_allclose(model.actuator_ctrlrange[i], [-EFFORT[base], EFFORT[base]])
        assert model.jnt_limited[model.joint(name).id]
        assert model.dof_damping[model.jnt_dofadr[model.joint(name).id]] == 0.0
    np.testing.assert_allclose(model.joint("left_knee").range, [-0.083, 2.057])
    np.testing.assert_allclose(model.joint("left_hipYaw").range, [-0.414, 1.1])
    np.testing.assert_allclose(model.joint("right_hipYaw").range, [-1.1, 0.414])  # mirrored
    np.testing.assert_allclose(model.joint("right_shoulderRoll").range, [-1.266, 1.519])


def test_zero_pose(model):
    data = at_key(model, "zero")
    assert data.qpos[2] == pytest.approx(1.171)
    com_rel = data.subtree_com[1] - data.qpos[:3]
    np.testing.assert_allclose(com_rel, [-0.008, -0.001, -0.024], atol=2e-3)
    np.testing.assert_allclose(data.site(COP_SITES["left"]).xpos[1], 0.1377, atol=1e-3)
    np.testing.assert_allclose(data.site(COP_SITES["right"]).xpos[1], -0.1377, atol=1e-3)


def test_walking_keyframe(model):
    data = at_key(model, "walk")
    assert data.qpos[2] == pytest.approx(1.13, abs=0.005)
    assert data.subtree_com[1][2] == pytest.approx(1.08, abs=0.015)
    # The soles rest flat on the floor: every contact site at z = 0.
    for side in ("left", "right"):
        for site in (*CONTACT_SITES[side], COP_SITES[side]):
            assert data.site(site).xpos[2] == pytest.approx(0.0, abs=1e-6)
    # Arms lowered: hands below the shoulders.
    assert data.site("left_hand").xpos[2] < 1.0


def test_contacts_are_only_soles_on_the_floor(model):
    """Per foot, 4 contact spheres whose lowest points are the sole box's bottom corners."""
    assert model.npair == 8
    assert all(
        model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0 for g in range(model.ngeom)
    )
    floor = model.geom("floor").id
    pairs = {
        frozenset((int(model.pair_geom1[i]), int(model.pair_geom2[i]))) for i in range(model.npair)
    }
    spheres = [model.geom(f"{side}_sole{k}").id for side in ("left", "right") for k in range(4)]
    assert pairs == {frozenset((s, floor)) for s in spheres}
    np.testing.assert_allclose(model.pair_friction[:, 0], 0.8)
    for side in ("left", "right"):
        box = model.geom(f"{side}_sole")
        half = box.size
        want = {(round(box.pos[0] + sx * half[0], 6), round(box.pos[1] + sy * half[1], 6))
                for sx in (1, -1) for sy in (1, -1)}  # fmt: skip
        got = set()
        for k in range(4):
            ball = model.geom(f"{side}_sole{k}")
            assert ball.type[0] == mujoco.mjtGeom.mjGEOM_SPHERE
            assert ball.bodyid[0] == box.bodyid[0]
            # the sphere's lowest point lies on the box's bottom face
            assert ball.pos[2] - ball.size[0] == pytest.approx(box.pos[2] - half[2], abs=1e-9)
            got.add((round(ball.pos[0], 6), round(ball.pos[1], 6)))
        assert got == want


def test_force_qp_points_lie_on_the_sole(model):
    """The force QP may put all of a foot's load on any of its contact points, so each must
    lie on the sole, inside the footprint of the 4 sole spheres (else the QP asks for a
    centre of pressure beyond the sole's edge and the foot rolls over it)."""
    for side in ("left", "right"):
        spheres = np.array([model.geom(f"{side}_sole{k}").pos for k in range(4)])
        low, high = spheres[:, :2].min(axis=0), spheres[:, :2].max(axis=0)
        sole_bottom = spheres[0, 2] - model.geom(f"{side}_sole0").size[0]
        foot = model.geom(f"{side}_sole0").bodyid[0]
        points = np.array([model.site(s).pos for s in CONTACT_SITES[side]])
        assert all(model.site(s).bodyid[0] == foot for s in CONTACT_SITES[side])
        np.testing.assert_allclose(points[:, 2], sole_bottom, atol=1e-9)
        inset = np.minimum(points[:, :2] - low, high - points[:, :2])
        np.testing.assert_allclose(inset, 0.01, atol=1e-9)  # 1 cm inside every edge


def test_committed_xml_is_what_the_generator_writes(tmp_path):
    script = assets_dir() / "valkyrie" / "build_valkyrie.py"
    spec = importlib.util.spec_from_file_location("build_valkyrie", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out = module.main(tmp_path / "valkyrie.xml")
    assert out.read_text() == (assets_dir() / "valkyrie" / "valkyrie.xml").read_text()


def test_unknown_model_and_keyframe_errors(model):
    with pytest.raises(FileNotFoundError, match="no model 'nope'"):
        load_model("nope")
    with pytest.raises(KeyError, match="no keyframe 'run'"):
        keyframe_qpos(model, "run")
    assert Path(assets_dir()).is_dir()


def test_planar_arm_starts_with_its_tip_on_the_target_line():
    model = load_model("planar3dof")
    assert (model.nq, model.nv, model.nu) == (3, 3, 3)
    data = at_key(model, "start")
    np.testing.assert_allclose(data.site("tip").xpos, [0.62, 0.0, 0.0], atol=1e-5)
