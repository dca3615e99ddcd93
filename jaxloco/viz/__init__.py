"""Figures (matplotlib Figure objects, no pyplot state)."""

from jaxloco.viz.planner import draw_footsteps, plot_phase_portraits, plot_walk

__all__ = ["draw_footsteps", "plot_phase_portraits", "plot_walk"]
