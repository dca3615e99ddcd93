"""Reports of a push sweep, rebuilt from what is on disk (``jaxloco sweep-report
run_dir=RUN_DIR``).

- ``success_polar.png``: success rate per direction x impulse, one polar map per
  replanning setting.
- ``success_vs_phase.png``: success rate against the gait phase of the push.
- ``summary.json`` / ``summary.md``: counts, the largest recovered impulse per direction
  (the largest impulse at which every push in that direction was recovered, and every
  smaller one too), success per phase, both with replanning on and off.

:func:`paired_comparison` says whether one controller recovers more of the same pushes
than another beyond chance (pushes at the edge of recovery flip outcome for small causes).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from jaxloco.runtime import write_json
from jaxloco.sweep.store import SweepStore


def _variants(table, have):
    out = []
    for replan in (True, False):
        mask = have & (table["replan"] == replan)
        if mask.any():
            out.append(("replan" if replan else "no_replan", mask))
    return out


def summarize(table, outcomes, have) -> dict:
    """The numbers of the report (plain JSON types)."""
    impulse = table["magnitude"] * table["duration"]
    summary = {"pushes": int(len(table)), "with_results": int(have.sum()), "variants": {}}
    rec = outcomes.get("recovered", np.zeros(len(table), bool))
    for name, mask in _variants(table, have):
        per_dir = {}
        for d in np.unique(np.round(table["direction_deg"][mask], 6)):
            sel = mask & np.isclose(table["direction_deg"], d)
            levels = np.unique(np.round(impulse[sel], 9))
            best = 0.0
            for level in levels:  # ascending: stop at the first impulse not always recovered
                at = sel & np.isclose(impulse, level)
                if not rec[at].all():
                    break
                best = float(level)
            per_dir[f"{d:g}"] = {
                "pushes": int(sel.sum()),
                "recovered": int(rec[sel].sum()),
                "largest_recovered_impulse_Ns": best,
            }
        per_phase = {}
        for p in np.unique(np.round(table["phase"][mask], 6)):
            sel = mask & np.isclose(table["phase"], p)
            per_phase[f"{p:g}"] = float(rec[sel].mean())
        summary["variants"][name] = {
            "pushes": int(mask.sum()),
            "recovered": int(rec[mask].sum()),
            "success_rate": float(rec[mask].mean()),
            "fell": int(outcomes["fell"][mask].sum()),
            "mean_replans": float(outcomes["replans"][mask].mean()),
            "failed_plans": int(outcomes["failed_plans"][mask].sum()),
            "relaxed_ticks": int(outcomes["relaxed_ticks"][mask].sum()),
            "max_com_error": float(outcomes["max_com_error"][mask].max()),
            "peak_torque_norm": float(outcomes["peak_torque_norm"][mask].max()),
            "directions": per_dir,
            "success_vs_phase": per_phase,
        }
    return summary


def paired_comparison(recovered_a, recovered_b) -> dict:
    """Controllers ``a`` and ``b`` on the same pushes (boolean arrays, one entry per push):
    how many only ``a`` / only ``b`` recovered, and the exact two-sided McNemar p-value
    (binomial test on those discordant pushes at 1/2): the chance of a split at least this
    uneven if neither controller were better and each flip were a coin toss."""
    a, b = np.asarray(recovered_a, bool), np.asarray(recovered_b, bool)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"paired_comparison: want two equal 1-D arrays; got {a.shape}, {b.shape}")
    only_a, only_b = int(np.sum(a & ~b)), int(np.sum(b & ~a))
    n, k = only_a + only_b, min(only_a, only_b)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2.0**n if n else 1.0
    return {
        "recovered_a": int(a.sum()),
        "recovered_b": int(b.sum()),
        "only_a": only_a,
        "only_b": only_b,
        "p_value": min(1.0, 2.0 * tail),
    }


def _markdown(summary: dict, manifest: dict) -> str:
    lines = [
        f"# Push sweep: {summary['with_results']}/{summary['pushes']} pushes done "
        f"(backend {manifest.get('backend')})",
        "",
        "| variant | pushes | recovered | success | fell | mean replans | failed plans "
        "| relaxed-cone ticks | max Eq. 33 error |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, v in summary["variants"].items():
        lines.append(
            f"| {name} | {v['pushes']} | {v['recovered']} | {v['success_rate']:.0%} | {v['fell']} "
            f"| {v['mean_replans']:.1f} | {v['failed_plans']} | {v['relaxed_ticks']} "
            f"| {v['max_com_error']:.3f} |"
        )
    for name, v in summary["variants"].items():
        lines += [
            "",
            f"## {name}: per direction (0 deg pushes forward, 90 deg to the left)",
            "",
            "| direction (deg) | recovered | largest recovered impulse (N s) |",
            "|---|---|---|",
        ]
        for d, r in v["directions"].items():
            lines.append(
                f"| {d} | {r['recovered']}/{r['pushes']} | {r['largest_recovered_impulse_Ns']:g} |"
            )
    runs = manifest.get("runs", [])
    if runs:
        r = runs[-1]
        rate = r.get("env_steps_per_s")
        rate = (
            f"{rate:.0f} env-steps/s steady"
            if rate is not None
            else "one chunk only, so no compile-free rate"
        )
        lines += [
            "",
            f"Last run: {r['wall_s']:.0f} s wall, first chunk (with compile) "
            f"{r['first_chunk_s']:.1f} s, {rate}, devices {manifest.get('devices')}.",
        ]
    return "\n".join(lines) + "\n"


def plot_polar(table, outcomes, have, dpi=120) -> Figure:
    impulse = table["magnitude"] * table["duration"]
    variants = _variants(table, have)
    fig = Figure(figsize=(4.2 * max(1, len(variants)), 4.4), constrained_layout=True)
    rec = outcomes.get("recovered", np.zeros(len(table), bool)).astype(float)
    for k, (name, mask) in enumerate(variants):
        ax = fig.add_subplot(1, len(variants), k + 1, projection="polar")
        dirs = np.unique(np.round(table["direction_deg"][mask], 6))
        levels = np.unique(np.round(impulse[mask], 9))
        rate = np.full((len(levels), len(dirs)), np.nan)
        for i, level in enumerate(levels):
            for j, d in enumerate(dirs):
                sel = mask & np.isclose(impulse, level) & np.isclose(table["direction_deg"], d)
                if sel.any():
                    rate[i, j] = rec[sel].mean()
        theta = np.radians(dirs)
        th, r = np.meshgrid(theta, levels)
        sc = ax.scatter(
            th.ravel(), r.ravel(), c=rate.ravel(), cmap="RdYlGn", vmin=0, vmax=1, s=120,
            edgecolors="k", linewidths=0.4,
        )  # fmt: skip
        ax.set_ylim(0, max(levels.max() * 1.15, 1e-9))
        ax.set_title(f"{name}: success by direction x impulse (N s)", fontsize=9)
        ax.set_theta_zero_location("N")  # forward (0 deg) up
        ax.set_theta_direction(1)  # counter-clockwise: 90 deg (left) to the left
    if variants:
        fig.colorbar(sc, ax=fig.axes, shrink=0.7, label="recovered fraction")
    return fig


def plot_phase(table, outcomes, have, dpi=120) -> Figure:
    fig = Figure(figsize=(5, 3.4), constrained_layout=True)
    ax = fig.subplots()
    rec = outcomes.get("recovered", np.zeros(len(table), bool)).astype(float)
    for name, mask in _variants(table, have):
        phases = np.unique(np.round(table["phase"][mask], 6))
        rate = [rec[mask & np.isclose(table["phase"], p)].mean() for p in phases]
        ax.plot(phases, rate, "o-", label=name)
    ax.set(
        xlabel="push start (fraction of single support)",
        ylabel="recovered fraction",
        ylim=(-0.05, 1.05),
    )
    ax.grid(alpha=0.3)
    ax.legend()
    return fig


def write_report(run_dir, dpi: int = 120) -> dict:
    """Rebuild every report file of the sweep in ``run_dir``; returns the summary."""
    store = SweepStore(run_dir)
    manifest = store.read_manifest()
    table, outcomes, have = store.load_results()
    if not have.any():
        raise ValueError(f"{run_dir}: no finished chunks yet, nothing to report")
    summary = summarize(table, outcomes, have)
    out = Path(run_dir)
    write_json(out / "summary.json", summary)
    (out / "summary.md").write_text(_markdown(summary, manifest))
    plot_polar(table, outcomes, have).savefig(out / "success_polar.png", dpi=dpi)
    plot_phase(table, outcomes, have).savefig(out / "success_vs_phase.png", dpi=dpi)
    return summary
