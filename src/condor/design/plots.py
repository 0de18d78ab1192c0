"""Figures of a design run, for the stage layer and the report (matplotlib, Agg). Nothing here
is called by the search or the confirmation."""

from __future__ import annotations

import numpy as np
import pandas as pd


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_confirmation(table: pd.DataFrame, summary: pd.DataFrame, path=None, title: str = ""):
    """Predicted against simulated objective of the confirmed designs (`confirmation_table`):
    top and random designs apart, the replica spread as error bars, the identity line and, when
    the summary has one, the best baseline mould's simulated objective. Returns the Figure."""
    plt = _pyplot()
    row = summary.iloc[0]
    fig, ax = plt.subplots(figsize=(4.6, 4.2))
    for role, marker, colour in (("random", "o", "#6baed6"), ("top", "*", "#d62728")):
        part = table[table["role"] == role]
        if len(part):
            ax.errorbar(part["predicted_objective"], part["simulated_objective"],
                        yerr=part.get("simulated_objective_std"), fmt=marker, color=colour,
                        ms=9 if marker == "*" else 5, capsize=2, label=f"{role} ({len(part)})")
    values = np.concatenate([table["predicted_objective"], table["simulated_objective"]])
    values = values[np.isfinite(values)]
    if values.size:
        low, high = values.min(), values.max()
        pad = 0.05 * (high - low or 1.0)
        ax.plot([low - pad, high + pad], [low - pad, high + pad], color="grey", lw=0.8, ls="--")
    if "best_baseline" in row and np.isfinite(row["best_baseline"]):
        ax.axhline(row["best_baseline"], color="#31a354", lw=1,
                   label=f"best baseline mould ({row['best_baseline']:.3g})")
    ax.set_xlabel("predicted objective (surrogate)")
    ax.set_ylabel("simulated objective (replica mean)")
    rho = f"Spearman {row['spearman']:.2f} [{row['spearman_low']:.2f}, {row['spearman_high']:.2f}]"
    ax.set_title(f"{title}\n{rho}, bias {row['bias']:+.3f}" if title else rho, fontsize=9)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig


def plot_search_history(history: pd.DataFrame, path=None):
    """Best score so far and each generation's median against designs evaluated."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(4.6, 3.2))
    ax.plot(history["evaluations"], history["best_score"], label="best so far")
    ax.plot(history["evaluations"], history["generation_median"], lw=0.8,
            label="generation median")
    ax.set_xlabel("designs evaluated")
    ax.set_ylabel("score (predicted)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig
