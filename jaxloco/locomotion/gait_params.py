"""The walking state machine's numbers: :class:`GaitParams` (one robot's, static) and
:class:`GaitOverrides` (those that may differ from robot to robot of a batch, as traced
data), and how they scale with a robot's size."""

from __future__ import annotations

import dataclasses
import math
from typing import Optional

import jax
import jax.numpy as jnp
from flax import struct

from jaxloco import validation as v
from jaxloco.planner.scaling import FroudeScale

LEFT, RIGHT = 0, 1
"""The feet, as ``GaitState.stance`` and ``GaitParams.first_stance`` number them."""


@dataclasses.dataclass(frozen=True)
class GaitParams:
    """Numbers of the walking state machine (every field a plain number: hashable, and a
    hydra structured-config node)."""

    start_duration: float = 1.0
    """Double support before the first lift-off (s)."""
    start_lateral: float = 0.056
    """Lateral CoM offset from the first stance foot at lift-off (m, towards the other foot):
    the paper's nominal apex ``y``."""
    start_speed: float = 0.08
    """Forward CoM speed at the first lift-off (m/s)."""
    first_stance: int = RIGHT
    """0: left foot is the first stance foot, 1: right."""
    contact_blend: float = 0.03
    """Seconds over which a contact's force bound ramps in or out (authors' code: 0.03)."""
    swing_height: float = 0.1
    """Swing-foot height above the landing point at mid-swing (m; authors: 0.1)."""
    min_step_duration: float = 0.25
    """Shortest step, touch-down to touch-down (s)."""
    max_step_duration: float = 2.0
    """Clip of a step's duration, touch-down to touch-down (s)."""
    fallback_duration: float = 0.45
    """Time to touch-down of a fallback step (s): see ``fallback_dcm_offset``."""
    fallback_dcm_offset: tuple[float, float] = (0.05, 0.05)
    """When the PSP has no solution (e.g. a push leaves the CoM no forward apex), the foot
    goes to the LIPM capture point predicted at touch-down, ``x + xd / omega``, moved back
    by ``b_x`` and outwards by ``b_y`` (m, local frame), so that the CoM then diverges
    forward and back towards the old stance side, and walking resumes at the next plan."""
    max_lateral_dcm: tuple[float, float] = (0.15, 0.55)
    """Step timing adaptation: bounds on the lateral DCM ``y + yd / omega`` (stance frame,
    m) at touch-down, (inwards, past the stance foot; outwards, towards the swing side).
    The PSP times a step by the sagittal orbits, so after a lateral push it can plan a
    touch-down long after the lateral DCM has run out of reach (docs/architecture.md,
    measured choices). A step planned to land later than the LIPM's DCM reaches its bound
    lands then, on the capture step (below)."""
    max_com_lead: float = 0.18
    """Step timing adaptation, sagittal: the farthest the CoM may run ahead of the stance
    foot (stance frame, m) before touch-down. On our model the stance ankle reaches its
    dorsiflexion limit (-0.93 rad) with the CoM 0.15-0.2 m ahead (traced after 520 N
    pushes); the heel then lifts, the flat-foot contact constraint no longer holds and the
    robot pitches over. Undisturbed walking lands with the CoM 0.15-0.17 m ahead. A step
    planned to land after the LIPM's CoM passes this bound lands then, on the capture step
    (docs/locomotion.md)."""
    step_x_range: tuple[float, float] = (-0.45, 0.65)
    """Sagittal limits of a footstep in the stance frame (m): behind, ahead."""
    step_y_range: tuple[float, float] = (0.12, 0.6)
    """Kinematic limits of a footstep in the stance frame (m): every planned or fallback
    step is clipped to them (``y`` > 0 keeps the legs from crossing)."""
    touchdown_height: float = 0.005
    """A landing foot is down when its contact frame is within this height of its target
    (m). With ``max_touchdown_delay`` > 0, the gait switches stance at the planned
    touch-down only once the foot is down: a stance foot still in the air (a late landing
    after a push, or a step shortened by ``max_lateral_dcm``) would be held there by the
    contact constraint, standing on nothing."""
    max_touchdown_delay: float = 0.0
    """The longest a touch-down waits for a late foot (s); then the stance switches anyway.
    0 (the default): no wait; waiting recovered fewer pushes on the criterion sweep
    (docs/locomotion.md)."""
    late_landing_depth: float = 0.03
    """While a touch-down waits, the swing foot's height reference is this far below its
    target (m), so that the foot goes down instead of hovering over it."""
    replan: bool = True
    """Replan the step when Eq. 33's error passes ``replan_threshold`` (Section IV-C)."""
    replan_threshold: float = 0.05
    """Eq. 33's error norm that triggers replanning. Per robot it is data
    (:class:`GaitOverrides`), like ``replan_gamma``; as a trigger its
    pathwise derivative is zero almost everywhere, so tune it with smoothed gradients
    (``TuneConfig(gradient="smoothed")``)."""
    replan_delay: float = 0.02
    """How long the error must stay above the threshold (s)."""
    replan_delay_behind: Optional[float] = None  # noqa: UP045 (OmegaConf needs typing.Optional)
    """``replan_delay`` (s) for an error that puts the CoM behind its reference along the
    heading (Eq. 33's sagittal component: a push from the front, which the LIPM slows
    further); None: ``replan_delay`` in every direction."""
    replan_gamma: float = 0.2
    """Eq. 34's blend of the desired (gamma) and measured (1 - gamma) CoM state, in (0, 1).
    The paper uses 0.8, which under-reacts to a push on this model; 0.2 recovers more than
    0.5 on the limit search at both torque bounds (docs/locomotion.md).
    Per robot it is data (:class:`GaitOverrides`), so it can be traced and tuned
    by gradient."""
    max_apex_speed: float = 1.0
    """Cap on the next apex velocity the step policy asks for (m/s): sets the walking speed
    below the policy's own (the shipped policy asks for 0.37, the top of its action box).
    Per robot it is data (:class:`GaitOverrides`), so one compiled controller
    serves several speeds."""
    replan_min_remaining: float = 0.08
    """No replanning this close to the planned touch-down (s): the foot is landing."""
    replan_at_touchdown: bool = False
    """With ``replan`` on: a step whose touch-down finds Eq. 33's error above the threshold
    is planned from Eq. 34's blend, and its CoM reference starts there, instead of from the
    reference alone (a push that ends as the foot lands is otherwise seen only by the
    first replan of the next swing, ``contact_blend + replan_delay`` later)."""
    com_height: Optional[float] = 0.985  # noqa: UP045 (OmegaConf needs typing.Optional)
    """Walking CoM height above the stance foot (m): the LIPM height of the gait's CoM
    reference and of the planner at run time (``make_walking_controller`` sets ``psp.h``).
    None: the height the step policy was trained at (``psp.h``, 1.005294). Lower than the
    authors' (the measured CoM height, 1.07 at our walking keyframe) because a crouch
    reaches farther with the swing foot (docs/locomotion.md)."""
    arm_return_rate: float = 2.0
    """Rate (1/s) at which the CAM reference brings the arms back to their posture (see
    ``walking._cam_reference``): the arms serve as momentum actuators, and without it they
    wind up while steering. 0: off."""

    def __post_init__(self):
        def finite(name):
            value = getattr(self, name)
            return not (isinstance(value, float) and not math.isfinite(value))

        rules = [
            ("start_duration", self.start_duration > 0, "> 0"),
            ("start_lateral", 0 <= self.start_lateral < 0.3, "in [0, 0.3)"),
            ("start_speed", 0 < self.start_speed < 1, "in (0, 1)"),
            ("first_stance", self.first_stance in (LEFT, RIGHT), "0 (left) or 1 (right)"),
            (
                "contact_blend",
                0 < self.contact_blend < self.min_step_duration,
                "in (0, min_step_duration)",
            ),
            ("swing_height", 0 <= self.swing_height < 0.5, "in [0, 0.5)"),
            (
                "min_step_duration",
                0 < self.min_step_duration < self.max_step_duration,
                "in (0, max_step_duration)",
            ),
            (
                "fallback_duration",
                self.min_step_duration <= self.fallback_duration <= self.max_step_duration,
                "in [min_step_duration, max_step_duration]",
            ),
            (
                "fallback_dcm_offset",
                all(0 <= b < 0.3 for b in self.fallback_dcm_offset),
                "two numbers in [0, 0.3)",
            ),
            (
                "max_lateral_dcm",
                all(0 < b < 5 for b in self.max_lateral_dcm),
                "two numbers in (0, 5)",
            ),
            ("max_com_lead", 0 < self.max_com_lead < 5, "in (0, 5)"),
            ("touchdown_height", 0 < self.touchdown_height < 0.1, "in (0, 0.1)"),
            ("max_touchdown_delay", 0 <= self.max_touchdown_delay < 1, "in [0, 1)"),
            ("late_landing_depth", 0 <= self.late_landing_depth < 0.2, "in [0, 0.2)"),
            (
                "step_x_range",
                self.step_x_range[0] < 0 < self.step_x_range[1],
                "(low < 0 < high): stepping back and forth must both be possible",
            ),
            ("step_y_range", 0 < self.step_y_range[0] < self.step_y_range[1], "(0 < low < high)"),
            *v.positive(self, "max_apex_speed", "replan_threshold"),
            *v.non_negative(self, "replan_delay", "replan_min_remaining"),
            (
                "replan_delay_behind",
                self.replan_delay_behind is None or self.replan_delay_behind >= 0,
                "None or >= 0",
            ),
            *v.unit_interval(self, "replan_gamma"),
            ("arm_return_rate", 0 <= self.arm_return_rate < 100, "in [0, 100)"),
            (
                "com_height",
                self.com_height is None or 0.1 <= self.com_height <= 3.0,
                "in [0.1, 3] m (or None)",
            ),
        ]
        v.check_fields(self, [(n, ok and finite(n), rule) for n, ok, rule in rules])

    def scaled(self, scale: FroudeScale) -> GaitParams:
        """These numbers for a robot ``scale`` times the size they were chosen for (Froude
        scaling: lengths by ``L``, times and velocities by ``sqrt(L)``, rates by
        ``1 / sqrt(L)``); the identity for ``L = 1``. Switches, ``replan_gamma`` and the
        first stance foot are dimensionless and stay."""
        if scale.length == 1.0:
            return self
        factors = {
            **dict.fromkeys(_GAIT_LENGTHS, scale.length),
            **dict.fromkeys(_GAIT_TIMES, scale.time),
            **dict.fromkeys(_GAIT_VELOCITIES, scale.velocity),
            "arm_return_rate": 1.0 / scale.time,
        }
        changes = {}
        for name, f in factors.items():
            value = getattr(self, name)
            if value is None:
                continue
            changes[name] = tuple(x * f for x in value) if isinstance(value, tuple) else value * f
        return dataclasses.replace(self, **changes)


_GAIT_LENGTHS = (
    "start_lateral",
    "swing_height",
    "fallback_dcm_offset",
    "max_lateral_dcm",
    "max_com_lead",
    "step_x_range",
    "step_y_range",
    "touchdown_height",
    "late_landing_depth",
    "replan_threshold",
    "com_height",
)
_GAIT_TIMES = (
    "start_duration",
    "contact_blend",
    "min_step_duration",
    "max_step_duration",
    "fallback_duration",
    "max_touchdown_delay",
    "replan_delay",
    "replan_delay_behind",
    "replan_min_remaining",
)
_GAIT_VELOCITIES = ("start_speed", "max_apex_speed")


@struct.dataclass
class GaitOverrides:
    """Gait numbers that may differ from robot to robot of a batch, as traced data: one
    compiled controller serves a batch with replanning on for some robots and off for
    others, several walking speeds, or replan numbers under tuning (gradients go through
    them). Each defaults to its :class:`GaitParams` field (:meth:`of`)."""

    replan: jax.Array
    """() bool: whether Eq. 33-34 replanning is on (``GaitParams.replan``)."""
    apex_speed: jax.Array
    """() cap on the policy's next-apex velocity (m/s; ``GaitParams.max_apex_speed``)."""
    replan_gamma: jax.Array
    """() Eq. 34's blend, in [0, 1] (``GaitParams.replan_gamma``)."""
    replan_threshold: jax.Array
    """() Eq. 33's trigger, > 0 (``GaitParams.replan_threshold``)."""

    @classmethod
    def of(
        cls,
        params: GaitParams,
        dtype=None,
        replan=None,
        apex_speed=None,
        replan_gamma=None,
        replan_threshold=None,
    ) -> GaitOverrides:
        """``params``' values, with those given here in their place."""
        dtype = dtype or jnp.zeros(()).dtype

        def pick(given, default):
            return jnp.asarray(default if given is None else given, dtype)

        return cls(
            replan=jnp.asarray(params.replan if replan is None else replan, bool),
            apex_speed=pick(apex_speed, params.max_apex_speed),
            replan_gamma=pick(replan_gamma, params.replan_gamma),
            replan_threshold=pick(replan_threshold, params.replan_threshold),
        )
