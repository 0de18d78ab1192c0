"""Which novelty score tells a surrogate's bad moulds: the four of condor.surrogate.novelty
(feature distance, transform disagreement, descriptor distance, and one over the prediction's
own reproducibility, inverse_spread), computed for every model of
run.py on every test mould, against whether the model's error on the mould exceeds one
simulation's scatter (moulds.csv: squared_error > noise).

  python experiments/generalisation/novelty.py --pool results/generalisation_pool/dataset.zarr \\
      --fresh results/generalisation_fresh/dataset.zarr

writes novelty_moulds.csv (every model x test mould: the scores beside the error) and
novelty.csv (per score: AUROC over the held-out families' and the other test moulds, the share
of bad moulds flagged at the threshold that raises at most 20% false alarms, and at the
threshold of 90% caught the false alarms). Cached under --cache (run.py's).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.data.dataset import mould_geometry  # noqa: E402
from condor.data.store import open_store  # noqa: E402
from condor.moulds.mould import Mould  # noqa: E402
from condor.surrogate import novelty  # noqa: E402
from condor.surrogate.predict import Predictor  # noqa: E402
from condor.surrogate.samples import model_inputs  # noqa: E402

HERE = Path(__file__).resolve().parent
FALSE_ALARMS = 0.2  # the verdict's budget of false alarms (issue 41's goal: 90% caught at 20%)
import run as study  # noqa: E402  (its own folder is on sys.path, as for any script)


def log(line: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} {line}", flush=True)


def geometry_descriptors(ds, ids) -> np.ndarray:
    box = float(ds.attrs["scene"]["box"])
    out = []
    for m in ids:
        polygon, tethers = mould_geometry(ds, int(m))
        out.append(novelty.descriptors(Mould(box=box, polygon=polygon, tethers=tethers)))
    return np.array(out)


def scores_of(predictor: Predictor, ds, ids, cache: Path, tag: str) -> dict:
    """features, disagreement and descriptors of moulds `ids` of ds for one checkpoint."""
    path = cache / f"{Path(predictor.path).stem}_novelty_{tag}.npz"
    if path.exists():
        with np.load(path) as data:
            return dict(data)
    position = {int(m): i for i, m in enumerate(np.asarray(ds["sample"].values))}
    pos = [position[int(m)] for m in ids]
    masks = model_inputs(ds, pos, "mask")
    lattice = model_inputs(ds, pos, "lattice") if predictor.needs_lattice else None
    x = novelty.network_inputs(predictor.inputs_kind, masks, lattice)
    feats = novelty.features(predictor.model, predictor.inputs_kind, x)
    tissue = masks.max(axis=1) > 0
    n_cells = np.asarray(ds["n_cells"].values)[pos]
    dis = novelty.disagreement(predictor.model, predictor.scaling, predictor.inputs_kind, x,
                               n_cells, tissue)
    out = {"features": feats, "disagreement": dis, "descriptors": geometry_descriptors(ds, ids)}
    np.savez(path, **out)
    return out


def inverse_spread_of(predictor: Predictor, ds, ids) -> np.ndarray:
    """condor.surrogate.novelty.inverse_spread of the checkpoint's predictions of moulds `ids`
    of ds (replica 0), as `condor predict` computes it."""
    position = {int(m): i for i, m in enumerate(np.asarray(ds["sample"].values))}
    pos = [position[int(m)] for m in ids]
    lattice = model_inputs(ds, pos, "lattice") if predictor.needs_lattice else None
    out = predictor(model_inputs(ds, pos, "mask"), n_cells=np.asarray(ds["n_cells"].values)[pos],
                    lattice=lattice)
    return novelty.inverse_spread(out.spread, out.normalised)


def flagging(score: np.ndarray, bad: np.ndarray) -> dict:
    """AUROC of `score` for `bad`, the share of bad caught at <= 20% false alarms, and the
    false alarms at >= 90% caught."""
    order = np.argsort(-score)
    bad_sorted = bad[order]
    tp = np.cumsum(bad_sorted) / max(bad.sum(), 1)
    fp = np.cumsum(~bad_sorted) / max((~bad).sum(), 1)
    auroc = float(np.trapezoid(np.concatenate([[0], tp]), np.concatenate([[0], fp])))
    caught = float(tp[fp <= 0.2].max(initial=0.0))
    alarms = float(fp[tp >= 0.9].min(initial=1.0))
    return {"auroc": auroc, "caught_at_20pct_false_alarms": caught,
            "false_alarms_at_90pct_caught": alarms, "n_bad": int(bad.sum()),
            "n_good": int((~bad).sum())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pool", type=Path, required=True)
    ap.add_argument("--fresh", type=Path, required=True)
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache/condor/generalisation")
    ap.add_argument("--out", type=Path, default=HERE)
    ap.add_argument("--lab-share", type=float, default=0.5)
    ap.add_argument("--n-train", type=int, default=study.N_TRAIN,
                    help="the models' training moulds (run.py's --n-train)")
    ap.add_argument("--extra", type=Path, default=None,
                    help="run.py's --extra: the store its models took more training moulds from")
    ap.add_argument("--extra-share", type=float, default=0.25, help="run.py's --extra-share")
    ap.add_argument("--extra-lab-share", type=float, default=1.0,
                    help="run.py's --extra-lab-share")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE",
                    help="run.py's --set (the models' names follow it)")
    a = ap.parse_args(argv)
    ds, fresh = open_store(a.pool), open_store(a.fresh)
    extra = open_store(a.extra) if a.extra is not None else None
    suffix = f"_extra{a.extra_share:g}" if extra is not None else ""  # run.py's names
    suffix += study.with_settings({}, a.set)[1]
    per = pd.read_csv(a.out / "moulds.csv")
    rows = []
    for name, spec in study.models(ds, a.lab_share, a.n_train).items():
        name += suffix
        # run.train_model's names: NAME[_eEPOCHS]_KEY.pt (not NAME_n450_..., NAME_extra...)
        own = re.compile(rf"^{re.escape(name)}(_e\d+)?_[0-9a-f]{{12}}\.pt$")
        checkpoints = sorted(p for p in a.cache.glob(f"{name}_*.pt") if own.match(p.name))
        mine = per[per["model"] == name]
        if not checkpoints or mine.empty:
            continue
        predictor = Predictor(checkpoints[-1], device="cpu", precision="float32")
        train_ids, extra_ids = study.training_ids(ds, spec, extra, a.extra_share,
                                                  a.extra_lab_share)
        bank = scores_of(predictor, ds, train_ids, a.cache, "train")
        if extra_ids:  # the extra store's training moulds are the model's too
            more = scores_of(predictor, extra, extra_ids, a.cache, "train_extra")
            bank = {k: np.concatenate([bank[k], more[k]]) for k in bank}
        for group, store in (("pool", ds), ("fresh", fresh)):
            subset = mine[mine["family"].eq(study.FRESH) == (group == "fresh")]
            if subset.empty:
                continue
            s = scores_of(predictor, store, subset["mould"].to_numpy(), a.cache, group)
            part = subset.copy()
            part["feature_distance"] = novelty.knn_distance(bank["features"], s["features"])
            part["disagreement"] = s["disagreement"]
            part["descriptor_distance"] = novelty.knn_distance(bank["descriptors"],
                                                               s["descriptors"])
            part["inverse_spread"] = inverse_spread_of(predictor, store,
                                                       subset["mould"].to_numpy())
            rows.append(part)
        log(f"novelty of {name}")
    table = pd.concat(rows, ignore_index=True)
    table["bad"] = table["squared_error"] > table["noise"]
    table["held_out_mould"] = [f in h.split("+") for f, h in zip(table["family"], table["held_out"])]
    table.to_csv(a.out / "novelty_moulds.csv", index=False)
    summary = []
    for scope, frame in (("every model x test mould", table),
                         ("leave-one-out models", table[table["held_out"] != "none"])):
        for score in ("feature_distance", "disagreement", "descriptor_distance",
                      "inverse_spread"):
            summary.append({"scope": scope, "score": score,
                            **flagging(frame[score].to_numpy(), frame["bad"].to_numpy())})
    summary = pd.DataFrame(summary)
    summary.to_csv(a.out / "novelty.csv", index=False)
    print(summary.to_string(index=False))
    lofo = table[table["held_out"] != "none"]
    chosen = summary[(summary["scope"] == "leave-one-out models")
                     & summary["score"].isin(novelty.SCORES)].sort_values(
        "auroc", ascending=False).iloc[0]["score"]  # among those `condor predict` computes
    calibration, threshold, rates = calibrate(lofo, chosen)
    calibration.to_csv(a.out / "novelty_calibration.csv", index=False)
    (a.out / "novelty_choice.json").write_text(json.dumps(
        {"score": chosen, "threshold": threshold, "n_moulds": int(len(lofo)), **rates},
        indent=1) + "\n")
    print(f"chosen score {chosen}: threshold {threshold:.3g}: {rates}")
    print(calibration.to_string(index=False))
    return 0


def calibrate(frame: pd.DataFrame, score: str, bins: int = 6):
    """The product's calibration of `score` (condor.findings.NOVELTY_COLUMNS): per quantile bin
    of the score, the error over one simulation's scatter (median, 10-90%) and the share above
    1; the threshold: the lowest score that raises at most FALSE_ALARMS of false alarms (the
    issue's budget), or, where that is higher, the lowest bin edge above which every bin's
    median error is at least one simulation's scatter (the rule before 2026-12-07, kept in
    `threshold_median_rule`), so that "inside" means the moulds of that novelty lay within it
    (issue 41); with the share of the moulds above the scatter it flags and the false alarms,
    and, for comparison, the false alarms of the lowest threshold that flags 90% of them."""
    values = frame[score].to_numpy()
    ratio = np.sqrt(np.maximum(frame["squared_error"], 0) / frame["noise"]).to_numpy()
    bad = frame["bad"].to_numpy()
    edges = np.quantile(values, np.linspace(0, 1, bins + 1))
    edges[0], edges[-1] = -np.inf, np.inf
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        inside = (values > lo) & (values <= hi)
        r = ratio[inside]
        rows.append({"score_lo": lo, "score_hi": hi, "n_moulds": int(inside.sum()),
                     "ratio_median": float(np.median(r)), "ratio_lo": float(np.quantile(r, 0.1)),
                     "ratio_hi": float(np.quantile(r, 0.9)),
                     "share_above_ceiling": float(bad[inside].mean())})
    table = pd.DataFrame(rows)
    above = (table["ratio_median"] >= 1.0).to_numpy()
    k = len(above)
    while k > 0 and above[k - 1]:
        k -= 1
    median_rule = float(table["score_lo"].iloc[k]) if k < len(above) else float("inf")

    def rates(t):
        return (float((values[bad] > t).mean()), float((values[~bad] > t).mean()))
    budget = min((t for t in np.unique(values) if rates(t)[1] <= FALSE_ALARMS), default=np.inf)
    threshold = min(median_rule, float(budget))
    caught, alarms = rates(threshold)
    at_90 = min((t for t in np.unique(values) if rates(t)[0] >= 0.9), key=lambda t: rates(t)[1])
    return (table, threshold,
            {"caught": caught, "false_alarms": alarms, "n_bad": int(bad.sum()),
             "n_good": int((~bad).sum()), "threshold_median_rule": median_rule,
             "threshold_at_90pct_caught": float(at_90),
             "false_alarms_at_90pct_caught": rates(at_90)[1]})


if __name__ == "__main__":
    sys.exit(main())
