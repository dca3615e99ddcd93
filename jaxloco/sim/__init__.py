"""Simulation backends that close the loop around the jitted controllers."""

from jaxloco.sim.mujoco_c import ClosedLoopLog, PackedController, run_closed_loop

__all__ = ["ClosedLoopLog", "PackedController", "run_closed_loop"]
