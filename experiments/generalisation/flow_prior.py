"""Where the held-out kinds' error lies, field by field, and how much of the density field a
contracting spring network's displacement explains (experiments/generalisation/README.md,
"The flow input").

- field_errors.csv: the leave-one-kind-out models of run.py's cache (--tag, e.g. n450_e120) on
  the kinds they held out, each field's noise-corrected squared error against the expected
  fields beside that field's noise ceiling (one simulation's), the family's mean over moulds;
- flow_prior.csv: flow_density (below; the product's at commit 346553f) at each strain of --strains against the
  expected density P of every test mould (the mean of its replicas, scaled to the same sum):
  the squared error over the field's variance, the family's median.

    python experiments/generalisation/flow_prior.py --pool POOL --cache CACHE --tag n450_e120
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

import run as R  # this folder's run.py (python puts a script's folder first on its path)
from condor.data.fields import FIELD_NAMES
from condor.files import write_text
from condor.data.inputs import spring_displacement
from condor.measures import estimators as est
from condor.measures.metrics import normalise_predicted

HERE = Path(__file__).resolve().parent
# the strain of least error against the expected density on every family (flow_prior.csv); the
# flow input of commit 346553f read flow_density at it (condor.data.inputs there)
FLOW_STRAIN = 0.16


def flow_density(masks: np.ndarray, strain: float = FLOW_STRAIN) -> np.ndarray:
    """(2, H, W) masks -> (1, H, W) float32: the mould's and posts' pixels (mass 1 each)
    carried by `strain` times the contracting spring network's displacement
    (`spring_displacement`; post pixels stay) and spread bilinearly over the pixels they land
    between: a first guess of where the cells' density goes. Its sum is the pixels' count
    (mass that would land outside the grid is kept at the edge pixel)."""
    masks = np.asarray(masks)
    H, W = masks.shape[1:]
    domain, fixed = (masks[0] > 0) | (masks[1] > 0), masks[1] > 0
    out = np.zeros((H, W), dtype=np.float64)
    if not domain.any():
        return out[None].astype(np.float32)
    u = spring_displacement(masks) if fixed.any() else np.zeros((H, W, 2))
    yy, xx = np.nonzero(domain)
    move = np.where(fixed[yy, xx], 0.0, strain)
    x = xx + move * u[yy, xx, 0]
    y = yy + move * u[yy, xx, 1]
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    for dy, dx, w in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)),
                      (1, 0, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(out, (np.clip(y0 + dy, 0, H - 1), np.clip(x0 + dx, 0, W - 1)), w)
    return out[None].astype(np.float32)


def field_errors(ds, cache: Path, tag: str) -> pd.DataFrame:
    test, fam = R.first_replicas(ds, "test"), R.families_of(ds)
    lab = R.reference_ensemble(ds, [int(i) for i in test if fam[i] != R.PAPER])
    labels = np.array([str(fam[int(m)]) for m in lab.moulds])
    truth = lab.normalised
    rows = []
    for kind in R.KINDS:
        found = sorted(cache.glob(f"without_{'_'.join(kind)}_{tag}_" + "?" * 12 + "_lab.npy"))
        if len(found) != 1:
            raise SystemExit(f"{len(found)} cached models without {'+'.join(kind)} of tag "
                             f"{tag!r} in {cache}: run run.py first")
        predicted = normalise_predicted(np.load(found[0])).astype(np.float64)
        for family in kind:
            sel = labels == family
            for k, name in enumerate(FIELD_NAMES):
                err = est.mse_against_expected(predicted[sel][:, k:k + 1],
                                               truth[sel][:, :, k:k + 1]).corrected
                noise = est.noise_ceiling(truth[sel][:, :, k:k + 1])
                rows.append({"family": family, "held_out": "+".join(kind), "field": name,
                             "squared_error": float(np.mean(err)),
                             "noise_ceiling": float(np.mean(noise))})
    return pd.DataFrame(rows)


def flow_prior(ds, strains) -> pd.DataFrame:
    fam = R.families_of(ds)
    replicated = set(int(m) for m in ds["replicated"].values)
    rows = []
    for i in R.first_replicas(ds, "test"):
        if int(i) not in replicated:
            continue
        masks = np.asarray(ds["inputs"].values[i])
        density = np.asarray(ds["fields_mean"].sel(replicated=int(i)).values[0], np.float64)
        for strain in strains:
            guess = flow_density(masks, strain)[0].astype(np.float64)
            guess *= density.sum() / guess.sum()
            rows.append({"mould": int(i), "family": str(fam[i]), "strain": strain,
                         "relative_error": float(np.mean((guess - density) ** 2)
                                                 / np.var(density))})
    per = pd.DataFrame(rows)
    return per.groupby(["family", "strain"], as_index=False)["relative_error"].median()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pool", type=Path, required=True, help="the pool's dataset.zarr")
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache/condor/generalisation")
    ap.add_argument("--tag", default="n450_e120", help="the models' cache tag")
    ap.add_argument("--strains", type=float, nargs="+",
                    default=[0, 0.04, 0.08, 0.12, 0.16, 0.2, 0.24, 0.3])
    ap.add_argument("--out", type=Path, default=HERE)
    a = ap.parse_args(argv)
    ds = R.open_store(a.pool)
    errors = field_errors(ds, a.cache, a.tag)
    write_text(a.out / "field_errors.csv", errors.to_csv(index=False, float_format="%.5g"))
    print(errors.assign(ratio=errors["squared_error"] / errors["noise_ceiling"])
          .pivot(index="family", columns="field", values="ratio").round(2).to_string())
    prior = flow_prior(ds, a.strains)
    write_text(a.out / "flow_prior.csv", prior.to_csv(index=False, float_format="%.5g"))
    print(prior.pivot(index="family", columns="strain", values="relative_error").round(3)
          .to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
