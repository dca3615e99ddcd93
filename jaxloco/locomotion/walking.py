"""The walking controller: gait state machine + learned step planner + WBLC, one tick.

:func:`make_walking_controller` binds a model, a WBLC configuration (the walking hierarchy
of Section V-B by default), :class:`~jaxloco.locomotion.gait_params.GaitParams` and a step policy
(the shipped default, ``load_planner()``). The result's ``step(t, qpos, qvel, state)`` is pure
and jittable, and ``jax.vmap`` batches it over robots: the same function drives MuJoCo's C
engine (:mod:`jaxloco.sim.mujoco_c`) and MJX rollouts (:mod:`jaxloco.sim.mjx_loop`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from jaxloco.control.force_qp import ForceQPState
from jaxloco.control.presets import foot_task, walking_config
from jaxloco.control.tasks import TaskReference
from jaxloco.control.wblc import WBLC, WBLCConfig, make_wblc
from jaxloco.dynamics.engine_terms import EngineTerms
from jaxloco.dynamics.quiet_mjx import mjx
from jaxloco.learning.loading import load_planner
from jaxloco.learning.scaled import ScaledPlanner, planner_at_height
from jaxloco.locomotion import gait as gait_lib
from jaxloco.locomotion.gait import GaitState
from jaxloco.locomotion.gait_params import GaitOverrides, GaitParams
from jaxloco.locomotion.walking_log import WalkingLog
from jaxloco.planner.protocol import Planner
from jaxloco.robots import DEFAULT_ROBOT, RobotDescription, check_model, robot_scale

ARM_TASK = "arms"
"""The joint-posture task of the arms (the walking hierarchy's last level)."""


@struct.dataclass
class WalkingState:
    """The walking controller's state between ticks."""

    gait: GaitState
    """The gait state machine's state (footsteps, timing, plans)."""
    qp: ForceQPState
    """The force QP's warm start (its last ADMM iterate)."""


@struct.dataclass
class WalkingController:
    """Build with :func:`make_walking_controller`.

    A pytree: the WBLC (its MJX model and arrays), the step policy's weights and the
    posture references are leaves; the gait's numbers, the foot sites and the robot's
    description static. So ``jax.jit(WalkingController.step)(ctrl, t, qpos, qvel, state)``
    takes the controller as an argument, and controllers that differ only in numbers
    stack and ``vmap``. Compared by identity."""

    wblc: WBLC
    """The whole-body controller (the walking hierarchy)."""
    gait_params: GaitParams = struct.field(pytree_node=False)
    """The gait's numbers at the robot's size."""
    planner: Planner
    """The step policy (any :class:`~jaxloco.planner.protocol.Planner`), at the robot's size."""
    posture: dict[str, TaskReference]
    """Hold references of every task by name (the keyframe the robot starts in); the
    gait overwrites the CoM, body, CAM and swing-foot ones every tick."""
    foot_sites: tuple[int, int] = struct.field(pytree_node=False)
    """Site ids of the (left, right) contact frames."""
    robot: RobotDescription = struct.field(pytree_node=False)
    """The robot whose model this controller is for."""

    # Identity, as for WBLC: jit keys bound methods on their object.
    __eq__ = object.__eq__
    __hash__ = object.__hash__

    @property
    def psp(self):
        return self.planner.psp

    def init(
        self,
        qpos,
        qvel=None,
        heading=0.0,
        turns=None,
        num_turns: int = 1,
        overrides: GaitOverrides | None = None,
        engine: EngineTerms | None = None,
    ) -> WalkingState:
        """The controller's state for a robot standing at ``qpos``; ``overrides``: this
        robot's per-robot gait numbers (default: ``GaitOverrides.of(gait_params)``);
        ``engine``: MuJoCo C's terms of this state, read instead of computing them
        (:mod:`~jaxloco.dynamics.engine_terms`).

        Jit it at the call site (``jax.jit(WalkingController.init,
        static_argnames="num_turns")(ctrl, qpos, ...)``): op by op, MJX's kinematics behind
        it take tens of seconds."""
        qpos = jnp.asarray(qpos)
        qvel = jnp.zeros(self.wblc.mx.nv, qpos.dtype) if qvel is None else jnp.asarray(qvel)
        snap = self.wblc.snapshot(qpos, qvel, engine)
        feet = snap.data.site_xpos[jnp.asarray(self.foot_sites)]
        g = gait_lib.init_gait(
            self.gait_params,
            self.psp,
            snap.com,
            feet,
            heading,
            turns,
            num_turns,
            overrides,
        )
        return WalkingState(g, self.wblc.initial_qp_state(qpos.dtype))

    def step(
        self,
        t,
        qpos,
        qvel,
        state: WalkingState,
        gains=None,
        engine: EngineTerms | mjx.Data | None = None,
    ) -> tuple[jax.Array, WalkingState, WalkingLog]:
        """One control tick: ``(torques, new state, log)``, the log a :class:`WalkingLog`.

        ``engine``: what the simulator computed for this same state (``qpos``, ``qvel``),
        read instead of computing it again (:meth:`WBLC.snapshot
        <jaxloco.control.wblc.WBLC.snapshot>`): the same torques to float round-off, a
        smaller program and a shorter tick."""
        wblc, params, psp = self.wblc, self.gait_params, self.psp
        with jax.named_scope("wblc.snapshot"):
            snap = wblc.snapshot(qpos, qvel, engine)
        dtype = snap.data.qvel.dtype
        t = jnp.asarray(t, dtype)
        feet = snap.data.site_xpos[jnp.asarray(self.foot_sites)]
        dt = jnp.asarray(wblc.mx.opt.timestep, dtype)
        with jax.named_scope("gait"):  # the state machine, the step planner, the references
            g = gait_lib.advance(
                state.gait, params, psp, self.planner.policy, t, snap.com, snap.com_vel, feet, dt
            )
            r = gait_lib.references(g, params, psp, t, snap.com, snap.com_vel)
        refs = dict(self.posture)
        refs["com"] = refs["com"].replace(pos=r.com.pos, vel=r.com.vel, acc=r.com.acc)
        body = gait_lib.yaw_reference(r.body_yaw)
        for name in ("pelvis_ori", "body_ori"):
            refs[name] = refs[name].replace(pos=body.pos, vel=body.vel, acc=body.acc)
        refs[wblc.config.cam_task] = _cam_reference(self, snap, qpos, body)
        swing_ori = gait_lib.yaw_reference(r.swing_yaw)
        for k in range(2):
            on = r.swinging[k]
            pos_task, ori_task = foot_task(k, "foot_pos"), foot_task(k, "foot_ori")
            refs[pos_task] = refs[pos_task].replace(
                pos=r.swing.pos, vel=r.swing.vel, acc=r.swing.acc, weight=on
            )
            refs[ori_task] = refs[ori_task].replace(
                pos=swing_ori.pos, vel=swing_ori.vel, acc=swing_ori.acc, weight=on
            )
        out = wblc(qpos, qvel, refs, r.contact, gains=gains, previous=state.qp, snap=snap)
        log = WalkingLog.of(snap.com, snap.com_vel, feet, g, r, out)
        return out.torques, WalkingState(g, out.qp_state), log


def _cam_reference(ctrl: WalkingController, snap, qpos, body_yaw):
    """The CAM task's reference while walking: the angular momentum of the whole body
    turning at the commanded yaw rate, plus that of the arms moving back to their posture
    at ``arm_return_rate``.

    The CAM task sits above the arm posture, so the arms carry whatever momentum the rest
    of the body does not. With a zero reference they cancel the body's own turn, far past
    the shoulders' effort limits (docs/architecture.md, measured choices); with the turn
    alone they still wind up, turn after turn, until past their joint limits. Walking
    straight the turn term is zero.
    """
    mx, cfg = ctrl.wblc.mx, ctrl.wblc.config
    a_ang = snap.centroidal_matrix[:3]
    base_body, base_dof = int(mx.jnt_bodyid[0]), int(mx.jnt_dofadr[0])
    world_z_in_base = snap.data.xmat[base_body][2]  # free-joint angular velocity is local
    k_per_yaw_rate = a_ang[:, base_dof + 3 : base_dof + 6] @ world_z_in_base
    ref = ctrl.posture[cfg.cam_task]
    pos = k_per_yaw_rate * body_yaw.vel[2]
    rate = ctrl.gait_params.arm_return_rate
    if ARM_TASK in ctrl.wblc.indices and ARM_TASK in ctrl.posture and rate > 0:
        arms = ctrl.wblc.indices[ARM_TASK]
        qd_back = rate * (ctrl.posture[ARM_TASK].pos - qpos[jnp.asarray(arms.qpos)])
        pos = pos + a_ang[:, jnp.asarray(arms.dof)] @ qd_back
    return ref.replace(pos=pos, acc=k_per_yaw_rate * body_yaw.acc[2])


def robot_gait(
    robot: RobotDescription, model: mujoco.MjModel, gait: GaitParams | None = None
) -> GaitParams:
    """``gait`` (default ``GaitParams()``: numbers for the reference robot) scaled to
    ``robot``'s size (:func:`~jaxloco.robots.robot_scale`); unchanged for the reference."""
    return (GaitParams() if gait is None else gait).scaled(robot_scale(robot, model))


def robot_planner(robot: RobotDescription, model: mujoco.MjModel, planner=None):
    """``planner`` for ``robot``'s size (default: the robot's shipped policy,
    ``robot.planner``): a planner learned at the reference robot's size is wrapped in a
    :class:`~jaxloco.learning.scaled.ScaledPlanner` unless the robot is the reference size;
    a scaled one is taken as it is."""
    planner = load_planner(shipped=robot.planner) if planner is None else planner
    scale = robot_scale(robot, model)
    if scale.length == 1.0 or isinstance(planner, ScaledPlanner):  # already at a size
        return planner
    return ScaledPlanner(planner, scale)


def make_walking_controller(
    model: mujoco.MjModel,
    config: WBLCConfig | None = None,
    gait: GaitParams | None = None,
    planner: Planner | None = None,
    keyframe_qpos=None,
    robot: RobotDescription = DEFAULT_ROBOT,
) -> WalkingController:
    """A walking controller for ``model``, a model of ``robot``: WBLC ``config`` (default:
    the robot's walking hierarchy), gait numbers (default: :func:`robot_gait`) and the step
    ``planner`` (default: :func:`robot_planner`, ``load_planner()``'s Algorithm 1 RL-PSP
    policy with the refined one as its fallback, scaled to the robot's size; any
    :class:`~jaxloco.planner.protocol.Planner`). ``keyframe_qpos`` sets the joint postures the
    posture tasks hold (default: the robot's keyframe). The planner walks at
    ``gait.com_height`` (its ``psp.h`` is replaced unless that is None)."""
    check_model(robot, model)
    config = walking_config(robot) if config is None else config
    gait = robot_gait(robot, model) if gait is None else gait
    planner = robot_planner(robot, model) if planner is None else planner
    if gait.com_height is not None:
        # The policy's apex states and actions are in metres and m/s; only the LIPM's
        # omega changes with the height, and the PSP plans with it at run time.
        planner = planner_at_height(planner, gait.com_height)
    wblc = make_wblc(model, config)
    qpos0 = robot.keyframe_qpos(model) if keyframe_qpos is None else np.asarray(keyframe_qpos)
    # From MuJoCo C's kinematics: MJX's, run op by op, is hundreds of small compiles, each
    # too small for the persistent cache.
    posture = wblc.hold_references_at(model, qpos0)
    return WalkingController(
        wblc=wblc,
        gait_params=gait,
        planner=planner,
        posture=posture,
        foot_sites=robot.foot_sites(model),
        robot=robot,
    )
