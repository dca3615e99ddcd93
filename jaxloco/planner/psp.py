"""The analytic phase-space planner (PSP): one step, Algorithm 2 of the paper.

Conventions (paper Section II-A, Appendix A, and the authors' code where the text is silent):

- The *local frame* of a step has its origin at the stance foot, x along the walking
  direction and y lateral, pointing from the stance foot towards the side the next foot goes.
  (Each step the lateral axis is mirrored, so one policy serves both feet.)
- An *apex state* ``s = (y_apex, xd_apex, yd_apex)`` is the CoM state at the instant its
  sagittal position is over the stance foot (``x = 0``), where the sagittal speed is minimal.
- An *action* ``a = (p_x, xd_apex_next, yd_apex_next)``: the next foot's sagittal position
  and the CoM velocities at the next apex (over the next foot).

Given ``(s, a)`` the PSP finds where the two sagittal orbits meet (the switching state,
Eq. 44), the time to get there and from there to the next apex (Eq. 38), and the lateral
foot position that makes the lateral velocity at the next apex equal the requested one
(Eq. 45). The next apex state in the next foot's (mirrored) frame is
``s' = (-(y - p_y), xd, -yd)``.

Everything is elementwise over leading axes and safe under ``jit``, ``vmap`` and ``grad``.
Inputs for which the equations have no solution come back with ``terminal=True``, a
``reason`` bitmask (:class:`Reason`) and finite numbers in every field, never NaN.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math

import jax
import jax.numpy as jnp
from flax import struct

from jaxloco import validation as v
from jaxloco.planner import lipm

# |p_x| below this has no switching state (the two orbits are parallel).
_MIN_STEP = 1e-6
# Inputs beyond this magnitude (m, m/s) are rejected: no walking CoM state comes near it,
# and the squares in Eq. 43-44 would overflow long before float64 runs out.
_MAX_INPUT = 1e3
# sinh(w t_apex) below this: the lateral foot position is undetermined (Eq. 45, D = 0).
_MIN_SINH = 1e-9


@dataclasses.dataclass(frozen=True)
class PSPParams:
    """Parameters of the phase-space planner and of its reward and terminal conditions.

    Defaults are the paper's values (Eq. 3, Eq. 4) and, where it is silent, those its
    authors' code used (``h``, ``g``, stride bounds, terminal reward). All fields are plain
    floats, so an instance is hashable (a static argument under ``jit``) and serves directly
    as a hydra structured-config node.
    """

    g: float = 9.81
    """Gravity (m/s^2)."""
    h: float = 1.005294
    """LIPM height: CoM height above the stance foot (m)."""
    y_apex_nominal: float = 0.056
    """Lateral CoM offset from the stance foot at the nominal apex (m)."""
    xd_apex_nominal: float = 0.2
    """Nominal sagittal apex velocity (m/s): the reward's target (Eq. 3)."""
    p_y_nominal: float = 0.3
    """Nominal lateral step (m): the reward's target (Eq. 3)."""
    reward_weight_xd: float = 1.0
    """Weight of the apex-velocity error ``(xd_apex_nominal - xd_apex_next)^2`` in the reward (Eq.
    3)."""
    reward_weight_p_y: float = 15.0
    """Weight of the lateral-step error ``(p_y_nominal - p_y)^2`` (Eq. 3)."""
    reward_weight_yd: float = 1.0
    """Weight of the next apex's lateral velocity squared (Eq. 3)."""
    terminal_reward: float = -5.0
    """Reward of a transition that ends in a terminal condition."""
    t_switch_min: float = 0.12
    """Shortest time from the apex to the switch that is safe (s, Eq. 4)."""
    t_apex_min: float = 0.12
    """Shortest time from the switch to the next apex that is safe (s, Eq. 4)."""
    p_y_min: float = 0.1
    """Least safe lateral step (m, Eq. 4), exclusive."""
    p_y_max: float = 0.5
    """Safe lateral step range (m, Eq. 4), exclusive."""
    stride_min: float = 0.20
    """Shortest safe stride ``sqrt(p_x^2 + p_y^2)`` (m), inclusive."""
    stride_max: float = 0.95
    """Safe stride length ``sqrt(p_x^2 + p_y^2)`` range (m), inclusive."""
    p_x_min: float = 0.1
    """Action box: the shortest sagittal step ``p_x`` (m)."""
    p_x_max: float = 0.5
    """Action box: the longest sagittal step ``p_x`` (m)."""
    xd_apex_next_min: float = 0.03
    """Action box: the slowest next apex velocity (m/s)."""
    xd_apex_next_max: float = 0.37
    """Action box: the fastest next apex velocity (m/s)."""
    yd_apex_next_min: float = -0.25
    """Action box: the least next apex lateral velocity (m/s)."""
    yd_apex_next_max: float = 0.25
    """The action box (Eq. 2). ``plan_step`` accepts any action; policies sample and
    search inside this box (the paper bounds the sagittal step through it, not Eq. 4)."""

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise TypeError(f"PSPParams.{f.name} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"PSPParams.{f.name} must be finite, got {value!r}")
        v.check_fields(
            self,
            [
                *v.positive(self, "g"),
                ("h", self.h > 0, "> 0 (CoM height above the stance foot)"),
                *v.non_negative(self, "t_switch_min", "t_apex_min"),
                *v.positive(self, "xd_apex_nominal"),
                (
                    "p_y_min",
                    self.p_y_min < self.p_y_max,
                    f"< p_y_max = {self.p_y_max} (the lateral step range is empty)",
                ),
                *v.non_negative(self, "stride_min"),
                (
                    "stride_min",
                    self.stride_min < self.stride_max,
                    f"< stride_max = {self.stride_max} (the stride range is empty)",
                ),
                *(
                    (
                        f"{name}_min",
                        getattr(self, f"{name}_min") < getattr(self, f"{name}_max"),
                        f"< {name}_max = {getattr(self, f'{name}_max')} (empty action range)",
                    )
                    for name in ("p_x", "xd_apex_next", "yd_apex_next")
                ),
            ],
        )

    @property
    def action_low(self) -> tuple[float, float, float]:
        """Lower corner of the action box (Eq. 2)."""
        return (self.p_x_min, self.xd_apex_next_min, self.yd_apex_next_min)

    @property
    def action_high(self) -> tuple[float, float, float]:
        """Upper corner of the action box (Eq. 2)."""
        return (self.p_x_max, self.xd_apex_next_max, self.yd_apex_next_max)

    @property
    def omega(self) -> float:
        """LIPM natural frequency ``sqrt(g / h)`` (1/s)."""
        return math.sqrt(self.g / self.h)

    @property
    def nominal_state(self) -> tuple[float, float, float]:
        """The nominal apex state ``(y_apex_nominal, xd_apex_nominal, 0)``."""
        return (self.y_apex_nominal, self.xd_apex_nominal, 0.0)


class Reason(enum.IntFlag):
    """Why a step is terminal: bits of ``StepPlan.reason`` (0 = safe step)."""

    NO_SWITCH_STATE = 1
    """p_x = 0: the two sagittal orbits are parallel and never meet."""
    SWITCH_UNREACHABLE = 2
    """The switching state is not ahead on the current orbit (non-positive log argument)."""
    APEX_UNREACHABLE = 4
    """The next apex is not ahead on the next orbit (non-positive log argument)."""
    LATERAL_UNDETERMINED = 8
    """t_apex = 0: no lateral foot position sets the apex velocity (Eq. 45, D = 0)."""
    SWITCH_TOO_SOON = 16
    """t_switch <= t_switch_min (Eq. 4)."""
    APEX_TOO_SOON = 32
    """t_apex <= t_apex_min (Eq. 4)."""
    P_Y_OUT_OF_RANGE = 64
    """p_y outside (p_y_min, p_y_max) (Eq. 4)."""
    STRIDE_OUT_OF_RANGE = 128
    """sqrt(p_x^2 + p_y^2) outside [stride_min, stride_max]."""
    INVALID_INPUT = 256
    """The state or action holds NaN, inf, or a magnitude above 1e3 (m, m/s)."""
    NO_APEX = 512
    """(multi-step planning) the CoM does not cross the stance foot moving forward."""
    SWITCH_IN_PAST = 1024
    """(multi-step planning) after re-projection, the switch would precede the present."""
    STEP_SHORTENED = 2048
    """(walking gait) the touch-down was brought forward to keep the lateral DCM within
    reach (``GaitParams.max_lateral_dcm``); not terminal, the step is taken."""


# Bits meaning the equations have no solution (as opposed to an unsafe but real one).
INFEASIBLE = (
    Reason.NO_SWITCH_STATE
    | Reason.SWITCH_UNREACHABLE
    | Reason.APEX_UNREACHABLE
    | Reason.LATERAL_UNDETERMINED
    | Reason.INVALID_INPUT
    | Reason.NO_APEX
    | Reason.SWITCH_IN_PAST
)


def describe_reason(code: int) -> list[str]:
    """Names of the bits set in a ``StepPlan.reason`` value (empty for a safe step)."""
    return [r.name for r in Reason if int(code) & r.value]


@struct.dataclass
class StepValidity:
    """Per-field validity of a :class:`StepPlan`: False where the field is a placeholder."""

    x_switch: jax.Array
    """() bool, ``x_switch`` (and the sagittal switch state) is a real solution."""
    t_switch: jax.Array
    """() bool, ``t_switch`` is a real solution."""
    t_apex: jax.Array
    """() bool, ``t_apex`` is a real solution."""
    p_y: jax.Array
    """() bool, ``p_y`` (and the lateral switch state) is a real solution (Eq. 45's ``D != 0``)."""
    next_state: jax.Array
    """() bool, ``next_state`` is a real apex state."""


@struct.dataclass
class StepPlan:
    """The result of planning one step. All positions are in the current local frame.

    Times: ``t_switch`` from the planning state to the switch; ``t_apex`` from the switch to
    the next apex.
    """

    x_switch: jax.Array
    """Sagittal CoM position at the switch, from the current stance foot (m)."""
    xd_switch: jax.Array
    """Sagittal CoM velocity at the switch (m/s)."""
    y_switch: jax.Array
    """Lateral CoM position at the switch, from the current stance foot (m)."""
    yd_switch: jax.Array
    """Lateral CoM velocity at the switch (m/s)."""
    t_switch: jax.Array
    """Time from the planning state to the switch (s)."""
    t_apex: jax.Array
    """Time from the switch to the next apex (s)."""
    p_x: jax.Array
    """Sagittal position of the next stance foot, from the current one (m)."""
    p_y: jax.Array
    """Lateral position of the next stance foot, from the current one (m)."""
    next_state: jax.Array
    """Apex state in the next stance foot's (mirrored) frame, shape (..., 3)."""
    reward: jax.Array
    """The transition's reward (Eq. 3; ``terminal_reward`` when terminal)."""
    terminal: jax.Array
    """() bool, the step breaks a safety condition (Eq. 4) or has no solution."""
    reason: jax.Array
    """int32 bitmask of :class:`Reason`; 0 for a safe step."""
    valid: StepValidity
    """Which fields are real solutions rather than placeholders."""

    @property
    def stride(self) -> jax.Array:
        return jnp.sqrt(self.p_x**2 + self.p_y**2)


def plan_step(state, action, params: PSPParams = PSPParams()) -> StepPlan:
    """Plan one step from an apex state (Algorithm 2 + the LIPM transition of Fig. 4).

    Args:
      state: ``(..., 3)`` apex state ``(y_apex, xd_apex, yd_apex)`` in the stance-foot frame
        (``x_apex = 0``).
      action: ``(..., 3)`` action ``(p_x, xd_apex_next, yd_apex_next)``.
      params: :class:`PSPParams` (static under ``jit``).

    Returns:
      :class:`StepPlan`, with ``reward`` (Eq. 3, or ``terminal_reward``) and ``terminal``
      (Eq. 4, the stride bounds, or no solution; see ``reason``).
    """
    state, action = _as_float_arrays(state, 3, "state", action, 3, "action")
    return plan_apex_components(state[..., 0], state[..., 1], state[..., 2], action, params)


def plan_apex_components(y_apex, xd_apex, yd_apex, action, params: PSPParams) -> StepPlan:
    """:func:`plan_step` with the apex state given as three same-shape arrays.

    No shape checks or broadcasting: for inner loops that already hold the components.
    """
    return _plan(None, xd_apex, y_apex, yd_apex, action, params)


def plan_from_com_state(com_state, action, params: PSPParams = PSPParams()) -> StepPlan:
    """Plan one step from any CoM state, not only an apex (Eq. 44 holds for any start).

    Args:
      com_state: ``(..., 4)`` CoM state ``(x, xd, y, yd)`` relative to the stance foot, in
        the local frame. ``x`` may be non-zero (mid-step replanning, or a state projected
        into a rotated frame).
      action: ``(..., 3)`` action ``(p_x, xd_apex_next, yd_apex_next)``.
      params: :class:`PSPParams`.

    Returns:
      :class:`StepPlan` whose ``t_switch`` counts from ``com_state``.
    """
    com_state, action = _as_float_arrays(com_state, 4, "com_state", action, 3, "action")
    x0, xd0, y0, yd0 = (com_state[..., i] for i in range(4))
    return _plan(x0, xd0, y0, yd0, action, params)


def _plan(x0, xd0, y0, yd0, action, params: PSPParams) -> StepPlan:
    """The planner on components; ``x0 = None`` means an apex state (x0 = 0, folded away)."""
    p_x, v_next, yd_next = action[..., 0], action[..., 1], action[..., 2]
    comps = (xd0, y0, yd0, p_x, v_next, yd_next) + (() if x0 is None else (x0,))
    finite = functools.reduce(jnp.logical_and, [jnp.abs(c) <= _MAX_INPUT for c in comps])
    # (False for NaN and inf too.) Invalid inputs are replaced by a harmless nominal step
    # so every field stays finite; the outputs are then zeroed and flagged.
    p_x_mid = 0.5 * (params.p_x_min + params.p_x_max)
    nominal = (params.xd_apex_nominal, params.y_apex_nominal, 0.0, p_x_mid, params.xd_apex_nominal)
    xd0, y0, yd0, p_x, v_next = (
        jnp.where(finite, c, d) for c, d in zip((xd0, y0, yd0, p_x, v_next), nominal, strict=True)
    )
    yd_next = jnp.where(finite, yd_next, 0.0)
    x0 = 0.0 if x0 is None else jnp.where(finite, x0, 0.0)
    w = params.omega
    # Eq. 44: the sagittal orbits xd^2 = w^2 x^2 + E1 (current foot at 0) and
    # xd^2 = w^2 (x - p_x)^2 + v_next^2 (next foot, through its apex) intersect once.
    has_switch = (jnp.abs(p_x) > _MIN_STEP) & finite
    p_safe = jnp.where(has_switch, p_x, 1.0)
    energy = lipm.orbital_energy(x0, xd0, 0.0, w)
    x_sw = 0.5 * p_safe + (v_next**2 - energy) / (2.0 * w**2 * p_safe)
    # Speed at the switch from the next orbit (always real); its sign follows the current
    # sagittal velocity (a backwards-moving CoM then fails the time checks below).
    direction = jnp.where(xd0 >= 0.0, 1.0, -1.0)
    xd_sw, _ = lipm.orbit_velocity(x_sw, v_next**2, p_safe, w, direction)

    # Eq. 38: time to the switch on the current orbit, and from there to the next apex.
    # The log's arguments are the growth factors e^{wt}, which also give cosh and sinh
    # below without transcendental calls.
    g_sw, sw_ok = lipm.growth_between(x0, xd0, x_sw, xd_sw, 0.0, w)
    g_ap, ap_ok = lipm.growth_between(x_sw, xd_sw, p_safe, v_next, p_safe, w)
    sw_ok = sw_ok & has_switch
    ap_ok = ap_ok & has_switch
    t_sw = jnp.log(g_sw) / w
    t_ap = jnp.log(g_ap) / w

    # Eq. 35 then Eq. 45: lateral state at the switch, then the foot position p_y that
    # makes yd(t_apex) = yd_next. Written as p_y = y_sw + (yd_sw cosh - yd_next) / (w sinh).
    y_sw, yd_sw = lipm.propagate_by_growth(y0, yd0, 0.0, w, g_sw)
    inv_ap = 1.0 / g_ap
    sinh_t = 0.5 * (g_ap - inv_ap)
    cosh_t = 0.5 * (g_ap + inv_ap)
    lateral_ok = ap_ok & (jnp.abs(sinh_t) > _MIN_SINH)
    sinh_safe = jnp.where(lateral_ok, sinh_t, 1.0)
    p_y = y_sw + (yd_sw * cosh_t - yd_next) / (w * sinh_safe)
    y_ap, yd_ap = lipm.propagate_by_growth(y_sw, yd_sw, p_y, w, g_ap)
    geometry_ok = sw_ok & lateral_ok

    zero = jnp.zeros_like(x_sw)
    next_state = jnp.stack([-(y_ap - p_y), v_next, -yd_ap], axis=-1)
    next_state = jnp.where(geometry_ok[..., None], next_state, 0.0)
    p_y = jnp.where(geometry_ok, p_y, zero)
    stride = jnp.sqrt(p_x**2 + p_y**2)

    reason = (
        _bit(~has_switch, Reason.NO_SWITCH_STATE)
        | _bit(has_switch & ~sw_ok, Reason.SWITCH_UNREACHABLE)
        | _bit(has_switch & ~ap_ok, Reason.APEX_UNREACHABLE)
        | _bit(ap_ok & ~lateral_ok, Reason.LATERAL_UNDETERMINED)
        | _bit(sw_ok & (t_sw <= params.t_switch_min), Reason.SWITCH_TOO_SOON)
        | _bit(ap_ok & (t_ap <= params.t_apex_min), Reason.APEX_TOO_SOON)
        | _bit(
            geometry_ok & ((p_y <= params.p_y_min) | (p_y >= params.p_y_max)),
            Reason.P_Y_OUT_OF_RANGE,
        )
        | _bit(
            geometry_ok & ((stride < params.stride_min) | (stride > params.stride_max)),
            Reason.STRIDE_OUT_OF_RANGE,
        )
    )
    # An invalid input has one reason only (its other bits would describe the placeholder).
    reason = jnp.where(finite, reason, jnp.int32(Reason.INVALID_INPUT.value))
    terminal = reason != 0

    # Eq. 3, on the next apex (its velocities are the action's, mirrored laterally).
    reward = _eq3_reward(v_next, p_y, yd_next, params)
    reward = jnp.where(terminal, params.terminal_reward, reward)

    return StepPlan(
        x_switch=jnp.where(has_switch, x_sw, zero),
        xd_switch=jnp.where(has_switch, xd_sw, zero),
        y_switch=jnp.where(sw_ok, y_sw, zero),
        yd_switch=jnp.where(sw_ok, yd_sw, zero),
        t_switch=jnp.where(sw_ok, t_sw, zero),
        t_apex=jnp.where(ap_ok, t_ap, zero),
        p_x=jnp.where(finite, p_x, zero),
        p_y=p_y,
        next_state=next_state,
        reward=reward,
        terminal=terminal,
        reason=reason,
        valid=StepValidity(
            x_switch=has_switch,
            t_switch=sw_ok,
            t_apex=ap_ok,
            p_y=geometry_ok,
            next_state=geometry_ok,
        ),
    )


def _eq3_reward(xd_next, p_y, yd_next, params: PSPParams):
    return -(
        params.reward_weight_xd * (params.xd_apex_nominal - xd_next) ** 2
        + params.reward_weight_p_y * (params.p_y_nominal - p_y) ** 2
        + params.reward_weight_yd * yd_next**2
    )


def smooth_reward(plan: StepPlan, action, params: PSPParams = PSPParams()) -> jax.Array:
    """Eq. 3 without its terminal switch: smooth in the action, for gradient-based planning
    and learning (``plan.reward`` jumps to ``terminal_reward`` on unsafe steps)."""
    action = jnp.asarray(action)
    return _eq3_reward(action[..., 1], plan.p_y, action[..., 2], params)


SAFETY_MARGIN_NAMES = ("t_switch", "t_apex", "p_y_low", "p_y_high", "stride_low", "stride_high")


def safety_margins(plan: StepPlan, params: PSPParams = PSPParams()) -> jax.Array:
    """``(..., 6)`` signed distances inside Eq. 4's bounds and the stride bounds (s, m), in
    the order of :data:`SAFETY_MARGIN_NAMES`: all positive for a safe step. Meaningful only
    where ``plan.valid.next_state`` (elsewhere the plan's fields are placeholders)."""
    stride = plan.stride
    return jnp.stack(
        [
            plan.t_switch - params.t_switch_min,
            plan.t_apex - params.t_apex_min,
            plan.p_y - params.p_y_min,
            params.p_y_max - plan.p_y,
            stride - params.stride_min,
            params.stride_max - stride,
        ],
        axis=-1,
    )


def _bit(condition, flag: Reason):
    return jnp.where(condition, jnp.int32(flag.value), jnp.int32(0))


def _as_float_arrays(a, a_size, a_name, b, b_size, b_name):
    """Check the last axes, broadcast the leading ones, and promote ints to float."""
    a, b = jnp.asarray(a), jnp.asarray(b)
    _check_last_axis(a, a_name, a_size)
    _check_last_axis(b, b_name, b_size)
    batch = jnp.broadcast_shapes(a.shape[:-1], b.shape[:-1])
    dtype = jnp.result_type(a, b, float)  # ints -> default float; float32 stays float32
    a = jnp.broadcast_to(a, (*batch, a_size)).astype(dtype)
    b = jnp.broadcast_to(b, (*batch, b_size)).astype(dtype)
    return a, b


def _check_last_axis(x, name: str, size: int = 3) -> None:
    if x.ndim == 0 or x.shape[-1] != size:
        raise ValueError(f"{name} must have shape (..., {size}); got {tuple(x.shape)}")
