"""Figures for RL-PSP: learning curves, value maps with the survival basin (Fig. 5-6)."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure


def plot_learning_curve(history: list[dict], title: str = "RL-PSP training") -> Figure:
    """Return, survival, spread and survival basin against iterations and wall time.

    Rows of the refinement stage (``stage == "refine"``) only carry the basin; a dashed
    line marks where refinement starts.
    """
    it = np.array([h["iteration"] for h in history])
    wall = np.array([h["wall_s"] for h in history])
    refine_rows = [i for i, h in enumerate(history) if h.get("stage") == "refine"]
    fig = Figure(figsize=(12, 6.5), constrained_layout=True)
    axes = fig.subplots(2, 4)
    series = [
        ("mean_return", "mean episode return"),
        ("survival", "episodes surviving the step cap"),
        ("spread", "mean policy spread"),
        ("basin", "survival basin (mean policy)"),
    ]
    for col, (key, label) in enumerate(series):
        for row, (x, xlabel) in enumerate(((it, "iteration"), (wall, "wall time (s)"))):
            ax = axes[row, col]
            if key == "spread":
                pts = [(xv, h["spread"]) for xv, h in zip(x, history, strict=True) if "spread" in h]
                if pts:
                    xs, values = np.array([p[0] for p in pts]), np.array([p[1] for p in pts])
                    for k, name in enumerate(("p_x", "xd_next", "yd_next")):
                        ax.plot(xs, values[:, k], label=name)
                    ax.legend(fontsize=7)
            elif key == "basin":
                for name, legend in (("basin", "straight"), ("steering_basin", "steering")):
                    pts = [(xv, h[name]) for xv, h in zip(x, history, strict=True) if name in h]
                    if pts:
                        ax.plot(*zip(*pts, strict=True), "o-", ms=3, label=legend)
                if refine_rows:
                    ax.axvline(x[refine_rows[0]], color="0.4", ls="--", lw=1, label="refinement")
                if refine_rows or any("steering_basin" in h for h in history):
                    ax.legend(fontsize=7)
            else:
                pts = [(xv, h[key]) for xv, h in zip(x, history, strict=True) if key in h]
                if pts:
                    ax.plot(*zip(*pts, strict=True))
            if key != "basin" and not any(key in h for h in history):
                note = "no Algorithm 1 iterations"
                ax.text(0.5, 0.5, note, ha="center", va="center", transform=ax.transAxes)
            ax.set(xlabel=xlabel, title=label if row == 0 else None)
            ax.grid(alpha=0.3)
    fig.suptitle(title)
    return fig


def plot_value_map(
    y_axis: np.ndarray,
    xd_axis: np.ndarray,
    value: np.ndarray,
    survived: np.ndarray,
    yd: float,
    title: str = "learned value and survival basin",
) -> Figure:
    """The learned value over a (y, xd) slice of the apex state box at lateral velocity
    ``yd``, with the boundary of the survival basin (states from which the mean policy
    walks the full horizon) drawn on top. ``value`` and ``survived``: (len(xd), len(y))."""
    fig = Figure(figsize=(6.5, 5), constrained_layout=True)
    ax = fig.subplots()
    mesh = ax.pcolormesh(y_axis, xd_axis, value, shading="auto", cmap="viridis")
    fig.colorbar(mesh, ax=ax, label="v(s)")
    if survived.any() and (~survived).any():
        ax.contour(y_axis, xd_axis, survived.astype(float), levels=[0.5], colors="w")
    ax.plot([], [], color="w", label="survival-basin boundary")
    ax.legend(loc="upper right", fontsize=8, facecolor="0.5")
    ax.set(xlabel="y_apex (m)", ylabel="xd_apex (m/s)", title=f"{title} (yd_apex = {yd:+.2f})")
    return fig


def plot_ppo_curve(history: list[dict], title: str = "PPO training") -> Figure:
    """Survival basin and Brax's mean evaluation episode reward against env steps and wall
    time (rows of :class:`~jaxloco.learning.ppo.PPOResult`'s history)."""
    fig = Figure(figsize=(9, 6), constrained_layout=True)
    axes = fig.subplots(2, 2)
    steps = np.array([h["env_steps"] for h in history], float)
    wall = np.array([h["wall_s"] for h in history], float)
    series = (
        ("basin", "survival basin (deterministic policy)"),
        ("episode_reward", "episode reward"),
    )
    for col, (key, label) in enumerate(series):
        ys = np.array([np.nan if h.get(key) is None else h[key] for h in history], float)
        for row, (x, xlabel) in enumerate(((steps, "env steps"), (wall, "wall time (s)"))):
            ax = axes[row, col]
            ax.plot(x, ys, "o-")
            ax.set_xlabel(xlabel)
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
    fig.suptitle(title)
    return fig
