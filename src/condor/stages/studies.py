"""The studies' stages: run a study (condor.studies), write its tables and draw its charts.

- `sweep_mould`: every simulation method on one test mould (its own job: the slow one);
- `accuracy`: every method, surrogate and baseline against the expected fields of the test
  moulds: results/evaluation/accuracy.csv, statistics.csv and the cost-against-error chart;
- `ladder`: the anneal ladder against the dataset solver's replicas;
- `convergence`: depth and box-size reductions against seed noise;
- `stability`: the stability cases with every solver.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from condor import plots
from condor.config import Config
from condor.stability import run_cases
from condor.stages.dataset import load_moulds
from condor.store import open_store
from condor.studies import accuracy as accuracy_study
from condor.studies.convergence import convergence as convergence_study
from condor.studies.ladder import ladder as ladder_study
from condor.studies.reference import reference_ensemble
from condor.studies.sweep import run_methods, study_methods
from condor.surrogate.baselines import fit_baselines
from condor.surrogate.data import dataset_pixel_size, usable_samples
from condor.surrogate.predict import Predictor

log = logging.getLogger("condor")


def study_moulds(config: Config) -> list[int]:
    """The test moulds the accuracy study and the sweeps use (first `report.moulds` by id)."""
    return config.test_moulds()[: config.report["moulds"]]


def mould_by_id(moulds_jsons, mould_id: int):
    for path in moulds_jsons:
        for mould in load_moulds(path):
            if mould.mould_id == int(mould_id):
                return mould
    raise ValueError(f"mould {mould_id} is in none of {list(map(str, moulds_jsons))}")


def sweep_mould(config: Config, moulds_json, mould_id: int, out_npz, out_csv) -> pd.DataFrame:
    """Every simulation method of the accuracy study on one mould: raw fields and a table."""
    report = config.report
    methods = study_methods(report["reference_budget"], report["anneal_budgets"])
    mould = mould_by_id([moulds_json], mould_id)
    rows, fields = run_methods(mould, config.scene, methods, config.seed, log=log.info)
    table = pd.DataFrame(rows)
    np.savez_compressed(out_npz, fields=fields, methods=np.array([m.label for m in methods]),
                        families=np.array([m.family for m in methods]),
                        cpu_s=table["cpu_s"].to_numpy(), mould=int(mould_id))
    table.to_csv(out_csv, index=False)
    return table


def _simulation_answers(ensemble, sweep_npzs) -> list:
    """One Answer per swept method, its moulds aligned with the ensemble's."""
    runs = {}
    for path in sweep_npzs:
        with np.load(path) as data:
            runs[int(data["mould"])] = {k: data[k] for k in ("fields", "methods", "families", "cpu_s")}
    missing = [int(m) for m in ensemble.moulds if int(m) not in runs]
    if missing:
        raise ValueError(f"no sweep for test mould(s) {missing}")
    first = runs[int(ensemble.moulds[0])]
    answers = []
    for k, (method, family) in enumerate(zip(first["methods"], first["families"])):
        raw = np.stack([runs[int(m)]["fields"][k] for m in ensemble.moulds])
        cpu = np.array([runs[int(m)]["cpu_s"][k] for m in ensemble.moulds])
        answers.append(accuracy_study.Answer(str(method), str(family), raw, cpu))
    return answers


def _predictor_answers(store, ensemble, checkpoints: dict) -> list:
    """Each surrogate (one torch thread, one mould per call) and each baseline."""
    inputs = ensemble.inputs.astype(np.float32)
    answers = []
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for name, path in checkpoints.items():
            predictor = Predictor(path, device="cpu")
            raw, cpu = accuracy_study.time_predictor(lambda x: predictor(x).raw, inputs)
            answers.append(accuracy_study.Answer(name, "surrogate", raw, cpu, predicted=True))
    finally:
        torch.set_num_threads(threads)
    ds = open_store(store)
    train = ds.isel(sample=usable_samples(ds, "train"))
    for baseline in fit_baselines(np.asarray(train["inputs"].values, np.float32),
                                  np.asarray(train["fields"].values, np.float32),
                                  dataset_pixel_size(ds)):
        raw, cpu = accuracy_study.time_predictor(baseline.predict, inputs)
        answers.append(accuracy_study.Answer(f"baseline {baseline.name}", "baseline", raw, cpu,
                                             predicted=True))
    return answers


def accuracy(config: Config, store, sweep_npzs, checkpoints: dict, out_accuracy, out_statistics,
             out_chart) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Every method against the expected fields of the study's test moulds (module docs)."""
    ensemble = reference_ensemble(store, study_moulds(config))
    log.info("reference ensemble: %d test moulds x %d replicas", len(ensemble.moulds),
             ensemble.n_replicas)
    answers = _simulation_answers(ensemble, sweep_npzs) + \
        _predictor_answers(store, ensemble, checkpoints)
    table, statistics = accuracy_study.accuracy_tables(ensemble, answers, seed=config.seed)
    for path, frame in ((out_accuracy, table), (out_statistics, statistics)):
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        frame.to_csv(path, index=False)
    plots.accuracy_chart(table, out_chart, title=(
        f"cost per mould against error vs the expected fields, scene {config.scene.name!r}, "
        f"{len(ensemble.moulds)} test moulds x {ensemble.n_replicas} replicas"))
    log.info("\n%s", table[["method", "cpu_s_per_mould", "field_error", "field_error_lo",
                            "field_error_hi"]].to_string(index=False))
    return table, statistics


def ladder(config: Config, store, moulds_jsons, out_csv) -> pd.DataFrame:
    """The anneal ladder on the first `report.ladder_moulds` study moulds."""
    report = config.report
    ensemble = reference_ensemble(store, study_moulds(config)[: report["ladder_moulds"]])
    moulds = [mould_by_id(moulds_jsons, m) for m in ensemble.moulds]
    table = ladder_study(ensemble, moulds, config.scene, report["ladder_budgets"],
                         report["ladder_seeds"], config.seed, log=log.info)
    table.to_csv(out_csv, index=False)
    return table


def convergence(config: Config, moulds_json, mould_id: int, out_csv, out_chart) -> pd.DataFrame:
    """Depth and box-size reductions of one mould against seed noise."""
    report = config.report
    table = convergence_study(config.scene, [mould_by_id([moulds_json], mould_id)],
                              report["convergence_seeds"], report["convergence_depths"],
                              report["convergence_box_scales"], config.solver()[0], config.seed,
                              log=log.info)
    table.to_csv(out_csv, index=False)
    plots.convergence_chart(table, out_chart)
    return table


def stability(config: Config, out_csv) -> pd.DataFrame:
    """Every stability case with every solver of `report.stability_solvers`."""
    table = run_cases(solvers=tuple(config.report["stability_solvers"]))
    table.to_csv(out_csv, index=False)
    log.info("\n%s", table.drop(columns=["what"]).to_string(index=False))
    return table
