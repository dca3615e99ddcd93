"""Figures for gain tuning: the loss curve and its terms."""

from __future__ import annotations

from collections.abc import Sequence

from matplotlib.figure import Figure


def plot_loss_curve(history: list[dict], terms: Sequence[str], title: str) -> Figure:
    """The loss per iteration (wall time on the top axis) and, on a log scale, every one
    of ``terms`` the history records (the unweighted loss terms)."""
    fig = Figure(figsize=(10, 4), constrained_layout=True)
    ax_it, ax_terms = fig.subplots(1, 2)
    it = [h["iteration"] for h in history]
    ax_it.plot(it, [h["loss"] for h in history], "o-", ms=3)
    ax_it.set(xlabel="iteration", ylabel="loss", title=title)
    top = ax_it.secondary_xaxis("top", functions=(lambda x: x, lambda x: x))
    top.set_xlabel(f"wall time: {history[-1]['wall_s']:.0f} s for {len(history)} iterations")
    for term in terms:
        if term in history[0]:
            ax_terms.semilogy(it, [max(h[term], 1e-12) for h in history], label=term)
    ax_terms.set(xlabel="iteration", title="loss terms (unweighted)")
    for ax in (ax_it, ax_terms):
        ax.grid(alpha=0.3)
    ax_terms.legend(fontsize=8)
    return fig
