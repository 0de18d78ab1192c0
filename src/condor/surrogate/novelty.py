"""How new a mould is to a trained surrogate, measured three ways (experiments/generalisation
chose among them by how well each flags the moulds whose error exceeds one simulation's scatter):

- `features`: the network's bottleneck (the encoder's deepest activations, averaged over the
  grid and the 8 planar transforms the prediction symmetrises over), one vector a mould;
  `feature_distance`: the mean distance of a mould's vector to its k nearest among the training
  moulds', over the training moulds' own (leave-one-out) distance, so 1 is typical of them;
- `disagreement`: how much the 8 planar transforms' predictions, moved back, disagree: the
  RMS over transforms and tissue pixels of their difference from their mean, over the mean's
  RMS there (0 for a network exactly equivariant on this mould);
- `descriptors`: a mould's geometry in a few numbers (area, perimeter, extent, posts, their
  radii and spacing, holes), and `descriptor_distance` as `feature_distance` over them.

A checkpoint trained by condor carries its training moulds' feature vectors and descriptors
(`condor.surrogate.train` stores them: `bank`), so `condor predict` scores a new mould alone.

A fourth score is no distance at all: `inverse_spread`, one over the RMS of the prediction's
own spread map over the tissue (in raw units: the printed reproducibility times N_c over the
grid's pixels). Whether the surrogate's error exceeds one simulation's scatter depends mostly
on how small that scatter is, and the spread map predicts it: measured on the held-out kinds it tells those moulds far
better than the distances (experiments/generalisation, "The predicted scatter as a verdict").
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import shapely
import torch

from condor.data.inputs import derived_channels

from .inference import decode, run_network
from .samples import DERIVED_INPUTS, INPUT_VARIABLES, N_SYMMETRIES, apply_symmetry, resample_inputs

PLANAR = N_SYMMETRIES // 2
K_NEAREST = 5
DESCRIPTORS = ("area", "perimeter_ratio", "extent", "aspect", "n_posts", "post_radius_max",
               "post_radius_min", "post_spacing", "post_to_wall", "post_area", "holes",
               "hole_area")


def network_inputs(inputs_kind: str, masks: np.ndarray, lattice=None) -> np.ndarray:
    """The network's input channels (S, C, H, W) at the native grid for masks (S, 2, H, W), as
    a network of `inputs_kind` reads them (lattice given when it reads the lattice)."""
    by_variable = {"inputs": masks, "lattice": lattice}
    for name in DERIVED_INPUTS:
        if name in INPUT_VARIABLES[inputs_kind]:
            by_variable[name] = derived_channels(masks, name)
    return np.concatenate([np.asarray(by_variable[name], dtype=np.float32)
                           for name in INPUT_VARIABLES[inputs_kind]], axis=1)


def _moved(model, inputs_kind: str, x: np.ndarray) -> list[torch.Tensor]:
    x = resample_inputs(np.asarray(x, dtype=np.float32), model.cfg.size, inputs_kind)
    t = torch.from_numpy(np.ascontiguousarray(x)).to(next(model.parameters()).device)
    return [apply_symmetry(k, inputs=t, input_kind=inputs_kind)[0] for k in range(PLANAR)]


def features(model, inputs_kind: str, x: np.ndarray, batch_size: int = 4) -> np.ndarray:
    """(S, C) bottleneck vectors of network inputs x (S, C_in, H, W) (`network_inputs`) of the
    U-Net `model`: its deepest encoder block's output averaged over its grid and the 8 planar
    transforms."""
    was_training = model.training
    model.eval()
    captured = []
    hook = model.down[-1].register_forward_hook(
        lambda module, args, out: captured.append(out.float().mean(dim=(-2, -1))))
    out = []
    try:
        with torch.inference_mode():
            for start in range(0, len(x), batch_size):
                captured.clear()
                moved = _moved(model, inputs_kind, x[start:start + batch_size])
                run_network(model, torch.cat(moved))
                vectors = captured[0].reshape(PLANAR, -1, captured[0].shape[-1])
                out.append(vectors.mean(dim=0).cpu().numpy())
    finally:
        hook.remove()
        model.train(was_training)
    return np.concatenate(out).astype(np.float64)


def disagreement(model, scaling, inputs_kind: str, x: np.ndarray, n_cells,
                 tissue: np.ndarray) -> np.ndarray:
    """(S,) the 8 planar transforms' disagreement (module docs) for network inputs x (S, C, H,
    W), N_c per mould, and each mould's tissue pixels (S, H, W) at the model's grid size."""
    model = model.eval()
    n_cells = np.asarray(n_cells, dtype=np.float64).reshape(-1)
    out = np.empty(len(x))
    with torch.inference_mode():
        for i in range(len(x)):
            moved = _moved(model, inputs_kind, x[i:i + 1])
            back = []
            for k, m in enumerate(moved):
                y, _ = decode(scaling, run_network(model, m).contiguous().double(),
                              n_cells[i:i + 1].astype(np.float32))
                back.append(apply_symmetry(k, fields=y.cpu().numpy(), inverse=True)[1][0])
            back = np.stack(back)  # (8, 8, H, W)
            mask = np.broadcast_to(tissue[i], back.shape[1:])
            mean = back.mean(axis=0)
            spread = np.sqrt(np.mean((back - mean)[:, mask] ** 2))
            out[i] = spread / max(np.sqrt(np.mean(mean[mask] ** 2)), 1e-12)
    return out


def descriptors(mould) -> np.ndarray:
    """The mould's geometry in DESCRIPTORS' numbers, lengths in box sides (so any scene)."""
    box = float(mould.box)
    polygon = mould.polygon
    tethers = np.asarray(mould.tethers, dtype=float).reshape(-1, 3)
    xmin, ymin, xmax, ymax = polygon.bounds
    rect = polygon.minimum_rotated_rectangle
    edges = np.diff(np.asarray(rect.exterior.coords)[:3], axis=0)
    sides = np.sort(np.hypot(edges[:, 0], edges[:, 1]))
    n = len(tethers)
    walls, spacing = np.zeros(1), 0.0
    if n:
        walls = shapely.distance(polygon.boundary, shapely.points(tethers[:, :2])) - tethers[:, 2]
        if n > 1:
            d = np.linalg.norm(tethers[:, None, :2] - tethers[None, :, :2], axis=2)
            np.fill_diagonal(d, np.inf)
            spacing = float(np.median(d.min(axis=1)))
    holes = [shapely.Polygon(ring) for ring in polygon.interiors]
    return np.array([
        polygon.area / box**2,
        polygon.length / (2 * math.sqrt(math.pi * polygon.area)),
        max(xmax - xmin, ymax - ymin) / box,
        sides[1] / max(sides[0], 1e-12),
        n,
        tethers[:, 2].max() / box if n else 0.0,
        tethers[:, 2].min() / box if n else 0.0,
        spacing / box,
        float(np.min(walls)) / box if n else 0.0,
        float(np.sum(np.pi * tethers[:, 2] ** 2)) / polygon.area if n else 0.0,
        len(holes),
        sum(h.area for h in holes) / box**2,
    ])


def knn_distance(bank: np.ndarray, query: np.ndarray, k: int = K_NEAREST,
                 scale: np.ndarray | None = None) -> np.ndarray:
    """(Q,) mean Euclidean distance of each query row to its k nearest rows of bank (N, D),
    each dimension divided by `scale` (default: the bank's standard deviation), over the bank
    rows' own mean distance to their k nearest others (leave one out): 1 is typical."""
    bank, query = np.asarray(bank, np.float64), np.atleast_2d(np.asarray(query, np.float64))
    if scale is None:
        scale = bank.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    b, q = bank / scale, query / scale
    k = min(k, len(b) - 1)

    def nearest(a, exclude_self):
        d = np.sqrt(np.maximum(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1), 0.0))
        if exclude_self:
            np.fill_diagonal(d, np.inf)
        return np.sort(d, axis=1)[:, :k].mean(axis=1)

    typical = float(np.median(nearest(b, True)))
    return nearest(q, False) / max(typical, 1e-12)


def training_bank(model, inputs_kind: str, dataset, positions) -> dict:
    """What a checkpoint keeps of its training moulds to score a new one (`condor.surrogate.
    train` stores it when training ends): their feature vectors (float16, (N, C)) and, when
    the store holds the moulds' geometry, their descriptors ((N, len(DESCRIPTORS))), as
    tensors (a checkpoint loads with torch's weights_only)."""
    from condor.data.dataset import mould_geometry
    from condor.data.store import StoreError
    from condor.moulds.mould import Mould

    from .samples import model_inputs

    positions = np.asarray(positions)
    x = model_inputs(dataset, positions, inputs_kind)
    bank = {"features": torch.from_numpy(features(model, inputs_kind, x).astype(np.float16))}
    try:
        box = float(dataset.attrs["scene"]["box"])
        rows = [descriptors(Mould(box=box, polygon=p, tethers=t))
                for p, t in (mould_geometry(dataset, int(i)) for i in positions)]
        bank["descriptors"] = torch.from_numpy(np.array(rows, dtype=np.float64))
    except (StoreError, KeyError, ValueError, TypeError):  # a store without the geometry
        pass
    return bank


# --- what condor predict says of a mould ------------------------------------------------------

def bank_of(state: dict) -> dict | None:
    """The training bank a checkpoint carries (training_bank), as numpy; None for a checkpoint
    trained before it."""
    bank = state.get("novelty")
    if not bank or "features" not in bank:
        return None
    return {k: np.asarray(v.float().numpy() if hasattr(v, "numpy") else v, dtype=np.float64)
            for k, v in bank.items()}


def training_ranges(bank: dict):
    """The checkpoint's training moulds' ranges (condor.moulds.domain.TrainingRanges) from its
    bank's descriptors; None without them."""
    from condor.moulds.domain import TrainingRanges

    d = bank.get("descriptors") if bank else None
    if d is None or not len(d):
        return None
    col = {name: d[:, i] for i, name in enumerate(DESCRIPTORS)}
    radii = np.concatenate([col["post_radius_min"][col["n_posts"] > 0],
                            col["post_radius_max"][col["n_posts"] > 0]])
    return TrainingRanges(area=(float(col["area"].min()), float(col["area"].max())),
                          extent=float(col["extent"].max()),
                          posts=(int(col["n_posts"].min()), int(col["n_posts"].max())),
                          post_radius=(float(radii.min()), float(radii.max())) if len(radii)
                          else (0.0, 0.0),
                          source=f"its {len(d)} training moulds")


SCORES = ("feature_distance", "inverse_spread")  # the scores `condor predict` can compute


def inverse_spread(spread, normalised) -> np.ndarray:
    """(S,) one over the RMS of each prediction's spread map in raw units (Prediction.spread,
    (S, 8, H, W), cells a pixel like Prediction.raw) over its tissue pixels (normalised P > 0):
    the reproducibility `condor predict` prints (normalised units) times N_c over the grid's
    pixels, reversed, so that a larger score is a tighter predicted scatter (one simulation's,
    which the surrogate's error more easily exceeds); NaN where a prediction covers no pixel.
    In raw units it told the moulds above one simulation's scatter better than in normalised
    ones (AUROC 0.84 against 0.75; experiments/generalisation)."""
    spread = np.asarray(spread, dtype=np.float64)
    tissue = np.asarray(normalised)[:, 0] > 0
    out = np.full(len(spread), np.nan)
    for k in range(len(spread)):
        if tissue[k].any():
            out[k] = 1.0 / math.sqrt(float((spread[k][:, tissue[k]] ** 2).mean()))
    return out


def mould_novelty(model, inputs_kind: str, bank: dict, x: np.ndarray) -> np.ndarray:
    """(S,) feature distance (module docs) of network inputs x (S, C, H, W) to the bank."""
    return knn_distance(bank["features"], features(model, inputs_kind, x))


# what a verdict advises where the surrogate may be off, and what it says where `predict`
# checks the mould by simulation anyway (condor.stages.check: by default at the default scene)
CHECK_ADVICE = "check it by simulation (--check 4)"
CHECKED_ADVICE = "the check by simulation below says how far"


def novelty_verdict(score: float, calibration: pd.DataFrame, threshold: float,
                    provenance: str, name: str = "feature_distance",
                    distance: float | None = None,
                    advice: str = CHECK_ADVICE) -> tuple[str, dict]:
    """Short lines on a mould's calibrated `score` (`name`: "feature_distance", its novelty, or
    "inverse_spread", one over the RMS of its spread map; the feature `distance` beside the
    latter): inside or outside (above `threshold`), and the error measured on moulds of that
    score (the bin of `calibration` it falls in); and the numbers, for the prediction's
    attributes."""
    rows = calibration.sort_values("score_lo").reset_index(drop=True)
    k = int(np.clip(np.searchsorted(rows["score_hi"].to_numpy(), score), 0, len(rows) - 1))
    row = rows.iloc[k]
    outside = score > threshold
    numbers = {"score": name, "threshold": float(threshold), "outside": bool(outside),
               "expected_error_ratio": float(row.ratio_median),
               "expected_error_ratio_lo": float(row.ratio_lo),
               "expected_error_ratio_hi": float(row.ratio_hi)}
    measured = (f"moulds {'this new' if name == 'feature_distance' else 'this tight'} lay "
                f"{row.ratio_median:.2g}x [{row.ratio_lo:.2g}, {row.ratio_hi:.2g}] one "
                f"simulation's scatter from their expected fields, "
                f"{row.share_above_ceiling:.0%} above it ({provenance})")
    if name == "feature_distance":
        numbers["novelty"] = float(score)
        state = (f"OUTSIDE what it learnt: {advice}" if outside else
                 "inside what it learnt")
        return (f"novelty {score:.2f} (1 is typical of its training moulds, flagged above "
                f"{threshold:.2g}): {state}\n  {measured}"), numbers
    numbers["inverse_spread"] = float(score)
    if distance is not None:
        numbers["novelty"] = float(distance)
    state = ("TIGHT: one simulation strays so little that the surrogate's error may exceed "
             f"it: {advice}" if outside else
             "its error is likely within one simulation's scatter")
    new = "" if distance is None else (f"novelty {distance:.2f} (1 is typical of its "
                                       "training moulds); ")
    return (f"{new}tightness {score:.3g} (one over its spread map's RMS in cells a pixel, "
            f"flagged above {threshold:.3g}): {state}\n  {measured}"), numbers


def never_drawn_sentence(moulds: pd.DataFrame, provenance: str) -> str | None:
    """One line on kinds of mould that no training source draws (the `never_drawn` finding,
    experiments/unseen_kinds: a default run's checkpoint checked by simulation on each mould,
    one row a mould with its `kind`, error over one simulation's scatter `ratio` and
    `tension_bias`): how many moulds and kinds, the median ratio and how many lay above 1, the
    median |tension bias| and the largest, with its kind. None without rows."""
    if moulds.empty:
        return None
    ratio = moulds["ratio"].astype(float)
    bias = moulds["tension_bias"].astype(float)
    worst = moulds.loc[bias.abs().idxmax()]
    return (f"on {len(moulds)} moulds of {moulds['kind'].nunique()} kinds that no training source "
            f"draws (T, H, U shapes, stars, ...), the default recipe's error was a median "
            f"{ratio.median():.2f}x one simulation's scatter ({int((ratio > 1).sum())} above it) "
            f"and its mean tension off by a median of {bias.abs().median():.0%}, up to "
            f"{float(worst['tension_bias']):+.0%} (a {worst['kind']}) ({provenance})")


def unseen_kinds_sentence(generalisation: pd.DataFrame, provenance: str,
                          advice: str = CHECK_ADVICE) -> str | None:
    """One line on the whole-mould mean tension of kinds of mould the surrogate never trained
    on, from the generalisation finding's held-out rows (a family scored by a model that did not
    see it): the median |bias| over the families and the largest, with its family. The feature
    distance does not tell these moulds well (novelty's AUROC), so `predict` says it whatever the
    verdict. None without held-out rows."""
    held = generalisation[[str(f) in str(h).split("+") for f, h in
                           zip(generalisation["family"], generalisation["held_out"])]]
    if held.empty:
        return None
    bias = held["tension_bias"].astype(float)
    worst = held.loc[bias.abs().idxmax()]
    return (f"on kinds of mould it never trained on, its mean tension was off by a median of "
            f"{bias.abs().median():.0%} over {len(held)} families, up to "
            f"{float(worst['tension_bias']):+.0%} (family {worst['family']}) ({provenance}): a new kind "
            "of mould's whole-mould numbers deserve a check by simulation"
            + ("" if advice == CHECKED_ADVICE else " (--check 4)"))
