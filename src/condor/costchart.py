"""Cost per mould against error for every way of answering "what fields does this mould give".

Every method is compared on the same moulds against the same long-anneal reference
(condor.tradeoff: the longest affordable anneal, then FIRE to a tight force tolerance):
simulations (long anneal, short anneals, minimiser, hybrid; rows of a `tradeoff.sweep` table)
and predictors (each surrogate variant, the baselines) that map the moulds' input channels to
fields. The error is the mean absolute error of the normalised fields (fields * N_p / N_c;
for a prediction N_c is the predicted sum of P), mean over the 8 channels and the pixels,
as `tradeoff.sweep`'s `field_mae`. The cost is CPU seconds per mould on one core
(time.process_time, one torch thread for the predictors).

The paper's reported costs are drawn as marks: 24 to 36 core-hours per CONDOR simulation
(its scene) and about 0.1 s per pix2pix prediction on a laptop CPU.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd

PAPER_SIMULATION_SECONDS = (24 * 3600.0, 36 * 3600.0)  # core-seconds per simulation
PAPER_PREDICTION_SECONDS = 0.1  # s per prediction, laptop CPU

# Chart colour and order of each family of methods.
FAMILIES = {
    "long anneal": "black", "reference": "grey", "anneal": "tab:red", "minimise": "tab:blue",
    "hybrid": "tab:green", "surrogate": "tab:orange", "baseline": "tab:brown",
}


def reference_result(lattice, reference_budget: float, tight_ftol: float | None = None):
    """The long-anneal reference of `condor.tradeoff.sweep` for one lattice: the long anneal
    (seed tradeoff.REFERENCE_SEED) then FIRE to `tight_ftol` (default tradeoff.TIGHT_FTOL).
    Deterministic, so it reproduces the sweep's reference (same energy, same fields)."""
    from condor import tradeoff
    from condor.energy import random_orientations
    from condor.simulate import simulate_lattice

    seed = tradeoff.REFERENCE_SEED
    ftol = tradeoff.TIGHT_FTOL if tight_ftol is None else tight_ftol
    ori = random_orientations(lattice.n_cells, np.random.default_rng([seed, 1]))
    long = simulate_lattice(lattice, lattice.positions, ori, "anneal", reference_budget, seed)
    return simulate_lattice(lattice, long.positions, long.orientations, "minimise", None, seed,
                            ftol)


def reference_fields(mould, scene, reference_budget: float) -> tuple[np.ndarray, dict]:
    """Normalised fields (8, pixels, pixels) of the reference state of `mould` in `scene`,
    and its scalars (energy per cell, cells, status)."""
    from condor import tradeoff
    from condor.lattice import build_lattice

    lattice = build_lattice(mould.polygon, mould.tethers, scene.depth)
    ref = reference_result(lattice, reference_budget)
    fields = tradeoff.normalised_fields(ref, scene.box, scene.pixels, scene.sigma)
    return fields, dict(energy_per_cell=ref.energy_per_cell, n_cells=ref.n_cells,
                        status=ref.status)


def sweep_with_reference(scene, mould, anneal_budgets=(10, 100, 1000), seeds=(1,),
                         reference_budget: float = 1e4, log=None) -> tuple[pd.DataFrame, np.ndarray]:
    """`tradeoff.sweep` of one mould (default methods with `anneal_budgets`) and the normalised
    fields (8, pixels, pixels) of its reference state, which predictors are scored against.
    The sweep table gains `reference_check`: the reproduced reference's E/cell over the
    sweep's - 1 (0 when both are the same state)."""
    from condor import tradeoff

    df = tradeoff.sweep(scene, moulds=[mould], seeds=tuple(seeds), reference_budget=reference_budget,
                        methods=tradeoff.default_methods(tuple(anneal_budgets)), log=log)
    fields, meta = reference_fields(mould, scene, reference_budget)
    swept = float(df.loc[df["role"] == "reference", "energy_per_cell"].iloc[0])
    df["reference_check"] = meta["energy_per_cell"] / swept - 1.0
    return df, fields


def field_errors(predicted_raw: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """MAE per sample of normalised predicted fields against normalised reference fields.

    predicted_raw: (S, 8, H, W) weighted sums Z_p (as the surrogate predicts them);
    reference: (S, 8, H, W) normalised. A prediction whose P sums to <= 0 scores NaN."""
    raw = np.asarray(predicted_raw, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if raw.shape != reference.shape:
        raise ValueError(f"predicted fields {raw.shape} and reference {reference.shape} differ")
    n_cells = raw[:, 0].sum(axis=(-2, -1))
    n_pixels = raw.shape[-1] * raw.shape[-2]
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(n_cells > 0, n_pixels / n_cells, np.nan)
    return np.abs(raw * scale[:, None, None, None] - reference).mean(axis=(1, 2, 3))


def core_seconds_per_call(fn, repeats: int = 3) -> tuple[object, float]:
    """fn() (after one untimed warm-up call) and the median CPU seconds of `repeats` calls."""
    result = fn()
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        result = fn()
        times.append(time.process_time() - t0)
    return result, float(np.median(times))


def predictor_rows(name: str, family: str, predict_raw, inputs: np.ndarray, reference: np.ndarray,
                   mould_ids, repeats: int = 3) -> list[dict]:
    """Rows (one per mould) for a predictor: `predict_raw` maps inputs (1, 2, H, W) to raw
    fields (1, 8, H, W); it is timed one mould at a time (CPU seconds, median of `repeats`)."""
    rows = []
    for k, mould_id in enumerate(mould_ids):
        raw, seconds = core_seconds_per_call(lambda: predict_raw(inputs[k:k + 1]), repeats)
        mae = float(field_errors(raw, reference[k:k + 1])[0])
        rows.append(dict(mould=int(mould_id), method=name, family=family, seconds=seconds,
                         field_mae=mae, status="ok" if np.isfinite(mae) else "no density"))
    return rows


def surrogate_rows(checkpoints: dict, inputs: np.ndarray, reference: np.ndarray, mould_ids,
                   threads: int = 1) -> list[dict]:
    """Rows for each surrogate variant {name: checkpoint path}, on CPU with `threads` torch
    threads (1: core-seconds comparable with the single-core simulations)."""
    import torch

    from condor.surrogate.predict import Predictor

    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        rows = []
        for name, path in checkpoints.items():
            predictor = Predictor(path, device="cpu")
            rows += predictor_rows(name, "surrogate", lambda x: predictor(x).raw, inputs,
                                   reference, mould_ids)
        return rows
    finally:
        torch.set_num_threads(previous)


def baseline_rows(ds, inputs: np.ndarray, reference: np.ndarray, mould_ids) -> list[dict]:
    """Rows for the surrogate baselines (fitted on the store's train split)."""
    from condor.surrogate.baselines import MaskedMeanBaseline, MouldBlurBaseline
    from condor.surrogate.data import dataset_pixel_size, usable_samples

    train = ds.isel(sample=usable_samples(ds, "train"))
    train_inputs = np.asarray(train["inputs"].values, dtype=np.float32)
    train_fields = np.asarray(train["fields"].values, dtype=np.float32)
    rows = []
    for baseline in (MaskedMeanBaseline(), MouldBlurBaseline(dataset_pixel_size(ds))):
        fitted = baseline.fit(train_inputs, train_fields)
        rows += predictor_rows(f"baseline {baseline.name}", "baseline", fitted.predict,
                               inputs.astype(np.float32), reference, mould_ids)
    return rows


def simulation_rows(sweep: pd.DataFrame) -> list[dict]:
    """Rows of a `tradeoff.sweep` table in this module's columns (the tight minimiser is a
    second reference, not a way of answering, and is left out)."""
    rows = []
    for r in sweep[sweep["role"] != "tight minimiser"].itertuples():
        family = r.role if r.role in ("long anneal", "reference") else str(r.solver)
        rows.append(dict(mould=int(r.mould), method=str(r.method), family=family,
                         seconds=float(r.seconds), field_mae=float(r.field_mae),
                         status=str(r.status)))
    return rows


def cost_table(rows) -> pd.DataFrame:
    """Per method: moulds, median and range of CPU seconds per mould and of the field MAE."""
    df = pd.DataFrame(rows)
    g = df.groupby(["family", "method"], sort=False)
    out = g.agg(moulds=("mould", "nunique"), ok=("status", lambda s: int((s == "ok").sum())),
                seconds=("seconds", "median"), seconds_min=("seconds", "min"),
                seconds_max=("seconds", "max"), field_mae=("field_mae", "median"),
                field_mae_min=("field_mae", "min"), field_mae_max=("field_mae", "max"))
    out = out.reset_index()
    order = {f: k for k, f in enumerate(FAMILIES)}
    return out.sort_values(["family", "seconds"], key=lambda c: c.map(order) if c.name == "family"
                           else c).reset_index(drop=True)


def chart(table: pd.DataFrame, path, title: str = "") -> None:
    """Median field MAE against median CPU seconds per mould (log x), one point per method with
    its range over moulds as error bars; the paper's costs as shaded marks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5.2))
    for row in table.itertuples():
        colour = FAMILIES.get(row.family, "grey")
        xerr = [[row.seconds - row.seconds_min], [row.seconds_max - row.seconds]]
        yerr = [[row.field_mae - row.field_mae_min], [row.field_mae_max - row.field_mae]]
        ax.errorbar(row.seconds, row.field_mae, xerr=xerr, yerr=yerr, fmt="o", color=colour,
                    ms=6, elinewidth=0.8, capsize=2)
        ax.annotate(row.method, (row.seconds, row.field_mae), fontsize=7, xytext=(4, 3),
                    textcoords="offset points")
    ax.axvspan(*PAPER_SIMULATION_SECONDS, color="tab:red", alpha=0.12)
    ax.axvline(PAPER_PREDICTION_SECONDS, color="tab:orange", ls="--", lw=1)
    ax.set_xscale("log")
    lo = min(table["seconds_min"].min(), PAPER_PREDICTION_SECONDS) / 3
    ax.set_xlim(max(lo, 1e-5), PAPER_SIMULATION_SECONDS[1] * 3)
    ax.set_ylim(bottom=0)
    top = ax.get_ylim()[1]
    ax.text(np.sqrt(np.prod(PAPER_SIMULATION_SECONDS)), 0.97 * top,
            "paper: 24-36 core-h\nper simulation", ha="center", va="top", fontsize=7,
            color="tab:red")
    ax.text(PAPER_PREDICTION_SECONDS * 1.15, 0.97 * top, "paper: ~0.1 s\nper prediction",
            va="top", fontsize=7, color="tab:orange")
    ax.set_xlabel("cost per mould, CPU seconds (one core)")
    ax.set_ylabel("field MAE vs long-anneal reference (normalised fields)")
    handles = [plt.Line2D([], [], color=c, marker="o", ls="", label=f)
               for f, c in FAMILIES.items() if f in set(table["family"])]
    ax.legend(handles=handles, fontsize=8, loc="center right")
    ax.grid(alpha=0.3, which="both", lw=0.4)
    ax.set_title(title or "cost per mould against error, same moulds, same reference", fontsize=10)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
