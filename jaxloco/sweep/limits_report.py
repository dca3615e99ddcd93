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
from jaxloco.sim.mjx_loop import MODEL_LIMITS, PhysicsParams
from jaxloco.sweep.limit_result import LimitResult
from jaxloco.sweep.limit_search import (
    LEARNED_IMPULSE,
    PAPER_IMPULSE,
    PAPER_MASS,
    paper_impulse_for,
)


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


def plot_limits_polar(result: LimitResult, paper: float = paper_impulse_for(None)) -> Figure:
    variants = _variants(result)
    fig = Figure(figsize=(4.3 * len(variants), 4.6), constrained_layout=True)
    dirs = np.radians(np.asarray(result.search.directions_deg, float))
    order = np.argsort(dirs)
    theta = np.r_[dirs[order], dirs[order][:1] + 2 * np.pi]
    top = max(result.search.impulse_range[1], paper) * 1.05
    for n, (name, sel) in enumerate(variants):
        ax = fig.add_subplot(1, len(variants), n + 1, projection="polar")
        grid, _ = _grid(result, sel)
        for i, phase in enumerate(result.search.phases):
            r = grid[i][order]
            ax.plot(theta, np.r_[r, r[:1]], "o-", ms=3, lw=1.2, label=f"phase {phase:g}")
        circle = np.linspace(0, 2 * np.pi, 200)
        label = f"paper's push, {paper:g} N s"
        ax.plot(circle, np.full_like(circle, paper), "k--", lw=1, label=label)
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
    paper, learned = summary["paper_impulse_Ns"], summary["learned_impulse_Ns"]
    lines = [
        "# Limit search: the largest recovered impulse",
        "",
        f"{summary['rounds_done']} bisection rounds over {s['impulse_range']} N s "
        f"(resolution {summary['resolution_Ns']:g} N s), up to {s['replicas']} replicas per "
        f"tested impulse (qvel noise {s['qvel_noise']:g}; the last only where the others "
        f"left the decision open), recovered when >= {s['min_recovered']} recover; "
        f"{summary['pushes_run']} pushes. The paper's push: {paper:g} N s; the largest "
        f"recovered by a learned policy on the paper's robot (Yuan et al., 2020): {learned:g} N s.",
        "",
    ]
    mass = summary.get("robot_mass_kg")
    if mass is None:
        lines += [
            f"| variant | median limit (N s) | min | max | cells >= {paper:g} N s "
            f"| cells >= {learned:g} N s | cells past the range |",
            "|---|---|---|---|---|---|---|",
        ]
    else:
        lines[2] += (
            f" On this robot ({mass:.1f} kg) that is the paper's velocity change, "
            f"{summary['paper_velocity_mps']:.3f} m/s ({PAPER_IMPULSE:g} N s on the paper's "
            f"{PAPER_MASS:g} kg robot), and the learned policy's {learned / mass:.3f} m/s "
            f"({LEARNED_IMPULSE:g} N s)."
        )
        lines += [
            f"| variant | median limit (N s) | min | max | median (m/s) | min | max "
            f"| cells >= {paper:g} N s | cells >= {learned:g} N s | cells past the range |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
    bound = summary.get("torque_limit")
    if bound == MODEL_LIMITS:
        lines[2] += " Actuator torques bounded by each joint's own effort limit (the model's)."
    elif bound is not None:
        lines[2] += f" Actuator torques bounded at +-{float(bound):g} N m at every joint" + (
            " (the paper's authors' setting)."
            if float(bound) == PhysicsParams().torque_limit
            else "."
        )
    for name, v in summary["variants"].items():
        speeds = (
            ""
            if mass is None
            else f"{v['median_limit_mps']:.3f} | {v['min_limit_mps']:.3f} | "
            f"{v['max_limit_mps']:.3f} | "
        )
        lines.append(
            f"| {name} | {v['median_limit_Ns']:g} | {v['min_limit_Ns']:g} | "
            f"{v['max_limit_Ns']:g} | {speeds}{v['cells_at_least_paper']}/{v['cells']} | "
            f"{v['cells_at_least_learned']}/{v['cells']} | {v['cells_censored_above']} |"
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


def write_limits_report(
    result: LimitResult,
    out_dir,
    dpi: int = 120,
    mass: float | None = None,
    torque_limit: float | str | None = None,
) -> dict:
    """Write the report files (see the module doc) into ``out_dir``; returns the summary.
    ``mass``: the robot's (kg), for the limits as velocity changes and the paper's push
    at the robot's mass (None: the paper's robot's numbers, 52 N s). ``torque_limit``: the
    simulation's actuator bound the search ran at (``PhysicsParams.torque_limit``: N m at
    every joint, or ``"model"``, each joint's own effort limit), stated in the report
    (None: not stated)."""
    out = Path(out_dir)
    summary = result.summary(mass)
    if torque_limit is not None:
        summary["torque_limit"] = torque_limit
    write_json(out / "summary.json", summary)
    (out / "summary.md").write_text(_markdown(summary))
    plot_limits_polar(result, summary["paper_impulse_Ns"]).savefig(
        out / "limits_polar.png", dpi=dpi
    )
    plot_limits_heatmap(result).savefig(out / "limits_heatmap.png", dpi=dpi)
    return summary


def compare_limit_summaries(summaries: dict[str, dict]) -> dict:
    """Per variant and direction, the limits of several searches side by side.

    ``summaries``: label -> a limit search's ``summary.json`` (e.g. the same search at two
    torque bounds). The searches must have the same directions, phases and variants.
    Per direction: the worst phase's limit (the impulse recovered at every phase) and the
    median over phases."""
    if len(summaries) < 2:
        raise ValueError("compare_limit_summaries: needs at least two summaries")
    labels = list(summaries)
    first = summaries[labels[0]]
    for label in labels[1:]:
        other = summaries[label]
        for key in ("directions_deg", "phases", "durations", "replan"):
            if other["search"][key] != first["search"][key]:
                raise ValueError(
                    f"compare_limit_summaries: {label!r} has search.{key} "
                    f"{other['search'][key]}, {labels[0]!r} has {first['search'][key]}"
                )
    variants = {}
    for name, v in first["variants"].items():
        rows = {}
        for d in first["search"]["directions_deg"]:
            row = {}
            for label in labels:
                s = summaries[label]
                limits = [
                    c["limit_Ns"]
                    for c in s["cells"]
                    if c["direction_deg"] == d
                    and c["replan"] == v["replan"]
                    and c["duration_s"] == v["duration_s"]
                ]
                row[label] = {
                    "worst_phase_Ns": float(np.min(limits)),
                    "median_Ns": float(np.median(limits)),
                }
            rows[f"{d:g}"] = row
        variants[name] = {
            "per_direction": rows,
            "median_limit_Ns": {
                lb: summaries[lb]["variants"][name]["median_limit_Ns"] for lb in labels
            },
            "cells_at_least_paper": {
                lb: summaries[lb]["variants"][name]["cells_at_least_paper"] for lb in labels
            },
            # Summaries written before the learned policy's reference have no count: None.
            "cells_at_least_learned": {
                lb: summaries[lb]["variants"][name].get("cells_at_least_learned") for lb in labels
            },
            "cells": v["cells"],
        }
    return {
        "labels": labels,
        "paper_impulse_Ns": first["paper_impulse_Ns"],
        "learned_impulse_Ns": first.get("learned_impulse_Ns"),
        "resolution_Ns": first["resolution_Ns"],
        "variants": variants,
    }


def _comparison_markdown(cmp: dict) -> str:
    labels = cmp["labels"]
    lines = [
        "# Limit searches compared: the largest recovered impulse per direction",
        "",
        f"Per direction, the worst phase's limit (recovered at every phase) and, in brackets, "
        f"the median over phases, in N s (resolution {cmp['resolution_Ns']:g} N s; the "
        f"paper's push: {cmp['paper_impulse_Ns']:g} N s).",
    ]
    for name, v in cmp["variants"].items():
        lines += ["", f"## {name}", ""]
        lines += ["| direction | " + " | ".join(labels) + " |"]
        lines += ["|---|" + "---|" * len(labels)]
        for d, row in v["per_direction"].items():
            cells = [f"{row[lb]['worst_phase_Ns']:g} ({row[lb]['median_Ns']:g})" for lb in labels]
            lines.append(f"| {d} deg | " + " | ".join(cells) + " |")
        medians = [f"{v['median_limit_Ns'][lb]:g}" for lb in labels]
        lines.append("| median cell | " + " | ".join(medians) + " |")
        paper = [f"{v['cells_at_least_paper'][lb]}/{v['cells']}" for lb in labels]
        lines.append("| cells >= paper | " + " | ".join(paper) + " |")
        learned = v.get("cells_at_least_learned", {})
        if cmp.get("learned_impulse_Ns") is not None:
            counts = [
                "-" if learned.get(lb) is None else f"{learned[lb]}/{v['cells']}" for lb in labels
            ]
            lines.append(
                f"| cells >= {cmp['learned_impulse_Ns']:g} N s (learned policy) | "
                + " | ".join(counts)
                + " |"
            )
    return "\n".join(lines) + "\n"


def plot_limits_comparison(cmp: dict) -> Figure:
    """One polar panel per variant: each search's worst-phase limit per direction."""
    variants = list(cmp["variants"].items())
    fig = Figure(figsize=(4.3 * len(variants), 4.6), constrained_layout=True)
    for n, (name, v) in enumerate(variants):
        ax = fig.add_subplot(1, len(variants), n + 1, projection="polar")
        dirs = np.radians([float(d) for d in v["per_direction"]])
        order = np.argsort(dirs)
        theta = np.r_[dirs[order], dirs[order][:1] + 2 * np.pi]
        for label in cmp["labels"]:
            r = np.array([row[label]["worst_phase_Ns"] for row in v["per_direction"].values()])
            r = r[order]
            ax.plot(theta, np.r_[r, r[:1]], "o-", ms=3, lw=1.4, label=label)
        circle = np.linspace(0, 2 * np.pi, 200)
        ax.plot(
            circle,
            np.full_like(circle, cmp["paper_impulse_Ns"]),
            "k--",
            lw=0.8,
            label="paper's push",
        )
        ax.set_title(f"{name}\nworst phase's limit (N s)", fontsize=9)
        ax.legend(fontsize=7, loc="lower left", bbox_to_anchor=(-0.15, -0.15))
    return fig


def write_limits_comparison(summaries: dict[str, dict], out_dir, dpi: int = 120) -> dict:
    """``comparison.json``, ``comparison.md`` and ``comparison_polar.png`` in ``out_dir``
    (:func:`compare_limit_summaries`); returns the comparison."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cmp = compare_limit_summaries(summaries)
    write_json(out / "comparison.json", cmp)
    (out / "comparison.md").write_text(_comparison_markdown(cmp))
    plot_limits_comparison(cmp).savefig(out / "comparison_polar.png", dpi=dpi)
    return cmp
