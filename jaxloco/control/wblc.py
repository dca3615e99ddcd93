"""The whole-body locomotion controller, WBLC (paper Section III, Fig. 7).

One tick (:func:`wblc_tick`), for a state ``(qpos, qvel)``, task references, a contact set
and the previous tick's QP solution, on one :class:`~jaxloco.control.tasks.RobotSnapshot`
(mass matrix, its Cholesky factor and inverse, bias forces, centroidal terms), in four
stages:

1. :func:`task_stage`: every task's Jacobian, ``Jdot qd`` and desired acceleration
   (:mod:`.tasks`);
2. :func:`hierarchy_stage`: the hierarchy of Eq. 9-10 (:mod:`.hierarchy`) over the levels
   of ``config.hierarchy``, with the CAM command left as a free term (the map is linear in
   it);
3. :func:`force_stage`: the reaction-force QP of Eq. 14 (:mod:`.force_qp`): the CoM task's
   acceleration as the hard linear part ``m (xdd_com^d + g)``, the CAM rate the hierarchy's
   motion implies as the soft angular part (the CAM task's PD command wherever the CAM is
   free in the hierarchy); the rate the forces achieve sets the CAM task's command (Eq. 15);
4. :func:`torque_stage`: torques by Eq. 16-19, ``[U', -A N] [tau; qdd_res] = A qdd_task +
   b + g - J_r' F_r``, its minimum-norm least-squares solution (:func:`torque_solution`).

Sign convention: ``F_r`` is the force of the ground *on the robot* (MuJoCo's), so Eq. 11
reads ``A qdd + b + g - J_r' F_r = U' tau``.

**Contact constraint.** Feet in contact are held still by a ``contact`` task: the paper's
hierarchy lists no such task, but without one ``qdd_task`` would accelerate feet that the
ground holds, and Eq. 11 would not describe the motion that follows. The presets put it
first; its rows are switched off for a foot out of contact. This is our choice, made
explicit in the configs.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from flax.core import FrozenDict

from jaxloco import validation as v
from jaxloco.control import force_qp
from jaxloco.control.hierarchy import INVERSES, HierarchyResult, prioritized_accelerations
from jaxloco.control.pinv import pinv_psd
from jaxloco.control.segments import Segments
from jaxloco.control.tasks import (
    PDGains,
    RobotSnapshot,
    TaskReference,
    TaskSpec,
    default_gains,
    engine_snapshot,
    hold_reference,
    hold_reference_from_data,
    snapshot,
    snapshot_of_data,
    task_index,
    task_terms,
)
from jaxloco.control.torque_limits import TorqueLimitParams, TorqueLimitSolution, limit_torques
from jaxloco.dynamics import jacobians as jac
from jaxloco.dynamics.engine_terms import EngineTerms
from jaxloco.dynamics.model import without_colliders
from jaxloco.dynamics.quiet_mjx import mjx


@dataclasses.dataclass(frozen=True)
class FootSpec:
    """A foot: the site of its contact frame and the sites of its contact points."""

    frame: str
    """Site of the foot's contact frame (its contact task's frame)."""
    points: tuple[str, ...]
    """Sites of the foot's contact points, where the force QP's forces act."""


@dataclasses.dataclass(frozen=True)
class WBLCConfig:
    """Tasks, their priority order and the solver settings.

    ``hierarchy``: levels, highest priority first; a level ``"a+b"`` stacks tasks ``a`` and
    ``b`` at one priority. A level ``"a|b"`` holds tasks of as many rows that are on one at
    a time (the swinging foot of either side): their rows, each scaled by its weight, are
    added into one block, which is the task that is on (and nothing when neither is), with
    half the rows of ``"a+b"``; both on at once, the block is their weighted sum, flagged
    by ``alternatives_overlap``. The two combine: ``"a|b+c"`` stacks ``c`` under the
    block. Tasks not named in it are not used. ``cam_task``/``com_task`` name the tasks
    whose commands feed the force QP.
    """

    tasks: tuple[TaskSpec, ...]
    """Every task the hierarchy or the force QP may use."""
    hierarchy: tuple[str, ...]
    """Priority levels, highest first (see the class doc)."""
    feet: tuple[FootSpec, ...]
    """The feet, each with its contact points."""
    com_task: str = "com"
    """The task whose command is the force QP's hard linear part."""
    cam_task: str = "cam"
    """The task whose command the force QP's achieved CAM rate sets (Eq. 15)."""
    force_qp: force_qp.ForceQPParams = force_qp.ForceQPParams()
    """The reaction-force QP's weights, bounds and solver settings."""
    com_acc_limit: float = float("inf")
    """Bound on the horizontal norm of the CoM task's commanded acceleration (m/s^2).
    The CoM's linear behaviour is a hard equality of the force QP, so a command beyond
    what friction gives (a push's velocity error times Kd) makes the QP relax the cone
    to ``mu_relaxed`` (1.75) and the feet slip on a floor of lower friction; bounding
    the command keeps the forces inside the cone (``inf``: off, the paper's WBLC)."""
    pinv_rtol: float = 1e-2
    """Rank threshold of the hierarchy: with ``whiten_tasks``, a projected task direction
    with less than this fraction left free by the levels above counts as lost; without,
    eigenvalues of ``J A^-1 J'`` below this fraction of the unprojected task's largest
    diagonal entry count as zero. A direction kept with freedom ``s`` amplifies its command
    by ``1/s``, so a looser threshold asks for smaller torques (docs/control.md)."""
    whiten_tasks: bool = True
    """Threshold in whitened task rows (:func:`jaxloco.control.hierarchy.whiten_task`)."""
    hierarchy_inverse: str | tuple[str, ...] = "truncated"
    """How the levels invert their projected ``J A^-1 J'``, for all levels or one per level:
    ``"truncated"`` (the paper's thresholded pseudo-inverse at ``pinv_rtol``, exact
    priorities) or ``"damped"`` (damped least squares with damping ``pinv_rtol``: priorities
    hold to ``(pinv_rtol/s)^2`` for a direction with freedom ``s``, and a Cholesky
    factorisation replaces an eigendecomposition; see :mod:`jaxloco.control.hierarchy`)."""
    torque_pinv_rtol: float = 1e-8
    """The same for Eq. 19's ``[U', -A N]``."""
    torque_limits_in_qp: bool = False
    """Keep the joints that carry a foot within the model's effort limits (control range
    times gear) in the force QP: their torques of Eq. 11, an affine map of the contact
    forces once the hierarchy has set the task accelerations (the CAM command through Eq.
    15), become inequality rows of Eq. 14, and the floating base's rotational rows
    equalities (:class:`~jaxloco.control.force_qp.TorqueRows`, :func:`torque_rows`). The
    forces move the centre of pressure and the split between the feet to bring the legs
    within their limits; a leg torque the forces cannot bring within its limit is reported
    (``qp_torque_excess``), and the upper body's torques, which the forces do not reach, are
    the hierarchy's (flagged in ``torque_over_limit``). Off: the paper's WBLC, torques
    unbounded."""
    whole_body_limits: bool = False
    """Bring every actuator's torque within its effort limit (control range times gear)
    in a last stage (:mod:`jaxloco.control.torque_limits`): the smallest change of the
    torques, in units of each limit, that keeps the feet in contact held; the other tasks
    give way, by what ``task_relaxation`` reports. Off: the torques leave the controller
    as the hierarchy and the force QP ask (``torque_over_limit`` flags the excess)."""
    torque_limit_stage: TorqueLimitParams = TorqueLimitParams()
    """The limit stage's solver settings (with ``whole_body_limits``)."""

    def __post_init__(self):
        names = [t.name for t in self.tasks]
        if len(set(names)) != len(names):
            raise ValueError(f"WBLCConfig.tasks: task names must be unique, got {names}")
        if not self.hierarchy:
            raise ValueError("WBLCConfig.hierarchy: needs at least one level")
        for level in self.hierarchy:
            for block in level_blocks(level):
                for name in block:
                    if name not in names:
                        raise ValueError(
                            f"WBLCConfig.hierarchy: unknown task {name!r} in level "
                            f"{level!r}; tasks are {names}"
                        )
                dims = {self.task(n).dim for n in block}
                if len(dims) > 1:
                    raise ValueError(
                        f"WBLCConfig.hierarchy: the alternatives {'|'.join(block)!r} in level "
                        f"{level!r} must have as many rows each, got {sorted(dims)}"
                    )
                if len(block) > 1 and self.cam_task in block:
                    raise ValueError(
                        f"WBLCConfig.hierarchy: the CAM task {self.cam_task!r} cannot be one "
                        f"of alternatives (level {level!r})"
                    )
        v.check_fields(
            self,
            [
                ("com_acc_limit", self.com_acc_limit > 0, "> 0 (inf: off)"),
                *(
                    (f, 0 < getattr(self, f) < 1, "in (0, 1)")
                    for f in ("pinv_rtol", "torque_pinv_rtol")
                ),
            ],
        )
        for field in ("com_task", "cam_task"):
            if getattr(self, field) not in names:
                raise ValueError(f"WBLCConfig.{field}: {getattr(self, field)!r} is not a task")
        if not self.feet:
            raise ValueError("WBLCConfig.feet: needs at least one foot")
        inverses = self.hierarchy_inverse
        one_for_all = isinstance(inverses, str)
        inverses = (inverses,) if one_for_all else tuple(inverses)
        if any(i not in INVERSES for i in inverses) or (
            not one_for_all and len(inverses) != len(self.hierarchy)
        ):
            raise ValueError(
                f"WBLCConfig.hierarchy_inverse: one of {sorted(INVERSES)}, or a tuple of "
                f"them, one per hierarchy level ({len(self.hierarchy)}); "
                f"got {self.hierarchy_inverse!r}"
            )

    def task(self, name: str) -> TaskSpec:
        return next(t for t in self.tasks if t.name == name)

    def level_tasks(self) -> tuple[str, ...]:
        """Every task the hierarchy names, in level order."""
        return tuple(n for level in self.hierarchy for b in level_blocks(level) for n in b)

    def with_hierarchy(self, *levels: str) -> WBLCConfig:
        return dataclasses.replace(self, hierarchy=tuple(levels))


def level_blocks(level: str) -> tuple[tuple[str, ...], ...]:
    """A hierarchy level's row blocks, in order: ``"a|b+c"`` is ``(("a", "b"), ("c",))``
    (see :class:`WBLCConfig`)."""
    return tuple(tuple(block.split("|")) for block in level.split("+"))


@struct.dataclass
class WBLCDiagnostics:
    qdd_desired: jax.Array
    """``qdd^d = qdd_task + N qdd_res`` (Eq. 12)."""
    contact_forces: jax.Array
    """(points, 3) reaction forces on the robot (N), world frame."""
    cam_rate_achieved: jax.Array
    """``W_ang F_r`` (Eq. 15)."""
    qp_relaxed: jax.Array
    """True when the nominal friction cone cannot carry the CoM task's net force, and
    ``mu_relaxed`` was used."""
    qp_infeasible: jax.Array
    """True when not even the relaxed cone can (see ``qp_linear_residual``)."""
    qp_linear_residual: jax.Array
    """Net force the contact forces miss (N)."""
    qp_primal_residual: jax.Array
    """How far the force QP's ADMM is from converged (N)."""
    qp_torque_excess: jax.Array
    """With ``torque_limits_in_qp``: the largest amount (N m) by which the QP's forces leave
    a torque over its limit (0: within every limit, and always without)."""
    base_residual: jax.Array
    """Floating-base rows of Eq. 17 left unmet (6,): 0 when the torques realise qdd^d."""
    torque_over_limit: jax.Array
    """(nu,) True where the output torque exceeds the actuator's limit (by more than
    1e-5 of it); never with ``whole_body_limits``."""
    torque_limit: TorqueLimitSolution
    """The limit stage's change of the torques (``whole_body_limits``; without it, no
    change)."""
    task_relaxation: Segments
    """Per task (by name), the change of its acceleration the limit stage makes
    (``J_k dqdd``; m/s^2 or rad/s^2): what each task gives way to keep the torques within
    their limits. Zero without ``whole_body_limits``."""
    task_errors: Segments
    """Per task (by name), its position error (rotation vector for orientations)."""
    level_residuals: Segments
    """Per hierarchy level (by level name or position), what it could not achieve
    (``e_k - J_k qdd_task``)."""
    alternatives_overlap: jax.Array
    """True when more than one task of a level's alternatives (``"a|b"``) was on: that
    block then held their weighted sum, not either task (always False without
    alternatives)."""


@struct.dataclass
class WBLCOutput:
    torques: jax.Array
    """(nu,) actuator torques, actuator order."""
    diagnostics: WBLCDiagnostics
    """What each stage did and left unmet."""
    qp_state: force_qp.ForceQPState
    """Pass back as ``previous`` next tick (warm start)."""


@struct.dataclass
class WBLC:
    """WBLC bound to a model: ``wblc(qpos, qvel, refs, contact, gains, previous)``.

    Build with :func:`make_wblc`. Pure and jittable; ``jax.vmap`` over a batch of robots.
    A pytree: the MJX model and the arrays are leaves, the configuration and the model's
    indices static, so a controller can be passed into ``jit`` as an argument (its model
    then is not baked into the program) and controllers of models that differ only in
    their numbers (masses, inertias, limits) stack and ``vmap``. Compared by identity.
    """

    mx: mjx.Model
    """The model the controller computes with (colliders off: it needs no contacts)."""
    selection: jax.Array
    """(nu, nv) the actuators' map to joint torques (their gears at their dofs)."""
    torque_limits: jax.Array
    """(nu,) each actuator's effort limit (N m; inf where the model sets none)."""
    config: WBLCConfig = struct.field(pytree_node=False)
    """Tasks, priority levels and solver settings."""
    indices: FrozenDict = struct.field(pytree_node=False)
    """``{task name: TaskIndex}``: each task's static model indices (sites, bodies,
    joints)."""
    point_sites: tuple[int, ...] = struct.field(pytree_node=False)
    """Site ids of the contact points, feet in config order."""
    point_bodies: tuple[int, ...] = struct.field(pytree_node=False)
    """Body id of each contact point."""
    foot_of_point: tuple[int, ...] = struct.field(pytree_node=False)
    """Index (in ``config.feet``) of each contact point's foot."""
    unactuated_dofs: tuple[int, ...] = struct.field(pytree_node=False)
    """Dofs no actuator drives (the floating base's)."""
    actuated_dofs: tuple[int, ...] = struct.field(pytree_node=False)
    """The dof each actuator drives, actuator order."""
    foot_actuators: tuple[int, ...] = struct.field(pytree_node=False)
    """Actuators whose joints carry a foot (a contact point's body or one of its
    ancestors): the torques the contact forces reach, the rows of ``torque_limits_in_qp``."""
    base_rotation_dofs: tuple[int, ...] = struct.field(pytree_node=False)
    """The free joint's rotational dofs (empty for a fixed base)."""

    # Compared by identity: jit keys bound methods (``jax.jit(ctrl.step)``)
    # on their object, and a field-wise hash would hash the model's arrays.
    __eq__ = object.__eq__
    __hash__ = object.__hash__

    def default_gains(self) -> dict[str, PDGains]:
        """``{task name: PDGains}``: the config's default gains as traced data."""
        return default_gains(self.config.tasks)

    def snapshot(self, qpos, qvel, engine: EngineTerms | mjx.Data | None = None) -> RobotSnapshot:
        """The dynamics of ``(qpos, qvel)``: computed by MJX, or read from ``engine``, what
        the simulator computed for this same state: MuJoCo C's
        :class:`~jaxloco.dynamics.engine_terms.EngineTerms`, or MJX's data after its
        position and velocity stages (:func:`jaxloco.sim.mjx_loop.step_first_half`). The
        simulated model must be this controller's (same bodies, masses, inertias)."""
        if engine is None:
            return snapshot(self.mx, qpos, qvel)
        if isinstance(engine, EngineTerms):
            return engine_snapshot(self.mx, engine)
        return snapshot_of_data(self.mx, engine, mjx.full_m(self.mx, engine))

    def hold_references(self, qpos, qvel=None) -> dict[str, TaskReference]:
        """References that hold every task where it is at ``qpos`` (zero velocity)."""
        qvel = jnp.zeros(self.mx.nv) if qvel is None else qvel
        snap = self.snapshot(qpos, qvel)
        return {
            t.name: hold_reference(self.mx, t, self.indices[t.name], snap)
            for t in self.config.tasks
        }

    def hold_references_at(self, model: mujoco.MjModel, qpos) -> dict[str, TaskReference]:
        """:meth:`hold_references` at rest at ``qpos``, computed by MuJoCo C on ``model``
        (this controller's model): no tracing, for set-up code (dtype: JAX's default)."""
        data = mujoco.MjData(model)
        data.qpos[:] = np.asarray(qpos)
        mujoco.mj_kinematics(model, data)
        dtype = jnp.result_type(float)
        return {
            t.name: hold_reference_from_data(model, data, t, self.indices[t.name], dtype)
            for t in self.config.tasks
        }

    def initial_qp_state(self, dtype=None) -> force_qp.ForceQPState:
        rows = len(self.foot_actuators) + len(self.base_rotation_dofs)
        rows = rows if self.config.torque_limits_in_qp else 0
        return force_qp.zero_warm_start(len(self.point_sites), dtype, rows)

    def __call__(
        self, qpos, qvel, refs, contact, gains=None, previous=None, snap=None
    ) -> WBLCOutput:
        return wblc_tick(self, qpos, qvel, refs, contact, gains, previous, snap)


def make_wblc(model: mujoco.MjModel, config: WBLCConfig, mx: mjx.Model | None = None) -> WBLC:
    mx = mjx.put_model(without_colliders(model)) if mx is None else mx
    indices = {t.name: task_index(model, t) for t in config.tasks}
    point_sites, foot_of_point = [], []
    for k, foot in enumerate(config.feet):
        for name in foot.points:
            site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)
            if site < 0:
                raise ValueError(f"WBLCConfig.feet: no site {name!r} in the model")
            point_sites.append(site)
            foot_of_point.append(k)
    for t in config.tasks:
        if t.kind == "contact" and t.frame not in [f.frame for f in config.feet]:
            raise ValueError(f"contact task {t.name!r}: frame {t.frame!r} is not a foot frame")
    if not all(model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT):
        raise ValueError("make_wblc: every actuator must drive a joint")
    dofs = model.jnt_dofadr[model.actuator_trnid[:, 0]]
    selection = (
        jnp.zeros((model.nu, model.nv))
        .at[jnp.arange(model.nu), dofs]
        .set(model.actuator_gear[:, 0])
    )
    limits = jnp.where(
        model.actuator_ctrllimited.astype(bool),
        jnp.max(jnp.abs(model.actuator_ctrlrange), axis=1) * model.actuator_gear[:, 0],
        jnp.inf,
    )
    if np.any(model.actuator_gear[:, 0] == 0):
        raise ValueError("make_wblc: every actuator needs a nonzero gear")
    if config.torque_limits_in_qp and not np.all(np.isfinite(np.asarray(limits))):
        unlimited = [model.actuator(a).name for a in np.flatnonzero(~np.isfinite(limits))]
        raise ValueError(
            "WBLCConfig.torque_limits_in_qp needs an effort limit (ctrlrange) on every "
            f"actuator; unlimited: {unlimited}"
        )
    if len(set(dofs.tolist())) != len(dofs):
        raise ValueError("make_wblc: each actuated joint must have exactly one actuator")
    unactuated = tuple(sorted(set(range(model.nv)) - {int(v) for v in dofs}))
    carrying = set()
    for site in point_sites:
        body = int(model.site_bodyid[site])
        while body > 0:
            start, count = int(model.body_dofadr[body]), int(model.body_dofnum[body])
            carrying.update(range(start, start + count))
            body = int(model.body_parentid[body])
    foot_actuators = tuple(a for a, dof in enumerate(dofs.tolist()) if dof in carrying)
    free = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    base_rotation = tuple(int(model.jnt_dofadr[j]) + k for j in free[:1] for k in (3, 4, 5))
    return WBLC(
        mx=mx,
        selection=selection,
        torque_limits=limits,
        config=config,
        indices=FrozenDict(indices),
        point_sites=tuple(point_sites),
        point_bodies=tuple(int(model.site_bodyid[s]) for s in point_sites),
        foot_of_point=tuple(foot_of_point),
        unactuated_dofs=unactuated,
        actuated_dofs=tuple(int(v) for v in dofs),
        foot_actuators=foot_actuators,
        base_rotation_dofs=base_rotation,
    )


@struct.dataclass
class ForceStage:
    """What the force QP gives the rest of the tick (stage 3)."""

    solution: force_qp.ForceQPSolution
    """The force QP's forces and residuals."""
    cam_shift: jax.Array
    """(4,) ``[1, W_ang F_r - cam_rate]``: the weights of the hierarchy's command columns
    (the tasks' commands, then unit CAM commands) that give Eq. 15's CAM command."""


@struct.dataclass
class TorqueSolution:
    """Eq. 19's solution (stage 4)."""

    torques: jax.Array
    """(nu,) actuator torques (N m, actuator order)."""
    qdd_res: jax.Array
    """(nv,) the null-space acceleration ``qdd_res`` of Eq. 12."""
    base_residual: jax.Array
    """(number of unactuated dofs,) floating-base rows left unmet (0 when met)."""


def wblc_tick(
    ctrl: WBLC, qpos, qvel, refs: dict, contact, gains=None, previous=None, snap=None
) -> WBLCOutput:
    """One WBLC tick (see the module doc): :func:`task_stage`, :func:`hierarchy_stage`,
    :func:`force_stage` and :func:`torque_stage` on one :class:`RobotSnapshot`.

    ``contact``: (feet,) weights in [0, 1]; a foot is in contact when > 0 and its
    normal-force bound ramps with the weight (blending). ``snap``: the state's
    :class:`RobotSnapshot` when the caller already has it."""
    gains = ctrl.default_gains() if gains is None else gains
    # Each stage a named scope: they show by name in profiles (jax.profiler, XLA dumps).
    if snap is None:
        with jax.named_scope("wblc.snapshot"):
            snap = ctrl.snapshot(qpos, qvel)
    dtype = snap.data.qvel.dtype
    contact = jnp.clip(jnp.asarray(contact, dtype), 0.0, 1.0)
    previous = ctrl.initial_qp_state(dtype) if previous is None else previous

    with jax.named_scope("wblc.tasks"):
        terms = task_stage(ctrl, snap, refs, contact, gains)
    with jax.named_scope("wblc.hierarchy"):
        hier = hierarchy_stage(ctrl, snap, terms, refs[ctrl.config.cam_task].weight)
    with jax.named_scope("wblc.force_qp"):
        forces = force_stage(ctrl, snap, terms, hier, contact, previous)
    with jax.named_scope("wblc.torques"):
        qdd_task = hier.qdd @ forces.cam_shift
        torques = torque_stage(ctrl, snap, hier, qdd_task, forces.solution.forces)
    with jax.named_scope("wblc.limits"):
        limited = limit_stage(ctrl, snap, terms, torques.torques)

    cfg, sol = ctrl.config, forces.solution
    diagnostics = WBLCDiagnostics(
        qdd_desired=qdd_task + hier.apply_null_space(torques.qdd_res),
        contact_forces=sol.forces,
        cam_rate_achieved=sol.angular,
        qp_relaxed=sol.relaxed,
        qp_infeasible=sol.infeasible,
        qp_linear_residual=sol.linear_residual,
        qp_primal_residual=sol.primal_residual,
        qp_torque_excess=sol.torque_excess,
        base_residual=torques.base_residual,
        torque_over_limit=jnp.abs(limited.torques) > ctrl.torque_limits * (1 + 1e-5),
        torque_limit=limited,
        task_relaxation=Segments.stack(
            {
                # Without the limit stage nothing gives way: no products with zeros.
                n: t.jacobian @ limited.acceleration_change
                if cfg.whole_body_limits
                else jnp.zeros(t.jacobian.shape[0], dtype)
                for n, t in terms.items()
            }
        ),
        task_errors=Segments.stack({n: t.error for n, t in terms.items()}),
        level_residuals=Segments(
            jnp.concatenate(hier.task_residuals, axis=0) @ forces.cam_shift,
            tuple(cfg.hierarchy),
            tuple(r.shape[0] for r in hier.task_residuals),
        ),
        alternatives_overlap=alternatives_overlap(cfg, terms),
    )
    return WBLCOutput(limited.torques, diagnostics, sol.warm_start)


def alternatives_overlap(cfg: WBLCConfig, terms: dict) -> jax.Array:
    """Whether more than one task of any level's alternatives (``"a|b"``) is on (has a
    row that is not zero)."""
    overlap = jnp.zeros((), bool)
    for level in cfg.hierarchy:
        for block in level_blocks(level):
            if len(block) > 1:
                on = sum(jnp.any(terms[n].jacobian != 0).astype(jnp.int32) for n in block)
                overlap = overlap | (on > 1)
    return overlap


def task_stage(
    ctrl: WBLC, snap: RobotSnapshot, refs: dict, contact, gains: dict[str, PDGains]
) -> dict:
    """Stage 1: the terms (Jacobian, ``Jdot qd``, desired acceleration) of every task the
    hierarchy or the force QP uses, by task name. A contact task's rows follow the contact
    set, not its reference; the CoM command's horizontal part is bounded by
    ``com_acc_limit``."""
    cfg, dtype = ctrl.config, snap.data.qvel.dtype
    foot_frames = [f.frame for f in cfg.feet]
    used = set(cfg.level_tasks()) | {cfg.com_task, cfg.cam_task}
    terms = {}
    for t in cfg.tasks:
        if t.name not in used:
            continue
        ref = refs[t.name]
        if t.kind == "contact":  # the contact set decides, not the reference
            ref = ref.replace(weight=(contact[foot_frames.index(t.frame)] > 0).astype(dtype))
        terms[t.name] = task_terms(ctrl.mx, t, ctrl.indices[t.name], snap, ref, gains[t.name])
    if cfg.com_acc_limit < float("inf"):
        com = terms[cfg.com_task]
        horizontal = com.desired[:2]
        norm = jnp.linalg.norm(horizontal)
        scale = jnp.minimum(1.0, cfg.com_acc_limit / jnp.maximum(norm, 1e-9))
        terms[cfg.com_task] = com.replace(desired=com.desired.at[:2].set(horizontal * scale))
    return terms


def hierarchy_stage(ctrl: WBLC, snap: RobotSnapshot, terms: dict, cam_weight) -> HierarchyResult:
    """Stage 2: the hierarchy (Eq. 9-10) over ``config.hierarchy``'s levels.

    It is linear in the commands: it is solved for the tasks' commands (column 0) and for
    unit changes of the CAM command (columns 1-3, scaled by the CAM reference's
    ``cam_weight``), so the CAM command can be set after the force QP without a second
    pass."""
    cfg, dtype = ctrl.config, snap.data.qvel.dtype
    jacs, cmds = [], []

    def command(n):
        return jnp.concatenate(
            [
                (terms[n].desired - terms[n].jdot_qdot)[:, None],
                cam_weight * jnp.eye(3, dtype=dtype)
                if n == cfg.cam_task
                else jnp.zeros((terms[n].desired.shape[0], 3), dtype),
            ],
            axis=1,
        )

    for level in cfg.hierarchy:
        blocks = level_blocks(level)
        # Alternatives add: each task's rows are already scaled by its weight, so the sum
        # is the task that is on, in one block of rows instead of one per task.
        jacs.append(
            jnp.concatenate([sum(terms[n].jacobian for n in block) for block in blocks], axis=0)
        )
        cmds.append(jnp.concatenate([sum(command(n) for n in block) for block in blocks]))
    return prioritized_accelerations(
        jacs,
        cmds,
        snap.mass_cholesky,
        cfg.pinv_rtol,
        cfg.whiten_tasks,
        cfg.hierarchy_inverse,
        snap.mass_cholesky_inverse,
    )


def force_stage(
    ctrl: WBLC, snap: RobotSnapshot, terms: dict, hier: HierarchyResult, contact, previous
) -> ForceStage:
    """Stage 3: the reaction forces (Eq. 14), the linear CoM behaviour hard and the CAM
    soft, warm-started from ``previous``.

    The angular target is the CAM rate the hierarchy's motion implies. Where the CAM task
    is free in the hierarchy (H1, walking), that is its PD command, the paper's choice;
    where tasks above it fix the CAM (H2's body and partial posture take every free dof), it
    is the rate those tasks need, and forces aiming elsewhere would leave the floating-base
    rows of Eq. 17 unmet. Eq. 15: the CAM task then follows what the forces can do;
    shifting its command by the shortfall gives the paper's command (the achieved rate)
    where the CAM is free."""
    cfg, d, dtype = ctrl.config, snap.data, snap.data.qvel.dtype
    cam_rate = snap.centroidal_matrix[:3] @ hier.qdd[:, 0] + snap.centroidal_bias[:3]
    qp = cfg.force_qp
    f_lin = snap.total_mass * (terms[cfg.com_task].desired - ctrl.mx.opt.gravity)
    points = d.site_xpos[jnp.asarray(ctrl.point_sites)]
    weight = contact[jnp.asarray(ctrl.foot_of_point)]
    fz_max = qp.fz_min + weight * (qp.fz_max - qp.fz_min)
    torques = None
    if cfg.torque_limits_in_qp:
        torques = torque_rows(ctrl, snap, hier, cam_rate, points, weight > 0)
    sol = force_qp.solve_contact_forces(
        points,
        weight > 0,
        snap.com,
        f_lin,
        cam_rate,
        qp,
        fz_max=fz_max,
        warm_start=previous,
        torques=torques,
    )
    shift = jnp.concatenate([jnp.ones(1, dtype), sol.angular - cam_rate])
    return ForceStage(sol, shift)


def torque_rows(
    ctrl: WBLC, snap: RobotSnapshot, hier: HierarchyResult, cam_rate, points, in_contact
) -> force_qp.TorqueRows:
    """The rows of Eq. 11 of the joints that carry a foot (``foot_actuators``; the forces
    reach no other torque but through the CAM command), limited by their effort limits,
    and of the floating base's rotation, as equalities: an affine map of the contact
    forces (N m).

    With the hierarchy's accelerations ``qdd = Q [1; W_ang f - cam_rate]`` (Eq. 15 sets
    the CAM command to the rate the forces achieve), the joint torques are ``A qdd + b + g
    - J_r' f``: ``offset = (A (Q_0 - Q_cam cam_rate) + b + g)_act`` and ``matrix = (J_r' - A
    Q_cam W_ang)_act``. The null-space term ``qdd_res`` of Eq. 12 is left out (it is
    chosen after the forces, and the walking hierarchy leaves it almost no room)."""
    d = snap.data
    moment = force_qp.moment_map(points, in_contact, snap.com)  # (3, 3n)
    rows = np.asarray(ctrl.foot_actuators)
    dofs = np.asarray(ctrl.actuated_dofs)[rows]
    # The floating base's rotational rows are equalities (limit 0): forces whose moment
    # strayed from the hierarchy's would leave Eq. 17's base rows unmet. Its translational
    # rows are the net force, already the QP's hard equality (with the CoM task's command:
    # written twice, the two differ by what the hierarchy leaves of that command).
    base = np.asarray(ctrl.base_rotation_dofs, int)
    every = np.concatenate([dofs, base])
    # Only these rows of A are needed: selected before the products, not after.
    mass = snap.mass_matrix[every]
    q_cam = hier.qdd[:, 1:4]
    bias = (snap.coriolis + snap.gravity)[every]
    offset = mass @ (hier.qdd[:, 0] - q_cam @ cam_rate) + bias
    jac_t = contact_jacobian(ctrl, d, points).T[every]  # (rows, 3n)
    matrix = jac_t - (mass @ q_cam) @ moment
    limits = jnp.concatenate([ctrl.torque_limits[rows], jnp.zeros(len(base), offset.dtype)])
    return force_qp.TorqueRows(matrix, offset, limits)


def contact_jacobian(ctrl: WBLC, d, points):
    """``J_r`` (3n, nv) of the contact points, rows coordinate-major (all ``x``, all
    ``y``, all ``z``), as the force QP orders its variables."""
    bodies = list(ctrl.point_bodies)
    spatial = {b: jac.frame_jacobian_spatial(ctrl.mx, d, b) for b in sorted(set(bodies))}
    rows = [spatial[b][3:] + jnp.cross(spatial[b][:3].T, points[k]).T for k, b in enumerate(bodies)]
    per_point = jnp.stack(rows)  # (n, 3, nv)
    return jnp.transpose(per_point, (1, 0, 2)).reshape(-1, per_point.shape[-1])


def torque_stage(
    ctrl: WBLC, snap: RobotSnapshot, hier: HierarchyResult, qdd_task, forces
) -> TorqueSolution:
    """Stage 4: torques by Eq. 16-19 for the task accelerations ``qdd_task`` and the
    (points, 3) reaction forces ``forces``."""
    tau_task = (
        snap.mass_matrix @ qdd_task
        + snap.coriolis
        + snap.gravity
        - contact_generalized_force(ctrl, snap.data, forces)
    )
    return torque_solution(
        ctrl, hier.mass_times_null_space(), tau_task, ctrl.config.torque_pinv_rtol
    )


def limit_stage(ctrl: WBLC, snap: RobotSnapshot, terms: dict, torques) -> TorqueLimitSolution:
    """Stage 5: with ``whole_body_limits``, every torque within its effort limit, the
    contact tasks' rows (the feet in contact) held (:func:`limit_torques`); without it,
    the torques unchanged."""
    cfg = ctrl.config
    if not cfg.whole_body_limits:
        zero = jnp.zeros_like(torques)
        return TorqueLimitSolution(
            torques=torques,
            torque_change=zero,
            acceleration_change=jnp.zeros_like(snap.data.qvel),
            held_residual=jnp.zeros((), torques.dtype),
            active=jnp.zeros((), bool),
        )
    held = [terms[t.name].jacobian for t in cfg.tasks if t.kind == "contact" and t.name in terms]
    nv = snap.data.qvel.shape[0]
    held = jnp.concatenate(held, axis=0) if held else jnp.zeros((0, nv), torques.dtype)
    return limit_torques(
        torques,
        ctrl.torque_limits,
        ctrl.selection,
        snap.mass_cholesky_inverse,
        held,
        cfg.torque_limit_stage,
    )


def torque_solution(ctrl: WBLC, a_null, tau_task, rtol: float) -> TorqueSolution:
    """Eq. 19: the minimum-norm least-squares ``[tau; qdd_res]`` of
    ``[U', -A N] [tau; qdd_res] = tau_task``.

    Every actuated dof's row can be met by its own actuator, so only the unactuated rows
    (the floating base) can be left unmet, and the problem is a least-norm one in
    ``qdd_res`` alone: with ``tau = (tau_task + A N qdd_res)_act / gear``, minimise
    ``|tau|^2 + |qdd_res|^2`` subject to the base rows in the least-squares sense. That is
    one Cholesky factorisation of ``H = I + E'E`` (eigenvalues >= 1) and a thresholded
    pseudo-inverse of the (base x base) ``K = C H^-1 C'``, the same answer as the
    pseudo-inverse of the whole ``(nv, nu + nv)`` system ``M`` for far less work. ``K`` is
    the Schur complement of ``M M'`` on the base rows; ``rtol`` is relative to the size of
    ``M M'``, as for the whole system's pseudo-inverse.
    """
    dofs = jnp.asarray(ctrl.actuated_dofs)
    gear = ctrl.selection[jnp.arange(len(ctrl.actuated_dofs)), dofs]
    coupling = a_null[dofs] / gear[:, None]  # E: torques per unit of qdd_res
    offset = tau_task[dofs] / gear  # h: torques at qdd_res = 0
    nv = a_null.shape[0]
    hessian = jnp.eye(nv, dtype=a_null.dtype) + coupling.T @ coupling
    factor = jax.scipy.linalg.cho_factor(hessian, lower=True)
    gradient = -coupling.T @ offset
    if ctrl.unactuated_dofs:
        base = jnp.asarray(ctrl.unactuated_dofs)
        constraint, target = -a_null[base], tau_task[base]  # C qdd_res = d
        solved = jax.scipy.linalg.cho_solve(
            factor, jnp.concatenate([gradient[:, None], constraint.T], axis=1)
        )
        free, h_inv_ct = solved[:, 0], solved[:, 1:]
        schur = constraint @ h_inv_ct
        # K is the Schur complement of the whole system's M M' on the base rows, so its
        # rank is judged against the size of M M' (as a pseudo-inverse of the whole
        # system would): max gear^2 + |A N|_2^2, bounded by |A N|_F^2 (within a factor of
        # the rank; no product of A N with itself). Relative to K's own largest
        # eigenvalue, round-off directions of a nearly unreachable base were inverted
        # into torques of 1e5 N m.
        scale = jnp.max(gear * gear) + jnp.sum(jnp.square(a_null))
        multiplier = pinv_psd(schur, rtol, scale) @ (constraint @ free - target)
        qdd_res = free - h_inv_ct @ multiplier
        base_residual = constraint @ qdd_res - target
    else:
        qdd_res = jax.scipy.linalg.cho_solve(factor, gradient)
        base_residual = jnp.zeros((0,), a_null.dtype)
    torques = offset + coupling @ qdd_res
    return TorqueSolution(torques, qdd_res, base_residual)


def contact_generalized_force(ctrl: WBLC, d, forces):
    """``J_r' F_r`` (nv,) for (points, 3) world forces at the contact points.

    Summed per body as a wrench at the world origin, ``[sum p x f; sum f]``, mapped by the
    body's spatial Jacobian: one ``(6, nv)`` product per foot instead of a point Jacobian
    per contact point.
    """
    points = d.site_xpos[jnp.asarray(ctrl.point_sites)]
    bodies = list(ctrl.point_bodies)
    total = jnp.zeros(d.qvel.shape, forces.dtype)
    for body in sorted(set(bodies)):
        idx = jnp.asarray([k for k, b in enumerate(bodies) if b == body])
        f, p = forces[idx], points[idx]
        wrench = jnp.concatenate([jnp.sum(jnp.cross(p, f), axis=0), jnp.sum(f, axis=0)])
        total = total + jac.frame_jacobian_spatial(ctrl.mx, d, body).T @ wrench
    return total
