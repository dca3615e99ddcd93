"""The report of a limit search (:mod:`.limits`): where recovery ends, per direction and phase.

- ``summary.json``: every number (per cell: the limit, its bracket, whether it is censored,
  each round's tested impulse and recovered replicas; per variant: median, min, max and
  the worst phase's limit per direction);
- ``summary.md``: the tables, compared with the paper's 52 N s;
- ``limits_polar.png``: the limit per direction, one panel per variant, one curve per
  phase, the paper's push as a dashed circle;
- ``limits_heatmap.png``: direction x phase maps of the limit, one per variant.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from jaxloco.runtime import write_json
from jaxloco.sweep.limits import PAPER_IMPULSE, LimitResult


def _variants(result: LimitResult):
    """``(name, cell indices)`` per (replan, duration)."""
    out = []
    for r in result.search.replan:
        for t in result.search.durations:
            sel = [k for k, c in enumerate(result.cells) if c[3] == r and c[2] == t]
            out.append((f"{'replan' if r else 'no replan'}, {t:g} s pushes", sel))
    return out


def _grid(result: LimitResult, sel):
    """The limits of cells ``sel`` as a (phases, directions) array."""
    dirs = list(result.search.directions_deg)
    phases = list(result.search.phases)
    grid = np.full((len(phases), len(dirs)), np.nan)
    censored = np.zeros_like(grid, bool)
    for k in sel:
        d, p = result.cells[k][:2]
        i, j = phases.index(p), dirs.index(d)
        grid[i, j] = result.limit[k]
        censored[i, j] = result.censored_above[k]
    return grid, censored


def plot_limits_polar(result: LimitResult) -> Figure:
    variants = _variants(result)
    fig = Figure(figsize=(4.3 * len(variants), 4.6), constrained_layout=True)
    dirs = np.radians(np.asarray(result.search.directions_deg, float))
    order = np.argsort(dirs)
    theta = np.r_[dirs[order], dirs[order][:1] + 2 * np.pi]
    top = max(result.search.impulse_range[1], PAPER_IMPULSE) * 1.05
    for n, (name, sel) in enumerate(variants):
        ax = fig.add_subplot(1, len(variants), n + 1, projection="polar")
        grid, _ = _grid(result, sel)
        for i, phase in enumerate(result.search.phases):
            r = grid[i][order]
            ax.plot(theta, np.r_[r, r[:1]], "o-", ms=3, lw=1.2, label=f"phase {phase:g}")
        circle = np.linspace(0, 2 * np.pi, 200)
        ax.plot(circle, np.full_like(circle, PAPER_IMPULSE), "k--", lw=1, label="paper, 52 N s")
        ax.set_ylim(0, top)
        ax.set_theta_zero_location("N")  # forward (0 deg) up
        ax.set_theta_direction(1)  # counter-clockwise: 90 deg (left) to the left
        ax.set_title(f"{name}\nlargest recovered impulse (N s)", fontsize=9)
    fig.axes[-1].legend(loc="upper left", bbox_to_anchor=(1.05, 1.0), fontsize=7)
    return fig


def plot_limits_heatmap(result: LimitResult) -> Figure:
    variants = _variants(result)
    fig = Figure(figsize=(4.6 * len(variants), 3.4), constrained_layout=True)
    lo, hi = result.search.impulse_range
    dirs, phases = result.search.directions_deg, result.search.phases
    for n, (name, sel) in enumerate(variants):
        ax = fig.add_subplot(1, len(variants), n + 1)
        grid, censored = _grid(result, sel)
        im = ax.imshow(grid, cmap="RdYlGn", vmin=lo, vmax=hi, aspect="auto", origin="lower")
        for i in range(len(phases)):
            for j in range(len(dirs)):
                text = f"{grid[i, j]:.0f}" + ("+" if censored[i, j] else "")
                ax.text(j, i, text, ha="center", va="center", fontsize=7)
        ax.set_xticks(range(len(dirs)), [f"{d:g}" for d in dirs], fontsize=7)
        ax.set_yticks(range(len(phases)), [f"{p:g}" for p in phases], fontsize=7)
        ax.set(xlabel="push direction (deg, 0: forward)", ylabel="phase of single support")
        ax.set_title(f"{name} (N s; +: every impulse tried recovered)", fontsize=8)
    fig.colorbar(im, ax=fig.axes, shrink=0.8, label="largest recovered impulse (N s)")
    return fig


def _markdown(summary: dict) -> str:
    s = summary["search"]
    lines = [
        "# Limit search: the largest recovered impulse",
        "",
        f"{summary['rounds_done']} bisection rounds over {s['impulse_range']} N s "
        f"(resolution {summary['resolution_Ns']:g} N s), up to {s['replicas']} replicas per "
        f"tested impulse (qvel noise {s['qvel_noise']:g}; the last only where the others "
        f"left the decision open), recovered when >= {s['min_recovered']} recover; "
        f"{summary['pushes_run']} pushes. The paper's push: {summary['paper_impulse_Ns']:g} N s.",
        "",
        "| variant | median limit (N s) | min | max | cells >= 52 N s |",
        "|---|---|---|---|---|",
    ]
    for name, v in summary["variants"].items():
        lines.append(
            f"| {name} | {v['median_limit_Ns']:g} | {v['min_limit_Ns']:g} | "
            f"{v['max_limit_Ns']:g} | {v['cells_at_least_paper']}/{v['cells']} |"
        )
    for name, v in summary["variants"].items():
        lines += ["", f"## {name}: worst phase's limit per direction (N s)", ""]
        dirs = v["worst_phase_limit_per_direction_Ns"]
        lines += ["| " + " | ".join(f"{d} deg" for d in dirs) + " |"]
        lines += ["|" + "---|" * len(dirs)]
        lines += ["| " + " | ".join(f"{x:g}" for x in dirs.values()) + " |"]
    censored = [c for c in summary["cells"] if c["censored_above"]]
    if censored:
        lines += [
            "",
            f"{len(censored)} cells recovered every impulse tried: their limit is at least "
            "the value shown and may lie past the range (`search.impulse_range`).",
        ]
    return "\n".join(lines) + "\n"


def write_limits_report(result: LimitResult, out_dir, dpi: int = 120) -> dict:
    """Write the report files (see the module doc) into ``out_dir``; returns the summary."""
    out = Path(out_dir)
    summary = result.summary()
    write_json(out / "summary.json", summary)
    (out / "summary.md").write_text(_markdown(summary))
    plot_limits_polar(result).savefig(out / "limits_polar.png", dpi=dpi)
    plot_limits_heatmap(result).savefig(out / "limits_heatmap.png", dpi=dpi)
    return summary
