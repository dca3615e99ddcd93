"""The whole-body locomotion controller (paper Section III): tasks, the prioritised
hierarchy, the contact-force QP, torques, and the presets built from a robot description."""

from jaxloco.control.force_qp import ForceQPParams, ForceQPSolution, solve_contact_forces
from jaxloco.control.gains import apply_gains_file, load_gains, save_gains, with_gains
from jaxloco.control.hierarchy import HierarchyResult, prioritized_accelerations
from jaxloco.control.pinv import pinv_psd
from jaxloco.control.presets import body_shaking_config, walking_config, wblc_config
from jaxloco.control.segments import Segments
from jaxloco.control.shaking import ShakingParams, shaking_reference
from jaxloco.control.tasks import PDGains, RobotSnapshot, TaskReference, TaskSpec, snapshot
from jaxloco.control.wblc import (
    WBLC,
    FootSpec,
    ForceStage,
    TorqueSolution,
    WBLCConfig,
    WBLCDiagnostics,
    WBLCOutput,
    force_stage,
    hierarchy_stage,
    make_wblc,
    task_stage,
    torque_solution,
    torque_stage,
    wblc_tick,
)

__all__ = [
    "PDGains",
    "WBLC",
    "FootSpec",
    "ForceQPParams",
    "ForceQPSolution",
    "ForceStage",
    "HierarchyResult",
    "RobotSnapshot",
    "Segments",
    "ShakingParams",
    "TaskReference",
    "TaskSpec",
    "TorqueSolution",
    "WBLCConfig",
    "WBLCDiagnostics",
    "WBLCOutput",
    "apply_gains_file",
    "body_shaking_config",
    "force_stage",
    "hierarchy_stage",
    "load_gains",
    "make_wblc",
    "pinv_psd",
    "prioritized_accelerations",
    "save_gains",
    "shaking_reference",
    "snapshot",
    "solve_contact_forces",
    "task_stage",
    "torque_solution",
    "torque_stage",
    "walking_config",
    "wblc_config",
    "wblc_tick",
    "with_gains",
]
