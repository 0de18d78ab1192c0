"""Where on the mould a checkpoint's excess error lies: each test mould's squared error against
its expected fields (the finite-replica noise removed, per pixel), split by pixel class and by
field, family by family:

  python experiments/generalisation/where_errors.py --store STORE --checkpoint PATH --out CSV

Pixel classes (from the store's lattice channels, in column units):
`post` (the fixed cells' channel >= 0.25), `beside_post` (within RING px of a post pixel),
`edge` (within RING px of the mould's outside, the initial cells' channels < 0.05, not beside a
post), `inside` (the rest of the initial cells), `outside` (where no initial cell was). Each row
gives a class's share of the family's summed excess squared error (plain - noise), its share of
the pixels, and the same split by field, in units of the family's summed one-simulation squared
error (a family's `excess_over_ceiling` sum to (error / noise ceiling)^2 over its classes).
With --maps it also draws the maps of some families' moulds.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from scipy import ndimage  # noqa: E402

from condor.data.fields import FIELD_NAMES  # noqa: E402
from condor.data.store import open_store  # noqa: E402
from condor.measures import estimators as est  # noqa: E402
from condor.measures.metrics import normalise_predicted  # noqa: E402
from condor.studies.recipes import reference_ensemble  # noqa: E402
from condor.studies.scoring import predict_replica_moulds  # noqa: E402

import run as study  # noqa: E402  (its own folder is on sys.path, as for any script)

RING = 3  # px
CLASSES = ("post", "beside_post", "edge", "inside", "outside")


def pixel_classes(lattice: np.ndarray) -> np.ndarray:
    """(M, H, W) int: each pixel's index into CLASSES, from lattice channels (M, 2, H, W)."""
    out = np.empty(lattice.shape[:1] + lattice.shape[2:], dtype=np.int64)
    for m, (mobile, fixed) in enumerate(lattice):
        post = fixed >= 0.25
        cells = (mobile + fixed) >= 0.05
        near_post = ndimage.binary_dilation(post, iterations=RING) & ~post
        near_out = ndimage.binary_dilation(~cells, iterations=RING) & cells & ~post & ~near_post
        c = np.full(mobile.shape, CLASSES.index("inside"))
        c[~cells] = CLASSES.index("outside")
        c[near_out] = CLASSES.index("edge")
        c[near_post] = CLASSES.index("beside_post")
        c[post] = CLASSES.index("post")
        out[m] = c
    return out


def draw_maps(path: Path, chosen, labels, moulds, mean, pred, truth) -> None:
    """One row a chosen mould: the expected P, the prediction's error in P, one replica's,
    the expected Sx2 - Sy2, the prediction's error in it, and in SxSy."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(chosen), 6, figsize=(15, 2.6 * len(chosen)), squeeze=False)
    for row, m in zip(axes, chosen):
        aniso = mean[m, 2] - mean[m, 3]
        panels = [("expected P", mean[m, 0]), ("predicted - expected P", pred[m, 0] - mean[m, 0]),
                  ("replica 0 - expected P", truth[m, 0, 0] - mean[m, 0]),
                  ("expected Sx2 - Sy2", aniso),
                  ("its prediction's error", pred[m, 2] - pred[m, 3] - aniso),
                  ("predicted - expected SxSy", pred[m, 5] - mean[m, 5])]
        for ax, (title, image) in zip(row, panels):
            if title == "expected P":
                ax.imshow(image, cmap="viridis")
            else:
                v = float(np.nanmax(np.abs(image))) or 1.0
                ax.imshow(image, cmap="RdBu_r", vmin=-v, vmax=v)
            ax.set_title(f"{labels[m]} {moulds[m]}: {title}", fontsize=7)
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=70)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", type=Path, required=True)
    ap.add_argument("--checkpoint", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--maps", type=Path, default=None, metavar="PNG",
                    help="also draw, for the test moulds of --families, the expected density "
                         "and Sx2 - Sy2 beside the prediction's error and one replica's")
    ap.add_argument("--families", nargs="+", default=["side_anchored", "frame", "cross"])
    a = ap.parse_args(argv)
    ds = open_store(a.store)
    fam = study.families_of(ds)
    ids = [int(i) for i in study.first_replicas(ds, "test")]
    ens = reference_ensemble(ds, ids)
    labels = np.array([str(fam[int(m)]) for m in ens.moulds])
    truth = ens.normalised  # (M, R, 8, H, W)
    raw = predict_replica_moulds(a.checkpoint, ds, list(ens.moulds))
    pred = normalise_predicted(raw).astype(np.float64)
    mean = est.replica_mean(truth)
    one_sim = est.replica_variance(truth)  # one simulation's expected squared error
    noise = one_sim / est.replica_counts(truth)[:, None, None, None]  # the mean's
    excess = (pred - mean) ** 2 - noise  # (M, 8, H, W)
    classes = pixel_classes(np.asarray(ens.lattice, dtype=np.float64))

    rows = []
    for family in dict.fromkeys(labels):
        idx = labels == family
        family_excess = excess[idx]
        total = family_excess.sum()
        ceiling = one_sim[idx].sum()
        for k, name in enumerate(CLASSES):
            sel = classes[idx] == k  # (m, H, W)
            per_field = [family_excess[:, f][sel].sum() for f in range(len(FIELD_NAMES))]
            rows.append({"family": family, "class": name, "pixel_share": sel.mean(),
                         "excess_share": float(np.sum(per_field) / total),
                         "excess_over_ceiling": float(np.sum(per_field) / ceiling),
                         **{f"{f}_over_ceiling": v / ceiling
                            for f, v in zip(FIELD_NAMES, per_field)}})
    if a.maps is not None:
        draw_maps(a.maps, [i for i, f in enumerate(labels) if f in a.families], labels,
                  ens.moulds, mean, pred, truth)
    table = pd.DataFrame(rows)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(a.out, index=False, float_format="%.4g")
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(table.round(3).to_string(index=False))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
