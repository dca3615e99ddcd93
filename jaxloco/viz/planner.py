"""Figures for the planner: phase portraits (Fig. 2b, 6, 11b) and footstep maps (Fig. 11a).

Functions build ``matplotlib.figure.Figure`` objects directly (no pyplot, no global backend)
and return them; save with ``fig.savefig(path)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.transforms import Affine2D

from jaxloco.planner.multistep import ComTrajectory, FootstepPlan

FOOT_COLORS = {"left": "tab:blue", "right": "tab:red"}


def _alive_segments(traj: ComTrajectory, values: np.ndarray):
    """Yield (step, phase, samples) for each phase of each alive step."""
    alive = np.asarray(traj.alive)[:, 0]
    half = values.shape[1] // 2
    for k in np.flatnonzero(alive):
        yield k, 0, values[k, :half]
        yield k, 1, values[k, half:]


def plot_phase_portraits(
    trajectories: Sequence[ComTrajectory],
    labels: Sequence[str],
    title: str = "LIPM phase portraits",
) -> Figure:
    """Fig. 2b: sagittal (x, xd) parabolas and frontal (y, yd) limit cycles, world frame.

    Each trajectory gets one colour; diamonds mark the switching states. Steps after a
    terminal one are not drawn.
    """
    fig = Figure(figsize=(11, 4.5), constrained_layout=True)
    ax_x, ax_y = fig.subplots(1, 2)
    colors = [f"C{i}" for i in range(10)]
    for i, (traj, label) in enumerate(zip(trajectories, labels, strict=True)):
        c = colors[i % len(colors)]
        state = np.concatenate([np.asarray(traj.position), np.asarray(traj.velocity)], axis=-1)
        first = True
        for _k, phase, seg in _alive_segments(traj, state):
            ax_x.plot(seg[:, 0], seg[:, 2], color=c, lw=1.4, label=label if first else None)
            ax_y.plot(seg[:, 1], seg[:, 3], color=c, lw=1.4)
            if phase == 1:  # the switching state starts phase 1
                ax_x.plot(seg[0, 0], seg[0, 2], "D", color=c, ms=4)
                ax_y.plot(seg[0, 1], seg[0, 3], "D", color=c, ms=4)
            first = False
        n_alive = int(np.asarray(traj.alive)[:, 0].sum())
        if n_alive < traj.alive.shape[0]:
            last = state[n_alive - 1, -1] if n_alive > 0 else state[0, 0]
            ax_x.plot(last[0], last[2], "x", color=c, ms=9, mew=2)
            if first:  # terminal at the first step: nothing drawn yet to carry the label
                ax_x.plot([], [], color=c, label=f"{label} (terminal at step 0)")
    ax_x.set(xlabel="x (m)", ylabel="xd (m/s)", title="sagittal plane")
    ax_y.set(xlabel="y (m)", ylabel="yd (m/s)", title="frontal plane")
    for ax in (ax_x, ax_y):
        ax.grid(alpha=0.3)
        ax.axhline(0.0, color="k", lw=0.5)
    ax_x.legend(fontsize=8, loc="upper left")
    fig.suptitle(f"{title}  (diamond: switching state, x: terminal step)")
    return fig


def draw_footsteps(ax, plan: FootstepPlan, foot_size=(0.27, 0.16), upto: int | None = None):
    """Draw the stance feet of a plan as oriented rectangles (red right, blue left)."""
    feet = np.asarray(plan.footsteps)
    headings = np.asarray(plan.headings)
    signs = np.asarray(plan.lateral_signs)
    alive = np.concatenate([[True], np.asarray(plan.alive)])
    n = len(feet) if upto is None else min(upto, len(feet))
    length, width = foot_size
    for k in range(n):
        if not alive[k]:
            break
        side = "right" if signs[k] > 0 else "left"
        rect = Rectangle(
            (-length / 2, -width / 2), length, width, fill=False, lw=1.2, ec=FOOT_COLORS[side]
        )
        rect.set_transform(Affine2D().rotate(headings[k]).translate(*feet[k]) + ax.transData)
        ax.add_patch(rect)
        ax.text(*feet[k], str(k), fontsize=6, ha="center", va="center", color=FOOT_COLORS[side])


def plot_walk(
    plan: FootstepPlan, traj: ComTrajectory, title: str = "walking path", foot_size=(0.27, 0.16)
) -> Figure:
    """Fig. 11: top view of footsteps and CoM path (left), CoM states in the local frames
    (right: sagittal and lateral phase, each step relative to its stance foot)."""
    fig = Figure(figsize=(13, 5.5), constrained_layout=True)
    gs = fig.add_gridspec(2, 2, width_ratios=(1.5, 1))
    ax = fig.add_subplot(gs[:, 0])
    ax_sx = fig.add_subplot(gs[0, 1])
    ax_sy = fig.add_subplot(gs[1, 1])

    draw_footsteps(ax, plan, foot_size)
    pos = np.asarray(traj.position)
    local = np.asarray(traj.local)
    for _k, phase, seg in _alive_segments(traj, pos):
        ax.plot(seg[:, 0], seg[:, 1], color="k", lw=1.0)
        if phase == 1:
            ax.plot(*seg[0], "D", color="tab:green", ms=3)
    n_steps = local.shape[0]
    cmap = matplotlib.colormaps["viridis"]
    for k, _phase, seg in _alive_segments(traj, local):
        c = cmap(k / max(n_steps - 1, 1))
        ax_sx.plot(seg[:, 0], seg[:, 1], color=c, lw=1.0)
        ax_sy.plot(seg[:, 2], seg[:, 3], color=c, lw=1.0)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="world x (m)", ylabel="world y (m)", title=title)
    ax.grid(alpha=0.3)
    ax.plot([], [], color=FOOT_COLORS["right"], label="right foot")
    ax.plot([], [], color=FOOT_COLORS["left"], label="left foot")
    ax.plot([], [], color="k", label="CoM")
    ax.legend(fontsize=8, loc="best")
    ax_sx.set(xlabel="x local (m)", ylabel="xd local (m/s)", title="CoM in the local frames")
    ax_sy.set(xlabel="y local (m)", ylabel="yd local (m/s)")
    for a in (ax_sx, ax_sy):
        a.grid(alpha=0.3)
    return fig
