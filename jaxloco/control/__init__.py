"""The whole-body locomotion controller (paper Section III): tasks, the prioritised
hierarchy, the contact-force QP, torques, and the Valkyrie presets."""

from jaxloco.control.force_qp import ForceQPParams, ForceQPSolution, solve_contact_forces
from jaxloco.control.gains import apply_gains_file, load_gains, save_gains, with_gains
from jaxloco.control.hierarchy import HierarchyResult, prioritized_accelerations
from jaxloco.control.pinv import pinv_psd
from jaxloco.control.presets import body_shaking_config, walking_config, wblc_config
from jaxloco.control.segments import Segments
from jaxloco.control.shaking import ShakingParams, shaking_reference
from jaxloco.control.tasks import RobotSnapshot, TaskReference, TaskSpec, snapshot
from jaxloco.control.wblc import (
    WBLC,
    FootSpec,
    WBLCConfig,
    WBLCDiagnostics,
    WBLCOutput,
    make_wblc,
    torque_solution,
)

__all__ = [
    "WBLC",
    "FootSpec",
    "ForceQPParams",
    "ForceQPSolution",
    "HierarchyResult",
    "RobotSnapshot",
    "Segments",
    "ShakingParams",
    "TaskReference",
    "TaskSpec",
    "WBLCConfig",
    "WBLCDiagnostics",
    "WBLCOutput",
    "apply_gains_file",
    "body_shaking_config",
    "load_gains",
    "make_wblc",
    "pinv_psd",
    "prioritized_accelerations",
    "save_gains",
    "shaking_reference",
    "snapshot",
    "solve_contact_forces",
    "torque_solution",
    "walking_config",
    "wblc_config",
    "with_gains",
]
