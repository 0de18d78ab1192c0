"""Figures of dataset samples (the paper's example-sample figure)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only; no display on workers
    import matplotlib.pyplot as plt

    return plt


def sample_panels(store: str | Path, out_png: str | Path, n: int = 4) -> list[int]:
    """For the first `n` ok samples: the mould (mould and tether channels) and its 8 fields,
    one row each. Returns the sample ids shown."""
    from condor.store import open_dataset

    ds = open_dataset(store)
    ok = np.flatnonzero(ds["status"].values.astype(str) == "ok")[:n]
    plt = _pyplot()
    names = [str(f) for f in ds["field"].values]
    ncols = 1 + len(names)
    fig, axes = plt.subplots(max(len(ok), 1), ncols, figsize=(1.6 * ncols, 1.7 * max(len(ok), 1)),
                             squeeze=False)
    for row, sample in enumerate(ok):
        inputs = ds["inputs"].isel(sample=int(sample)).values
        fields = ds["fields"].isel(sample=int(sample)).values
        axes[row, 0].imshow(inputs[0] + 2 * inputs[1], origin="lower", cmap="Greys", vmin=0, vmax=2)
        axes[row, 0].set_title(f"mould {int(sample)}", fontsize=7)
        for col, name in enumerate(names, 1):
            image = axes[row, col].imshow(fields[col - 1], origin="lower", cmap="viridis")
            axes[row, col].set_title(name, fontsize=7)
            fig.colorbar(image, ax=axes[row, col], fraction=0.046, pad=0.02).ax.tick_params(labelsize=5)
    if len(ok) == 0:
        axes[0, 0].text(0.5, 0.5, "no finished samples", ha="center")
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    Path(out_png).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return [int(s) for s in ok]
