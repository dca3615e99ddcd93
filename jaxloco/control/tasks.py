"""WBLC tasks: small pure objects that give a Jacobian, ``Jdot qd`` and a desired
acceleration from PD gains plus a feed-forward reference (paper Eq. 5-6).

Every task reads one :class:`RobotSnapshot` (the dynamics of one state, computed once per
tick and shared). Kinds:

- ``com``: whole-body centre of mass, 3 rows.
- ``cam``: centroidal angular momentum ``k`` (momentum units, rows of ``J_cm``), 3 rows;
  its "position" reference is the desired momentum (usually 0): ``kdot^d = kp (k^d - k) +
  acc``. Inside WBLC its command is replaced by what the contact forces achieve (Eq. 15).
- ``orientation``: a site's frame (its body's orientation times the site's own, fixed
  rotation), quaternion error :func:`se3.rotation_error`, 3 rows.
- ``position``: a site's origin, 3 rows.
- ``joints``: a set of joints (partial or full posture), one row each.
- ``contact``: a foot held still (6 rows, ``[angular; linear]``), command ``-Jdot qd``.

A reference's ``weight`` (0..1) scales the task's rows: 0 switches it off (a swing-foot task
in double support) without changing any shape. Gains are a separate pytree (see
:func:`default_gains`) so they can be differentiated and tuned.
"""

from __future__ import annotations

import jaxloco.dynamics.quiet_mjx  # noqa: F401  (before brax, whose math imports MJX)

# isort: split
import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.math import quat_mul
from flax import struct

from jaxloco.control.triangular import lower_triangular_inverse
from jaxloco.dynamics import centroidal, se3
from jaxloco.dynamics import jacobians as jac
from jaxloco.dynamics.engine_terms import EngineTerms, dense_mass_matrix, engine_data
from jaxloco.dynamics.quiet_mjx import mjx
from jaxloco.dynamics.terms import joint_space_terms

KINDS = ("com", "cam", "orientation", "position", "joints", "contact")


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    """One task: its ``kind``, what it acts on (``frame``: a site; ``joints``: joint
    names) and default PD gains (a number, or one per row)."""

    name: str
    """Unique name; the key of the task's reference, gains and diagnostics."""
    kind: str
    """One of ``KINDS`` (see the module doc)."""
    frame: str = ""
    """Site name the task acts on (``orientation``, ``position``, ``contact``); empty otherwise."""
    joints: tuple[str, ...] = ()
    """Joint names (``joints`` tasks), one row each, in this order."""
    kp: tuple[float, ...] = (0.0,)
    """Default proportional gain(s): one number for every row, or one per row (1/s^2)."""
    kd: tuple[float, ...] = (0.0,)
    """Default derivative gain(s): one number for every row, or one per row (1/s)."""

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(
                f"TaskSpec {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}"
            )
        if self.kind in ("orientation", "position", "contact") and not self.frame:
            raise ValueError(
                f"TaskSpec {self.name!r}: kind {self.kind!r} needs a frame (site name)"
            )
        if self.kind == "joints" and not self.joints:
            raise ValueError(f"TaskSpec {self.name!r}: kind 'joints' needs joint names")
        for field in ("kp", "kd"):
            gains = getattr(self, field)
            if len(gains) not in (1, self.dim) or any(g < 0 for g in gains):
                raise ValueError(
                    f"TaskSpec {self.name!r}: {field} must be 1 or {self.dim} numbers >= 0, "
                    f"got {gains}"
                )

    @property
    def dim(self) -> int:
        return {"joints": len(self.joints), "contact": 6}.get(self.kind, 3)

    @property
    def reference_dim(self) -> int:
        """Size of the position reference (a quaternion for orientations)."""
        return 4 if self.kind == "orientation" else self.dim


@struct.dataclass
class TaskReference:
    """Desired position (quaternion ``w, x, y, z`` for orientations), velocity and
    feed-forward acceleration, and a weight in [0, 1] scaling the task's rows."""

    pos: jax.Array
    """Desired position: (3,) m for positions and the CoM, (4,) quaternion ``w, x, y, z`` for
    orientations, (3,) momentum (kg m^2/s) for the CAM, (joints,) rad for joints."""
    vel: jax.Array
    """Desired velocity in the task's row space (m/s, rad/s; the CAM task uses none)."""
    acc: jax.Array
    """Feed-forward acceleration added to the PD command (m/s^2, rad/s^2)."""
    weight: jax.Array
    """() in [0, 1]: scales the task's rows (0: off, without changing any shape)."""


@struct.dataclass
class TaskTerms:
    jacobian: jax.Array
    """(rows, nv) the task Jacobian, rows scaled by the reference's weight."""
    jdot_qdot: jax.Array
    """(rows,) ``Jdot qd``, scaled alike."""
    desired: jax.Array
    """Desired task acceleration ``xdd^d`` (PD + feed-forward)."""
    error: jax.Array
    """Position error (rotation vector for orientations); what plots show."""


@struct.dataclass
class RobotSnapshot:
    """Everything the tasks and WBLC need about one state, computed once per tick."""

    data: mjx.Data
    """MJX data of the state after kinematics, inertias and velocities
    (:func:`~jaxloco.dynamics.jacobians.smooth`)."""
    mass_matrix: jax.Array
    """(nv, nv) joint-space mass matrix ``A``."""
    coriolis: jax.Array
    """(nv,) Coriolis and centrifugal forces ``b`` (gravity apart)."""
    gravity: jax.Array
    """(nv,) generalized gravity force ``g``."""
    motion: jac.BodyMotion
    """Every body's twist and ``Jdot qd`` (:func:`~jaxloco.dynamics.jacobians.body_motion`)."""
    centroidal_matrix: jax.Array
    """(6, nv) centroidal momentum matrix ``J_cm``: angular rows (about the CoM) first, then
    linear."""
    centroidal_bias: jax.Array
    """(6,) ``Jdot_cm qd`` (Eq. 31), the same row order."""
    mass_cholesky: jax.Array
    """(nv, nv) lower-triangular ``L`` with ``L L' = mass_matrix``."""
    mass_cholesky_inverse: jax.Array
    """(nv, nv) ``L^-1``: every solve with ``A`` or ``L`` in a tick is a product with it."""
    com: jax.Array
    """(3,) whole-body centre of mass, world frame (m)."""
    com_vel: jax.Array
    """(3,) its velocity (m/s)."""
    total_mass: jax.Array
    """() the robot's mass (kg)."""


def snapshot(mx: mjx.Model, qpos, qvel) -> RobotSnapshot:
    """The dynamics of the state ``(qpos, qvel)`` on the MJX model ``mx``."""
    d = jac.smooth(mx, mjx.make_data(mx).replace(qpos=qpos, qvel=qvel))
    return snapshot_of_data(mx, d, mjx.full_m(mx, d))


def engine_snapshot(mx: mjx.Model, terms: EngineTerms) -> RobotSnapshot:
    """The dynamics of a state from what MuJoCo's C engine computed for it (:mod:`~jaxloco.
    dynamics.engine_terms`): the same snapshot as :func:`snapshot` to float round-off,
    without MJX's kinematics, inertia and Newton-Euler passes."""
    d = engine_data(mx, terms)
    return snapshot_of_data(mx, d, dense_mass_matrix(mx, jnp.asarray(terms.M, d.qvel.dtype)))


def snapshot_of_data(mx: mjx.Model, d: mjx.Data, mass_matrix) -> RobotSnapshot:
    """The snapshot of ``d`` (after :func:`~jaxloco.dynamics.jacobians.smooth` or holding
    the engine's fields), with its full mass matrix ``mass_matrix`` (nv, nv)."""
    qvel = d.qvel
    jcm = centroidal.centroidal_momentum_matrix(mx, d)
    total = jnp.sum(mx.body_mass)
    # The linear rows of J_cm are the total mass times the CoM Jacobian (gravity's map).
    terms = joint_space_terms(
        mx, d, smoothed=True, com_jac=jcm[3:] / total, mass_matrix=mass_matrix
    )
    chol = jnp.linalg.cholesky(terms.mass_matrix)
    chol_inv = lower_triangular_inverse(chol)
    return RobotSnapshot(
        data=d,
        mass_matrix=terms.mass_matrix,
        coriolis=terms.coriolis,
        gravity=terms.gravity,
        motion=jac.body_motion(mx, d),
        centroidal_matrix=jcm,
        centroidal_bias=centroidal.centroidal_bias(
            jcm, terms.mass_matrix, terms.coriolis, mass_cholesky_inverse=chol_inv
        ),
        mass_cholesky=chol,
        mass_cholesky_inverse=chol_inv,
        com=centroidal.centre_of_mass(mx, d),
        com_vel=jcm[3:] @ qvel / total,
        total_mass=total,
    )


@dataclasses.dataclass(frozen=True)
class TaskIndex:
    """Static model indices of one task."""

    site: int = -1
    """Site id of the task's frame (-1: none)."""
    body: int = -1
    """Id of that site's body (-1: none)."""
    qpos: tuple[int, ...] = ()
    """``qpos`` addresses of a ``joints`` task's joints."""
    dof: tuple[int, ...] = ()
    """Dof addresses of the same joints."""
    site_quat: tuple[float, ...] | None = None
    """The site's rotation in its body (w, x, y, z); None where the site is body-aligned."""


def task_index(model: mujoco.MjModel, spec: TaskSpec) -> TaskIndex:
    if spec.frame:
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, spec.frame)
        if site < 0:
            raise ValueError(f"TaskSpec {spec.name!r}: no site {spec.frame!r} in the model")
        quat = np.asarray(model.site_quat[site], float)
        aligned = np.allclose(quat, [1, 0, 0, 0])
        return TaskIndex(
            site=site,
            body=int(model.site_bodyid[site]),
            site_quat=None if aligned else tuple(float(x) for x in quat / np.linalg.norm(quat)),
        )
    if spec.joints:
        ids = []
        for name in spec.joints:
            j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if j < 0:
                raise ValueError(f"TaskSpec {spec.name!r}: no joint {name!r} in the model")
            if int(model.jnt_type[j]) not in (
                int(mujoco.mjtJoint.mjJNT_HINGE),
                int(mujoco.mjtJoint.mjJNT_SLIDE),
            ):
                raise ValueError(f"TaskSpec {spec.name!r}: joint {name!r} is not 1-dof")
            ids.append(j)
        return TaskIndex(
            qpos=tuple(int(model.jnt_qposadr[j]) for j in ids),
            dof=tuple(int(model.jnt_dofadr[j]) for j in ids),
        )
    return TaskIndex()


def frame_quat(d: mjx.Data, index: TaskIndex) -> jax.Array:
    """(4,) world orientation of a task's site: its body's, turned by the site's own rotation."""
    q = d.xquat[index.body]
    if index.site_quat is None:
        return q
    return quat_mul(q, jnp.asarray(index.site_quat, q.dtype))


def current_position(mx: mjx.Model, spec: TaskSpec, index: TaskIndex, snap: RobotSnapshot):
    """The task's current position (quaternion for orientations, momentum for CAM)."""
    d = snap.data
    if spec.kind == "com":
        return snap.com
    if spec.kind == "cam":
        return snap.centroidal_matrix[:3] @ d.qvel
    if spec.kind == "orientation":
        return frame_quat(d, index)
    if spec.kind in ("position", "contact"):
        pos = d.site_xpos[index.site]
        return pos if spec.kind == "position" else jnp.concatenate([frame_quat(d, index), pos])
    return d.qpos[jnp.asarray(index.qpos)]


def task_terms(
    mx: mjx.Model, spec: TaskSpec, index: TaskIndex, snap: RobotSnapshot, ref: TaskReference, gains
) -> TaskTerms:
    """Jacobian, ``Jdot qd`` and desired acceleration of one task (rows scaled by weight)."""
    d = snap.data
    kp, kd = gains.kp, gains.kd
    dtype = d.qvel.dtype
    if spec.kind == "com":
        j = snap.centroidal_matrix[3:] / snap.total_mass  # = the CoM Jacobian
        jdqd = jac.com_jdot_qdot(mx, d, snap.motion)
        err = ref.pos - snap.com
        desired = kp * err + kd * (ref.vel - j @ d.qvel) + ref.acc
    elif spec.kind == "cam":
        j, jdqd = snap.centroidal_matrix[:3], snap.centroidal_bias[:3]
        err = ref.pos - j @ d.qvel
        desired = kp * err + ref.acc
    elif spec.kind in ("orientation", "position", "contact"):
        point = d.site_xpos[index.site]
        j6 = jac.frame_jacobian(mx, d, point, index.body)
        jdqd6 = jac.frame_jdot_qdot(mx, d, point, index.body, snap.motion)
        if spec.kind == "orientation":
            j, jdqd = j6[:3], jdqd6[:3]
            err = se3.rotation_error(ref.pos, frame_quat(d, index))
            desired = kp * err + kd * (ref.vel - j @ d.qvel) + ref.acc
        elif spec.kind == "position":
            j, jdqd = j6[3:], jdqd6[3:]
            err = ref.pos - point
            desired = kp * err + kd * (ref.vel - j @ d.qvel) + ref.acc
        else:  # contact: hold still, damp any residual slip
            j, jdqd = j6, jdqd6
            err = jnp.zeros(6, dtype)
            desired = -kd * (j @ d.qvel)
    else:
        dofs = jnp.asarray(index.dof)
        j = jnp.zeros((len(index.dof), mx.nv), dtype).at[jnp.arange(len(index.dof)), dofs].set(1)
        jdqd = jnp.zeros(len(index.dof), dtype)
        err = ref.pos - d.qpos[jnp.asarray(index.qpos)]
        desired = kp * err + kd * (ref.vel - d.qvel[dofs]) + ref.acc
    w = ref.weight
    return TaskTerms(w * j, w * jdqd, w * desired, err)


@struct.dataclass
class PDGains:
    """One task's PD gains as traced data (the WBLC's ``gains`` argument holds one per
    task, ``{task name: PDGains}``, so they can be tuned and differentiated)."""

    kp: jax.Array
    """(dim,) stiffness per task row (1/s^2; the CAM task's is a rate, 1/s)."""
    kd: jax.Array
    """(dim,) damping per task row (1/s)."""


def default_gains(specs) -> dict[str, PDGains]:
    """``{task name: PDGains}`` from the specs' defaults (each broadcast to the task's rows)."""
    return {
        s.name: PDGains(
            kp=jnp.broadcast_to(jnp.asarray(s.kp, float), (s.dim,)),
            kd=jnp.broadcast_to(jnp.asarray(s.kd, float), (s.dim,)),
        )
        for s in specs
    }


def hold_reference(mx: mjx.Model, spec: TaskSpec, index: TaskIndex, snap: RobotSnapshot):
    """A reference that holds the task where it is now, at rest (weight 1)."""
    dtype = snap.data.qvel.dtype
    pos = current_position(mx, spec, index, snap)
    if spec.kind == "cam":
        pos = jnp.zeros(3, dtype)
    if spec.kind == "contact":
        pos = jnp.zeros(spec.reference_dim, dtype)
    zeros = jnp.zeros(spec.dim, dtype)
    return TaskReference(pos, zeros, zeros, jnp.ones((), dtype))


def hold_reference_from_data(
    model: mujoco.MjModel, data: mujoco.MjData, spec: TaskSpec, index: TaskIndex, dtype
) -> TaskReference:
    """:func:`hold_reference` at rest, read from MuJoCo C's ``data`` after its position
    stage (``mj_kinematics``): the same numbers without tracing MJX's kinematics, for
    set-up code that runs once (op by op, MJX's kinematics take seconds)."""
    if spec.kind == "com":
        pos = model.body_mass @ data.xipos / np.sum(model.body_mass)
    elif spec.kind in ("cam", "contact"):
        pos = np.zeros(spec.reference_dim)
    elif spec.kind == "orientation":
        pos = data.xquat[index.body].copy()
        if index.site_quat is not None:
            mujoco.mju_mulQuat(pos, data.xquat[index.body], np.asarray(index.site_quat))
    elif spec.kind == "position":
        pos = data.site_xpos[index.site]
    else:
        pos = data.qpos[list(index.qpos)]
    zeros = jnp.zeros(spec.dim, dtype)
    return TaskReference(jnp.asarray(pos, dtype), zeros, zeros, jnp.ones((), dtype))
