"""What the controller needs to know about a humanoid: :class:`RobotDescription`.

WBLC's task set, the gait and the sweeps are built from a description, never from a
model's names directly: its feet (contact frame and contact points), the bodies whose
orientation the hierarchy holds, its joint groups, the keyframe it stands in, and default
task gains. :func:`check_model` tells, by name, what a model lacks before anything is
compiled. A model is bound to a description by name (``RobotDescription.model``: a model
shipped in ``assets/``, an MJCF path, or a :class:`~jaxloco.robots.model_source.PackagedModel`:
a model of the installed model package, edited by code).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from jaxloco.dynamics.model import keyframe_qpos, load_model
from jaxloco.planner.scaling import FroudeScale
from jaxloco.robots.model_source import PackagedModel, build_model


@dataclasses.dataclass(frozen=True)
class Foot:
    """One foot: the site of its contact frame and the sites of its contact points, all on
    the foot's body."""

    name: str
    """Side, e.g. ``"left"``: task names are ``{name}_contact``, ``{name}_foot_pos``..."""
    frame: str
    """The contact frame: its origin at the centre of pressure at rest, on the sole; its
    axes level (z up) when the foot stands flat (the swing-foot tasks hold it level)."""
    points: tuple[str, ...]
    """The contact points (on the sole): where the force QP's reaction forces act."""


@dataclasses.dataclass(frozen=True)
class PD:
    """Task gains: one number for every row, or one per row (``()``: none)."""

    kp: tuple[float, ...] = (0.0,)
    """Proportional gain(s) (1/s^2; the CAM task's is a rate, 1/s)."""
    kd: tuple[float, ...] = (0.0,)
    """Derivative gain(s) (1/s)."""


@dataclasses.dataclass(frozen=True)
class TaskGains:
    """Default PD gains of the presets' tasks (units of the task: 1/s^2 and 1/s).

    The defaults are Valkyrie's: the CoM gains are the authors' (from their code), the
    rest ours, chosen so the robot stands and shakes stably at 1 kHz (the paper gives
    none)."""

    contact: PD = PD(kd=(10.0,))
    """The feet in contact (damping only: they are held still)."""
    com: PD = PD((50.0, 50.0, 220.0), (15.0, 15.0, 10.0))
    """The centre of mass, rows (x, y, z)."""
    cam: PD = PD((5.0,))
    """The centroidal angular momentum."""
    base_orientation: PD = PD((100.0,), (20.0,))
    """The pelvis's orientation."""
    torso_orientation: PD = PD((100.0,), (20.0,))
    """The torso's orientation."""
    foot_orientation: PD = PD((200.0,), (30.0,))
    """A swing foot's orientation."""
    foot_position: PD = PD((400.0,), (40.0,))
    """A swing foot's position."""
    posture: PD = PD((100.0,), (20.0,))
    """The joint posture tasks (upper body, arms, partial and full posture)."""

    def scaled(self, scale: FroudeScale) -> TaskGains:
        """These gains for a robot ``scale`` times the size they were chosen for (Froude
        scaling: a stiffness ``kp`` in 1/s^2 by ``1 / L``, a damping ``kd`` in 1/s by
        ``1 / sqrt(L)``; the CAM task's ``kp`` is a rate, 1/s), so the tasks' responses keep
        their shape in the robot's time scale. The identity for ``L = 1``."""
        if scale.length == 1.0:
            return self

        def pd(gains: PD, kp_per_time_squared: bool = True) -> PD:
            kp_factor = 1.0 / (scale.length if kp_per_time_squared else scale.time)
            return PD(
                tuple(k * kp_factor for k in gains.kp), tuple(k / scale.time for k in gains.kd)
            )

        return TaskGains(
            **{f.name: pd(getattr(self, f.name), f.name != "cam") for f in dataclasses.fields(self)}
        )


@dataclasses.dataclass(frozen=True)
class RobotDescription:
    """A humanoid as the controller sees it (every name is one in the model).

    ``feet`` is (left, right). ``base_frame`` and ``torso_frame`` are sites of the floating
    base (the pelvis) and of the upper body, level when the robot stands upright, whose
    orientations the walking and shaking hierarchies hold; ``base_body`` is the body pushes
    act on and whose height tells a fall. ``joints`` are every actuated joint (the full
    posture task); the groups below are subsets of them."""

    name: str
    """The robot's name: ``robot=`` in the experiments."""
    model: str | PackagedModel
    """A model in ``assets/`` by name, an MJCF path, or a model of the installed model
    package with the edits the controller needs (:mod:`jaxloco.robots.model_source`)."""
    feet: tuple[Foot, Foot]
    """(left, right) feet: their contact frames and contact points."""
    base_frame: str
    """Site of the floating base (pelvis), level when standing upright."""
    base_body: str
    """The body pushes act on and whose height tells a fall."""
    torso_frame: str
    """Site of the upper body, level when standing upright."""
    joints: tuple[str, ...]
    """Every actuated joint: the full posture task."""
    upper_body_joints: tuple[str, ...]
    """Torso and neck: the walking hierarchy's upper-body posture task."""
    arm_joints: tuple[str, ...]
    """The arms: the walking hierarchy's last task, and what carries the CAM while turning."""
    partial_posture_joints: tuple[str, ...]
    """Eq. 32's partial posture (every joint except shoulder pitch, shoulder roll, knee)."""
    keyframe: str = "walk"
    """The keyframe the robot starts in, and whose joint angles the posture tasks hold."""
    gains: TaskGains = TaskGains()
    """Default task gains (Valkyrie's; scaled to the robot's size by its presets)."""
    fall_height: float = 0.7
    """Height (m) of ``base_body`` below which the robot has fallen."""
    torque_limit: float | str = "model"
    """The actuator bound the robot's experiments simulate by default (``physics.
    torque_limit``): ``"model"``, the model's own effort limits; Valkyrie: the paper's
    500 N m at every joint."""
    solver_iterations: tuple[int, int] = (100, 50)
    """MuJoCo's constraint-solver (iterations, line-search iterations) the robot's
    experiments simulate with by default (``physics.iterations``, ``physics.ls_iterations``):
    MuJoCo's own defaults, as the model ships; Valkyrie: (2, 4), the settings all its
    results were measured with."""
    torque_limits_in_qp: bool = False
    """Whether the walking controller keeps the legs' torques within the model's effort
    limits in its force QP by default (``WBLCConfig.torque_limits_in_qp``)."""
    whole_body_limits: bool = False
    """Whether the walking controller keeps every joint's torque within its effort limit
    by default (``WBLCConfig.whole_body_limits``)."""
    planner: str = "default"
    """The shipped step policy its walking controller loads by default (a key of
    :data:`jaxloco.learning.checkpoint.SHIPPED_POLICIES`)."""
    foot_friction: float = 0.8
    """The sliding friction coefficient between its feet and the floor in its model
    (:func:`model_foot_friction`; :func:`check_model` refuses a model that differs). The
    force QP's friction pyramids follow it (:func:`jaxloco.control.presets.robot_force_qp`):
    the paper's authors planned with 0.65, relaxed to 1.75, on a 0.8 floor (Valkyrie's)."""
    length_scale: float | None = None
    """The robot's size relative to the reference robot that the gait's and planner's
    default numbers were chosen for (Valkyrie, 1.0): the ratio of their CoM heights above
    the soles in their keyframes. None: derived from the model (:func:`robot_scale`)."""

    def __post_init__(self):
        if len(self.feet) != 2:
            raise ValueError(f"RobotDescription {self.name!r}: feet must be (left, right)")
        groups = ("upper_body_joints", "arm_joints", "partial_posture_joints")
        for group in groups:
            extra = sorted(set(getattr(self, group)) - set(self.joints))
            if extra:
                raise ValueError(
                    f"RobotDescription {self.name!r}: {group} names joints not in joints: {extra}"
                )
        if self.length_scale is not None and not 0 < self.length_scale < 10:
            raise ValueError(
                f"RobotDescription {self.name!r}: length_scale must be in (0, 10) or None, "
                f"got {self.length_scale}"
            )
        if not (
            self.torque_limit == "model"
            or (isinstance(self.torque_limit, (int, float)) and self.torque_limit > 0)
        ):
            raise ValueError(
                f"RobotDescription {self.name!r}: torque_limit must be 'model' or > 0 N m, "
                f"got {self.torque_limit!r}"
            )
        if len(self.solver_iterations) != 2 or min(self.solver_iterations) < 1:
            raise ValueError(
                f"RobotDescription {self.name!r}: solver_iterations must be two ints >= 1, "
                f"got {self.solver_iterations}"
            )
        if not 0 < self.foot_friction < 10:
            raise ValueError(
                f"RobotDescription {self.name!r}: foot_friction must be in (0, 10), "
                f"got {self.foot_friction}"
            )
        if not self.fall_height > 0:
            raise ValueError(
                f"RobotDescription {self.name!r}: fall_height must be > 0 m, got {self.fall_height}"
            )

    def load(self) -> mujoco.MjModel:
        """The model, checked against this description (:func:`check_model`)."""
        if isinstance(self.model, PackagedModel):
            model = build_model(self.model)
        else:
            model = load_model(self.model)
        check_model(self, model)
        return model

    def foot_sites(self, model: mujoco.MjModel) -> tuple[int, ...]:
        """Site ids of the feet's contact frames (left, right)."""
        return tuple(model.site(foot.frame).id for foot in self.feet)

    def keyframe_qpos(self, model: mujoco.MjModel) -> np.ndarray:
        """The ``qpos`` of the robot's keyframe in ``model``."""
        return keyframe_qpos(model, self.keyframe)


REFERENCE_COM_HEIGHT = 1.0683481336352882
"""CoM height above the soles (m) of the reference robot (Valkyrie) in its ``walk``
keyframe: the size the gait's and planner's default numbers were chosen for."""


def com_height(robot: RobotDescription, model: mujoco.MjModel) -> float:
    """The CoM height above the lower sole (m) with ``robot`` standing in its keyframe."""
    data = mujoco.MjData(model)
    data.qpos[:] = robot.keyframe_qpos(model)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    sole = min(float(data.site_xpos[model.site(f.frame).id][2]) for f in robot.feet)
    return float(data.subtree_com[0][2]) - sole


def robot_scale(robot: RobotDescription, model: mujoco.MjModel) -> FroudeScale:
    """The Froude scale of ``robot`` (``length_scale``, else its CoM height in the keyframe
    over the reference's): gait and planner numbers chosen for the reference robot serve it
    scaled (:meth:`~jaxloco.locomotion.gait_params.GaitParams.scaled`,
    :class:`~jaxloco.learning.scaled.ScaledPlanner`)."""
    if robot.length_scale is not None:
        return FroudeScale(float(robot.length_scale))
    return FroudeScale(com_height(robot, model) / REFERENCE_COM_HEIGHT)


def model_foot_friction(robot: RobotDescription, model: mujoco.MjModel) -> float | None:
    """The least sliding friction coefficient MuJoCo gives a contact between a foot's body
    and the world (the floor) in ``model``: an explicit contact pair's own, else, for geoms
    whose collision masks meet, the higher-priority geom's, or the larger of the two at
    equal priority (MuJoCo's rule). None when no foot geom can touch the world."""
    feet = {int(model.site(foot.frame).bodyid[0]) for foot in robot.feet}
    world = np.flatnonzero(model.geom_bodyid == 0)
    found = []
    paired = set()
    for i in range(model.npair):
        pair = {int(model.pair_geom1[i]), int(model.pair_geom2[i])}
        bodies = {int(model.geom_bodyid[g]) for g in pair}
        if 0 in bodies and bodies & feet:
            found.append(float(model.pair_friction[i, 0]))
            paired.add(frozenset(pair))
    for g in np.flatnonzero(np.isin(model.geom_bodyid, list(feet))):
        for w in world:
            if frozenset((int(g), int(w))) in paired:
                continue
            if not (
                model.geom_contype[g] & model.geom_conaffinity[w]
                or model.geom_contype[w] & model.geom_conaffinity[g]
            ):
                continue
            pg, pw = model.geom_priority[g], model.geom_priority[w]
            if pg != pw:
                found.append(float(model.geom_friction[g if pg > pw else w, 0]))
            else:
                found.append(float(max(model.geom_friction[g, 0], model.geom_friction[w, 0])))
    return min(found) if found else None


def effort_limits(model: mujoco.MjModel) -> np.ndarray:
    """(nu,) each actuator's torque bound (N m): its control range times its gear; inf
    where the control is not limited."""
    gear = model.actuator_gear[:, 0]
    bound = np.max(np.abs(model.actuator_ctrlrange), axis=1) * np.abs(gear)
    return np.where(model.actuator_ctrllimited.astype(bool), bound, np.inf)


def check_model(robot: RobotDescription, model: mujoco.MjModel) -> None:
    """Raise ``ValueError`` naming everything ``model`` lacks that ``robot`` needs: sites,
    bodies, joints, a keyframe, a floating base, and a torque motor of gear 1 on every joint
    (the controller's torques are the actuators' controls)."""
    missing = []

    def has(kind, name):
        return mujoco.mj_name2id(model, kind, name) >= 0

    site, body, joint = (
        mujoco.mjtObj.mjOBJ_SITE,
        mujoco.mjtObj.mjOBJ_BODY,
        mujoco.mjtObj.mjOBJ_JOINT,
    )
    for foot in robot.feet:
        for name in (foot.frame, *foot.points):
            if not has(site, name):
                missing.append(f"site {name!r} ({foot.name} foot)")
        if has(site, foot.frame):
            body_of = model.site(foot.frame).bodyid[0]
            off = [p for p in foot.points if has(site, p) and model.site(p).bodyid[0] != body_of]
            if off:
                missing.append(f"{foot.name} foot's points {off} on the body of {foot.frame!r}")
    if has(body, robot.base_body):
        base = model.body(robot.base_body).id
        for foot in robot.feet:
            if has(site, foot.frame):
                joints = _joints_between(model, base, int(model.site(foot.frame).bodyid[0]))
                if joints < 6:
                    missing.append(
                        f"6 joints between the base and the {foot.name} foot (it has "
                        f"{joints}: a flat foot in contact fixes 6 directions, so in single "
                        "support the stance leg cannot also move the base's 6; e.g. no "
                        "ankle roll)"
                    )
    for field in ("base_frame", "torso_frame"):
        name = getattr(robot, field)
        if not has(site, name):
            missing.append(f"site {name!r} ({field})")
    if not has(body, robot.base_body):
        missing.append(f"body {robot.base_body!r} (base_body)")
    friction = model_foot_friction(robot, model) if not missing else None
    if friction is not None and abs(friction - robot.foot_friction) > 1e-6:
        missing.append(
            f"feet that meet the floor with the stated foot_friction {robot.foot_friction} (the "
            f"model's give {friction:g}: state foot_friction={friction:g})"
        )
    if model.njnt == 0 or model.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE:
        missing.append("a free joint as its first joint (the floating base)")
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, robot.keyframe) < 0:
        missing.append(f"keyframe {robot.keyframe!r}")
    driven = {}
    for a in range(model.nu):
        if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT:
            driven.setdefault(int(model.actuator_trnid[a, 0]), []).append(a)
    for name in robot.joints:
        if not has(joint, name):
            missing.append(f"joint {name!r}")
            continue
        j = model.joint(name).id
        if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
            missing.append(f"a hinge joint {name!r}")
        actuators = driven.get(j, [])
        if len(actuators) != 1:
            missing.append(f"exactly one actuator on joint {name!r} (has {len(actuators)})")
            continue
        a = actuators[0]
        if not _is_torque_motor(model, a):
            missing.append(
                f"a torque motor on joint {name!r} (actuator {model.actuator(a).name!r} is a "
                "servo: gain or bias depends on the state)"
            )
        elif model.actuator_gear[a, 0] != 1:
            missing.append(f"gear 1 on the motor of joint {name!r}")
    if missing:
        raise ValueError(
            f"model {_model_name(robot.model)!r} does not fit robot {robot.name!r}; it lacks: "
            + "; ".join(missing)
        )


def _model_name(model: str | PackagedModel) -> str:
    return model.name if isinstance(model, PackagedModel) else model


def _joints_between(model: mujoco.MjModel, base: int, body: int) -> int:
    """Hinge and slide joints on the kinematic chain from ``base`` down to ``body``."""
    count = 0
    while body not in (base, 0):
        for j in range(model.body_jntadr[body], model.body_jntadr[body] + model.body_jntnum[body]):
            if int(model.jnt_type[j]) in (
                int(mujoco.mjtJoint.mjJNT_HINGE),
                int(mujoco.mjtJoint.mjJNT_SLIDE),
            ):
                count += 1
        body = int(model.body_parentid[body])
    return count


def _is_torque_motor(model: mujoco.MjModel, a: int) -> bool:
    """A motor: force = gear * ctrl, no activation, no state-dependent gain or bias."""
    return (
        model.actuator_dyntype[a] == mujoco.mjtDyn.mjDYN_NONE
        and model.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
        and model.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_NONE
        and model.actuator_gear[a, 0] != 0
    )
