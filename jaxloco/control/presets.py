"""WBLC configurations for the Valkyrie model: the paper's task sets as data.

- :func:`walking_config`: the walking hierarchy of Section V-B (CoM -> pelvis -> body ->
  swing-foot orientation -> swing-foot position -> neck and torso posture -> CAM -> arms).
- :func:`body_shaking_config`: Section V-A's six tasks with Eq. 32's ``H1`` or ``H2``.
- :func:`standing_config`: the walking task set in double support.

Each starts with the contact constraint (see :mod:`jaxloco.control.wblc`). CoM gains are
the authors' (from their code); the rest are ours, chosen so the
robot stands and shakes stably at 1 kHz (the paper gives none).
"""

from __future__ import annotations

from jaxloco.control.force_qp import ForceQPParams
from jaxloco.control.tasks import TaskSpec
from jaxloco.control.wblc import FootSpec, WBLCConfig
from jaxloco.dynamics.model import (
    ARM_JOINTS,
    CONTACT_SITES,
    COP_SITES,
    FEET,
    NECK_JOINTS,
    TORSO_JOINTS,
    VALKYRIE_JOINTS,
)

VALKYRIE_FEET = tuple(FootSpec(COP_SITES[side], CONTACT_SITES[side]) for side in FEET)
ARMS = tuple(f"{side}_{j}" for side in FEET for j in ARM_JOINTS)
NECK_TORSO = (*TORSO_JOINTS, *NECK_JOINTS)
# Eq. 32's partial posture: every joint except shoulder pitch, shoulder roll and knee.
PARTIAL_POSTURE = tuple(
    j for j in VALKYRIE_JOINTS if not j.endswith(("shoulderPitch", "shoulderRoll", "knee"))
)


def valkyrie_tasks() -> tuple[TaskSpec, ...]:
    """Every task the presets use, with default gains."""
    contact = tuple(
        TaskSpec(f"{side}_contact", "contact", frame=COP_SITES[side], kd=(10.0,)) for side in FEET
    )
    feet = tuple(
        spec
        for side in FEET
        for spec in (
            TaskSpec(f"{side}_foot_ori", "orientation", COP_SITES[side], kp=(200.0,), kd=(30.0,)),
            TaskSpec(f"{side}_foot_pos", "position", COP_SITES[side], kp=(400.0,), kd=(40.0,)),
        )
    )
    return (
        *contact,
        TaskSpec("com", "com", kp=(50.0, 50.0, 220.0), kd=(15.0, 15.0, 10.0)),
        TaskSpec("cam", "cam", kp=(5.0,)),
        TaskSpec("pelvis_ori", "orientation", "pelvis", kp=(100.0,), kd=(20.0,)),
        TaskSpec("body_ori", "orientation", "torso", kp=(100.0,), kd=(20.0,)),
        *feet,
        TaskSpec("neck_torso", "joints", joints=NECK_TORSO, kp=(100.0,), kd=(20.0,)),
        TaskSpec("arms", "joints", joints=ARMS, kp=(100.0,), kd=(20.0,)),
        TaskSpec("partial_posture", "joints", joints=PARTIAL_POSTURE, kp=(100.0,), kd=(20.0,)),
        TaskSpec("full_posture", "joints", joints=VALKYRIE_JOINTS, kp=(100.0,), kd=(20.0,)),
    )


CONTACT = "left_contact+right_contact"
WALKING = (
    CONTACT,
    "com",
    "pelvis_ori",
    "body_ori",
    "left_foot_ori+right_foot_ori",
    "left_foot_pos+right_foot_pos",
    "neck_torso",
    "cam",
    "arms",
)
H1 = (CONTACT, "com", "cam", "body_ori", "partial_posture", "pelvis_ori", "full_posture")
H2 = (CONTACT, "com", "body_ori", "partial_posture", "pelvis_ori", "cam", "full_posture")
HIERARCHIES = {"walking": WALKING, "H1": H1, "H2": H2}


def wblc_config(hierarchy: str | tuple[str, ...] = "walking", **overrides) -> WBLCConfig:
    """A Valkyrie WBLC config; ``hierarchy`` is a preset name or a tuple of levels."""
    if isinstance(hierarchy, str):
        if hierarchy not in HIERARCHIES:
            raise ValueError(f"hierarchy: one of {sorted(HIERARCHIES)} or a tuple of levels")
        hierarchy = HIERARCHIES[hierarchy]
    return WBLCConfig(
        tasks=valkyrie_tasks(), hierarchy=tuple(hierarchy), feet=VALKYRIE_FEET, **overrides
    )


# The walking controller's force QP runs every tick from the previous tick's solution, so
# it needs fewer iterations than a cold solve (ForceQPParams' defaults, which meet the
# accuracy target against quadprog from a cold start), and a smaller penalty suits it: warm,
# the iterate starts near the solution, and a smaller rho moves it along the active
# constraints faster. tests/test_force_qp.py bounds its error along a 1 kHz sequence of
# problems (measurements in docs/control.md).
CLOSED_LOOP_QP = ForceQPParams(iterations=150, rho=0.02)


# Damped inverses at the walking hierarchy's first and last levels, truncated between. The
# first level (the contact constraint) is not projected, so its whitened Gram matrix is the
# identity on the rows in contact: both inverses give it, to 1e-4. The last (arms) only
# shapes the null space. Those are the two largest levels (12 and 14 rows), whose
# eigendecompositions cost the most; damped at every level lost a push of a criterion
# sweep that the truncated middle levels recover (docs/control.md).
WALKING_INVERSES = ("damped",) + ("truncated",) * (len(WALKING) - 2) + ("damped",)


def walking_config(**overrides) -> WBLCConfig:
    """The walking hierarchy with the warm-started force QP settings (``CLOSED_LOOP_QP``)
    and damped inverses at its first and last levels (``WALKING_INVERSES``)."""
    overrides.setdefault("force_qp", CLOSED_LOOP_QP)
    overrides.setdefault("hierarchy_inverse", WALKING_INVERSES)
    return wblc_config("walking", **overrides)


def body_shaking_config(which: str = "H2", **overrides) -> WBLCConfig:
    if which not in ("H1", "H2"):
        raise ValueError(f"body_shaking_config: which must be 'H1' or 'H2', got {which!r}")
    return wblc_config(which, **overrides)
