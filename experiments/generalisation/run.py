"""Generalisation to lab families the surrogate never trained on, and the lab share of the
training set (experiments/generalisation/README.md).

The pool (`pool.yaml`, built by the workflow: `snakemake --configfile
experiments/generalisation/pool.yaml --until dataset`) holds 504 training moulds (half from the
lab families), 56 validation moulds, 60 paper test moulds and 80 lab test moulds (8 a family),
4 replicas a test mould. `fresh.yaml` builds 24 paper moulds of a generator seed no run uses
(7), 4 replicas each. Every model trains with the workflow's default recipe (the `unet` preset
of config/config.yaml) on N_TRAIN training moulds of the pool:

- mixture: LAB_SHARES of them from the lab families (each family an equal share), the rest
  from the paper's generator;
- lofo (leave one kind out): the chosen share, with no mould of a kind (two kindred families,
  KINDS) in training or validation;
- each model is scored on the pool's paper test set, the lab test set family by family, and the
  fresh-seed moulds, against the replicas' expected fields with the noise removed
  (condor.studies.families: error [95%], noise ceiling, mean tension bias [95%]).

  python experiments/generalisation/run.py --pool results/generalisation_pool/dataset.zarr \\
      --fresh results/generalisation_fresh/dataset.zarr --steps mixture lofo

writes mixture.csv, generalisation.csv (docs/data/generalisation.csv's columns: `family` the
moulds scored, `held_out` the families the model never saw, "none" for the mixture models) and
moulds.csv (every model on every test mould: its squared error, the mould's noise, the mean
tension ratio, and the novelty scores the domain verdict was chosen among: novelty.py).
Checkpoints and predictions are cached under --cache (resumable: a killed run picks up).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import xarray as xr  # noqa: E402

from condor.config import Config  # noqa: E402
from condor.data.store import open_store  # noqa: E402
from condor.measures import estimators as est  # noqa: E402
from condor.measures.metrics import normalise_predicted  # noqa: E402
from condor.moulds.mould import PAPER  # noqa: E402
from condor.studies.families import family_rows, mean_tension  # noqa: E402
from condor.studies.recipes import reference_ensemble  # noqa: E402
from condor.studies.scoring import predict_replica_moulds  # noqa: E402
from condor.surrogate.train import train as train_loop  # noqa: E402
from condor.surrogate.variants import SETTING_KEYS, train_config, workflow_variants  # noqa: E402

HERE = Path(__file__).resolve().parent
N_TRAIN = 250  # training moulds of every model (the pool holds 252 of each source)
LAB_SHARES = (0.0, 0.25, 0.5, 0.75)
# lofo's held-out kinds: each pair of kindred families leaves together, so that a family is not
# learnt from its sibling (a strip from the dog-bones, a ring from the annuli)
KINDS = (("strip", "dogbone"), ("ring", "annulus"), ("polygon", "cross"), ("spline", "oval"),
         ("frame", "side_anchored"))
FRESH = "fresh seed"  # the family label of the fresh generator seed's moulds
EXTRA_OFFSET = 1_000_000  # added to the extra store's mould ids and samples in a training set
TRAINING_DIMS = {"sample", "field", "y", "x", "channel", "cell"}  # what training reads


def log(line: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} {line}", flush=True)


def families_of(ds) -> np.ndarray:
    """Each sample's family (the store's per-sample `family`)."""
    return np.asarray(ds["family"].values).astype(str)


def first_replicas(ds, split: str) -> np.ndarray:
    """Mould ids of the split's usable replica-0 samples (sample == mould), in id order."""
    ok = np.asarray(ds["status"].values).astype(str) == "ok"
    first = np.asarray(ds["replica"].values) == 0
    labels = np.asarray(ds["split"].values).astype(str)
    return np.asarray(ds["mould"].values)[ok & first & (labels == split)]


def choose(ds, split: str, n: int, lab_share: float, exclude: tuple[str, ...] = ()) -> list[int]:
    """n moulds of `split`: round(lab_share x n) lab moulds, the families in turn (their moulds
    in id order), the families in `exclude` left out; the rest paper moulds in id order."""
    ids = first_replicas(ds, split)
    family = families_of(ds)[ids]
    n_lab = int(round(lab_share * n))
    paper = [int(i) for i in ids[family == PAPER]][: n - n_lab]
    by_family = {f: [int(i) for i in ids[family == f]] for f in sorted(set(family) - {PAPER})
                 if f not in exclude}
    lab: list[int] = []
    depth = 0
    while len(lab) < n_lab and any(len(v) > depth for v in by_family.values()):
        lab += [v[depth] for v in by_family.values() if len(v) > depth][: n_lab - len(lab)]
        depth += 1
    if len(paper) + len(lab) < n:
        raise ValueError(f"the pool's {split} split holds too few moulds for {n} at a lab share "
                         f"of {lab_share} without {exclude}")
    return sorted(paper + lab)


def relabelled(ds, train_ids, val_ids):
    """ds with train = train_ids, val = val_ids (every replica of a mould takes its label),
    test kept, everything else unused."""
    mould = np.asarray(ds["mould"].values)
    split = np.asarray(ds["split"].values).astype("<U8").copy()
    keep_test = split == "test"
    split[:] = "unused"
    split[np.isin(mould, train_ids)] = "train"
    split[np.isin(mould, val_ids)] = "val"
    split[keep_test] = "test"
    return ds.assign(split=("sample", split))


def with_extra(ds, extra, extra_ids):
    """ds's training variables (those of TRAINING_DIMS) with the `extra_ids` moulds of the
    extra store appended, their mould ids and samples offset by EXTRA_OFFSET, labelled
    "unused" (`relabelled` makes them training moulds)."""
    names = [n for n, v in ds.data_vars.items() if set(v.dims) <= TRAINING_DIMS and n in extra]
    mine = extra[names].isel(sample=[int(i) for i in extra_ids])
    mine = mine.assign_coords(sample=mine["sample"].values + EXTRA_OFFSET)
    mine["mould"] = mine["mould"] + EXTRA_OFFSET
    return xr.concat([ds[names], mine], dim="sample", data_vars="all", coords="minimal",
                     compat="override", join="override", combine_attrs="override")


def models(ds, lab_share_lofo: float, n_train: int = N_TRAIN,
           single: bool = False) -> dict[str, dict]:
    """Every model of the study: name -> {lab_share, held_out, n_train}; the mixture models'
    and, with n_train other than N_TRAIN, the size models' (the named share at n_train). The
    lofo models hold out a kind (KINDS) each, or with `single` one family each (its sibling
    trained on)."""
    tag = "" if n_train == N_TRAIN else f"_n{n_train}"
    out = {f"mixture_{share:g}{tag}": {"lab_share": share, "held_out": "none", "n_train": n_train}
           for share in sorted({*LAB_SHARES, lab_share_lofo})}
    known = set(families_of(ds)) - {PAPER}
    for kind in ([(f,) for pair in KINDS for f in pair] if single else KINDS):
        if not set(kind) <= known:
            raise ValueError(f"the pool holds no moulds of {sorted(set(kind) - known)}")
        out[f"without_{'_'.join(kind)}{tag}"] = {"lab_share": lab_share_lofo,
                                                 "held_out": "+".join(kind), "n_train": n_train}
    return out


def held_out(spec: dict) -> tuple[str, ...]:
    return () if spec["held_out"] == "none" else tuple(spec["held_out"].split("+"))


def training_ids(ds, spec: dict, extra=None, extra_share: float = 0.0,
                 extra_lab_share: float = 1.0) -> tuple[list[int], list[int]]:
    """The model's training moulds: (ids in the pool ds, ids in the extra store): with `extra`,
    round(extra_share x n) of the n come from it (`choose`: extra_lab_share of them lab moulds,
    the held-out kinds left out; 1, the composite store's, takes them in id order) and the pool
    supplies the rest, so that the model's lab share is spec's."""
    held = held_out(spec)
    n = spec.get("n_train", N_TRAIN)
    n_extra = int(round(extra_share * n)) if extra is not None else 0
    n_paper = n - int(round(spec["lab_share"] * n))
    n_paper_extra = n_extra - int(round(extra_lab_share * n_extra))
    n_pool = n - n_extra
    pool_ids = choose(ds, "train", n_pool, 1 - (n_paper - n_paper_extra) / n_pool, held)
    extra_ids = choose(extra, "train", n_extra, extra_lab_share, held) if n_extra else []
    return pool_ids, extra_ids


def train_model(ds, name: str, spec: dict, settings: dict, cache: Path, threads: int,
                extra=None, extra_share: float = 0.0, extra_lab_share: float = 1.0) -> Path:
    """Train (or find in `cache`) the model `spec` names, on `training_ids`."""
    held = held_out(spec)
    train_ids, extra_ids = training_ids(ds, spec, extra, extra_share, extra_lab_share)
    if extra_ids:
        ds = with_extra(ds, extra, extra_ids)
        train_ids = train_ids + [int(i) + EXTRA_OFFSET for i in extra_ids]
    val = first_replicas(ds, "val")  # validation only watches the loss: every mould of the
    val_ids = [int(i) for i in val if families_of(ds)[i] not in held]  # pool's but the held
    key = hashlib.sha256(json.dumps([train_ids, val_ids, settings], sort_keys=True)
                         .encode()).hexdigest()[:12]
    path = cache / f"{name}{'' if settings.get('epochs', 60) == 60 else '_e' + str(settings['epochs'])}_{key}.pt"
    if path.exists():
        return path
    log(f"train {name}: {len(train_ids)} training moulds ({spec}), {len(val_ids)} validation")
    cfg = train_config({**settings, "num_threads": threads}, int(ds.sizes["x"]))
    work = path.with_name(f".{path.name}.training")  # resumed when a run was killed
    train_loop(relabelled(ds, train_ids, val_ids), cfg, work,
               log=lambda line: log(f"  {name}: {line}"))
    work.replace(path)
    return path


def predictions(checkpoint: Path, ds, ids, cache: Path, tag: str) -> np.ndarray:
    """The checkpoint's raw fields of moulds `ids` of ds (cached beside it)."""
    path = cache / f"{checkpoint.stem}_{tag}.npy"
    if path.exists():
        return np.load(path)
    raw = predict_replica_moulds(checkpoint, ds, ids)
    np.save(path, raw)
    return raw


def per_mould(ensemble, raw, families) -> pd.DataFrame:
    """Per mould: the squared error against the expected fields (noise removed), one
    simulation's (its noise ceiling, held out), and the predicted / expected mean tension."""
    truth = ensemble.normalised
    predicted = normalise_predicted(raw).astype(np.float64)
    err = est.mse_against_expected(predicted, truth).corrected
    noise = est.noise_ceiling(truth)
    tension = mean_tension(predicted) / mean_tension(np.nanmean(truth, axis=1))
    return pd.DataFrame({"mould": ensemble.moulds, "family": families, "squared_error": err,
                         "noise": noise, "tension_ratio": tension})


def with_settings(settings: dict, items) -> tuple[dict, str]:
    """settings with run.py's --set KEY=VALUE items applied (VALUE as JSON), and the suffix
    they add to the models' names (_KEYVALUE each)."""
    suffix = ""
    for item in items:
        key, _, value = item.partition("=")
        if key not in SETTING_KEYS or not value:
            raise ValueError(f"--set {item!r}: give KEY=VALUE with KEY one of {SETTING_KEYS}")
        settings = {**settings, key: json.loads(value)}
        suffix += f"_{key}{value}"
    return settings, suffix


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pool", type=Path, required=True, help="the pool's dataset.zarr")
    ap.add_argument("--fresh", type=Path, required=True, help="the fresh seed's dataset.zarr")
    ap.add_argument("--steps", nargs="+", choices=("mixture", "lofo"), default=["mixture", "lofo"])
    ap.add_argument("--lab-share", type=float, default=0.5,
                    help="the lab share of the leave-one-family-out models")
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache/condor/generalisation")
    ap.add_argument("--out", type=Path, default=HERE)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--n-train", type=int, default=N_TRAIN, help="training moulds a model")
    ap.add_argument("--epochs", type=int, default=None, help="default: the preset's")
    ap.add_argument("--only", nargs="+", default=None, help="train and score only these models")
    ap.add_argument("--single", action="store_true",
                    help="lofo: hold out one family at a time, its sibling of KINDS trained on")
    ap.add_argument("--extra", type=Path, default=None,
                    help="a store of more training moulds (composite.yaml's dataset.zarr)")
    ap.add_argument("--extra-share", type=float, default=0.25,
                    help="the share of a model's training moulds from --extra")
    ap.add_argument("--extra-lab-share", type=float, default=1.0,
                    help="the lab share of the moulds from --extra (1: composite.yaml's, every "
                         "one a lab mould; pool2.yaml's: the model's --lab-share)")
    ap.add_argument("--inputs", default=None,
                    help="what the models read (TrainConfig.inputs; default: the preset's)")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE",
                    help="change a setting of the preset (the value as JSON), e.g. noise_weight=1")
    a = ap.parse_args(argv)
    a.cache.mkdir(parents=True, exist_ok=True)
    config = Config.load(Path(__file__).resolve().parents[2] / "config" / "config.yaml")
    settings = workflow_variants(config)["unet"]
    if a.epochs is not None:
        settings = {**settings, "epochs": a.epochs}
    ds, fresh = open_store(a.pool), open_store(a.fresh)
    extra = open_store(a.extra) if a.extra is not None else None
    suffix = f"_extra{a.extra_share:g}" if extra is not None else ""
    if a.inputs is not None and a.inputs != settings["inputs"]:
        settings = {**settings, "inputs": a.inputs}
        suffix += f"_{a.inputs}"
    try:
        settings, changed = with_settings(settings, a.set)
    except ValueError as err:
        ap.error(str(err))
    suffix += changed
    test = first_replicas(ds, "test")
    fam = families_of(ds)
    paper_ids = [int(i) for i in test if fam[i] == PAPER]
    lab_ids = [int(i) for i in test if fam[i] != PAPER]
    fresh_ids = [int(i) for i in first_replicas(fresh, "test")]
    ensembles = {"paper": reference_ensemble(ds, paper_ids), "lab": reference_ensemble(ds, lab_ids),
                 FRESH: reference_ensemble(fresh, fresh_ids)}
    labels = {"paper": [PAPER] * len(ensembles["paper"].moulds),
              "lab": [str(fam[int(m)]) for m in ensembles["lab"].moulds],
              FRESH: [FRESH] * len(ensembles[FRESH].moulds)}
    wanted = {n: s for n, s in models(ds, a.lab_share, a.n_train, a.single).items()
              if ("mixture" in a.steps and n.startswith("mixture"))
              or ("lofo" in a.steps and n.startswith("without"))}
    if a.only:
        wanted = {n: s for n, s in wanted.items() if n in a.only or n + suffix in a.only}
    rows, moulds = [], []
    wanted = {name + suffix: spec for name, spec in wanted.items()}
    for name, spec in wanted.items():
        checkpoint = train_model(ds, name, spec, settings, a.cache, a.threads, extra,
                                 a.extra_share, a.extra_lab_share)
        for group, ensemble in ensembles.items():
            store = fresh if group == FRESH else ds
            raw = predictions(checkpoint, store, ensemble.moulds, a.cache, group.replace(" ", "_"))
            table = family_rows(ensemble, raw, labels[group], seed=config.seed)
            rows.append(table.assign(held_out=spec["held_out"], model=name,
                                     lab_share=spec["lab_share"]))
            moulds.append(per_mould(ensemble, raw, labels[group]).assign(
                model=name, held_out=spec["held_out"]))
        log(f"scored {name}")
    table = pd.concat(rows, ignore_index=True)
    per = pd.concat(moulds, ignore_index=True)
    a.out.mkdir(parents=True, exist_ok=True)
    columns = ["family", "held_out", "n_moulds", "replicas", "error", "error_lo", "error_hi",
               "noise_ceiling", "tension_bias", "tension_bias_lo", "tension_bias_hi"]
    if "lofo" in a.steps:
        lofo = table[table["model"].str.startswith("without")]
        lofo[columns].to_csv(a.out / "generalisation.csv", index=False)
    if "mixture" in a.steps:
        mix = table[table["model"].str.startswith("mixture")]
        mix[["lab_share", *columns]].to_csv(a.out / "mixture.csv", index=False)
    per.to_csv(a.out / "moulds.csv", index=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
