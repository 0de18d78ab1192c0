"""The studies' stages: run a study (condor.studies), write its tables and draw its charts.

- `sweep_mould`: every simulation method on one test mould (its own job: the slow one);
- `accuracy`: every method, surrogate and baseline against the expected fields of the test
  moulds: results/evaluation/accuracy.csv, statistics.csv and the cost-against-error chart
  (accuracy_test.csv, statistics_test.csv, calibration_test.csv: the predictors alone on
  every test mould);
- `ladder`: the anneal ladder against the dataset solver's replicas;
- `convergence`: depth and box-size reductions against seed noise;
- `stability`: the stability cases with every solver;
- `fidelity`: the dataset's solver (and the L-BFGS quench) against the paper's CONDOR, the
  reference anneals the product ships (condor.studies.paper_reference).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from condor import plots
from condor.config import Config
from condor.studies.stability import run_cases
from condor.moulds.mould import input_channels
from condor.model.simulate import FAITHFUL_SOLVER
from condor.stages.build import load_moulds
from condor.data.store import open_store
from condor.studies import accuracy as accuracy_study
from condor.studies.convergence import convergence as convergence_study
from condor.studies.fidelity import fidelity_table, paper_ensemble, prediction_row
from condor.studies.paper_reference import mould_of
from condor.studies.ladder import ladder as ladder_study
from condor.studies.families import FAMILY_COLUMNS, family_rows
from condor.studies.recipes import reference_ensemble
from condor.studies.sweep import run_methods, study_methods
from condor.surrogate.baselines import fit_baselines
from condor.surrogate.samples import dataset_pixel_size, usable_samples
from condor.surrogate.predict import Predictor

log = logging.getLogger("condor")


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


def _predictors(store, checkpoints: dict) -> tuple[dict, list]:
    """The surrogates ({name: Predictor}) and the baselines, fitted once on the training split."""
    surrogates = {name: Predictor(path, device="cpu") for name, path in checkpoints.items()}
    ds = open_store(store)
    train = ds.isel(sample=usable_samples(ds, "train"))
    baselines = fit_baselines(np.asarray(train["inputs"].values, np.float32),
                              np.asarray(train["fields"].values, np.float32),
                              dataset_pixel_size(ds))
    return surrogates, baselines


def _predictor_answers(predictors: tuple[dict, list], ensemble) -> tuple[list, list]:
    """Each surrogate (one torch thread, one mould per call, given the mould's cell count) and
    each baseline of `predictors` (_predictors); and the calibration row of each surrogate with
    a spread map."""
    surrogates, baselines = predictors
    inputs = ensemble.inputs.astype(np.float32)
    answers, calibration = [], []
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for name, predictor in surrogates.items():
            lattice = ensemble.lattice if predictor.needs_lattice else None
            raw, cpu = accuracy_study.time_predictor(
                lambda k: predictor(inputs[k:k + 1], n_cells=ensemble.n_cells[k:k + 1],
                                    lattice=None if lattice is None else lattice[k:k + 1]).raw,
                len(inputs))
            answers.append(accuracy_study.Answer(name, "surrogate", raw, cpu, predicted=True))
            spread = predictor(inputs, n_cells=ensemble.n_cells, lattice=lattice).spread
            if spread is not None:
                calibration.append((accuracy_study.calibration_row(name, raw, spread, ensemble),
                                    raw, spread))
    finally:
        torch.set_num_threads(threads)
    for baseline in baselines:
        raw, cpu = accuracy_study.time_predictor(lambda k: baseline.predict(inputs[k:k + 1]),
                                                 len(inputs))
        answers.append(accuracy_study.Answer(f"baseline {baseline.name}", "baseline", raw, cpu,
                                             predicted=True))
    return answers, calibration


def accuracy(config: Config, store, sweep_npzs, checkpoints: dict, out_accuracy, out_statistics,
             out_calibration, out_chart, out_spread_chart, out_statistics_test=None,
             out_calibration_test=None, out_accuracy_test=None,
             out_lab: dict | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Every method against the expected fields of the study's test moulds (module docs), and
    each surrogate's spread map against the replicas' scatter (a table, and the maps of the
    first surrogate on three test moulds). out_accuracy_test / out_statistics_test /
    out_calibration_test: the same tables of the surrogates and baselines alone on every
    replicated mould of the paper test set (they need no sweep; 60 test moulds narrow an
    interval about 2x against the study's 12). out_lab: {"accuracy", "statistics",
    "calibration", "families"} paths: the same tables on the lab test set, and each surrogate
    family by family (condor.studies.families); empty tables when the config has none."""
    ensemble = reference_ensemble(store, config.study_moulds())
    log.info("reference ensemble: %d test moulds x %s", len(ensemble.moulds),
             ensemble.describe_replicas())
    predictors = _predictors(store, checkpoints)
    predicted, calibration = _predictor_answers(predictors, ensemble)
    answers = _simulation_answers(ensemble, sweep_npzs) + predicted
    table, statistics = accuracy_study.accuracy_tables(ensemble, answers, seed=config.seed)
    spread_maps(ensemble, calibration, out_spread_chart)
    outputs = [(out_accuracy, table), (out_statistics, statistics),
               (out_calibration, _calibration_frame(calibration))]
    if out_statistics_test is not None:
        every = reference_ensemble(store, config.test_moulds("paper"))
        log.info("predictors on every paper test mould: %d x %s", len(every.moulds),
                 every.describe_replicas())
        predicted, calibration = _predictor_answers(predictors, every)
        every_errors, every_statistics = accuracy_study.accuracy_tables(every, predicted,
                                                                        seed=config.seed)
        outputs += [(out_statistics_test, every_statistics),
                    (out_calibration_test, _calibration_frame(calibration))]
        if out_accuracy_test is not None:
            outputs.append((out_accuracy_test, every_errors))
    if out_lab is not None:
        outputs += _lab_tables(config, store, predictors, out_lab)
    for path, frame in outputs:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        frame.to_csv(path, index=False)
    plots.accuracy_chart(table, out_chart, title=(
        f"cost per mould against error vs the expected fields, scene {config.scene.name!r}, "
        f"{len(ensemble.moulds)} test moulds x {ensemble.describe_replicas()}"))
    log.info("\n%s", table[["method", "cpu_s_per_mould", "field_error", "field_error_lo",
                            "field_error_hi"]].to_string(index=False))
    return table, statistics


def _lab_tables(config: Config, store, predictors, out_lab: dict) -> list:
    """(path, table) of the surrogates and baselines on the lab test set: accuracy, statistics
    and calibration as on the paper test set, and each surrogate family by family."""
    moulds = config.test_moulds("lab")
    if not moulds:
        log.info("no lab test set (split.lab_test is 0)")
        empty = pd.DataFrame(columns=["method"])
        return [(out_lab[key], empty) for key in ("accuracy", "statistics", "calibration")] + \
            [(out_lab["families"], pd.DataFrame(columns=["method", *FAMILY_COLUMNS]))]
    lab = reference_ensemble(store, moulds)
    log.info("predictors on the lab test set: %d x %s", len(lab.moulds), lab.describe_replicas())
    predicted, calibration = _predictor_answers(predictors, lab)
    errors, statistics = accuracy_study.accuracy_tables(lab, predicted, seed=config.seed)
    sources = config.sources()
    families = [sources[int(m)] for m in lab.moulds]
    per_family = [family_rows(lab, answer.raw, families, seed=config.seed).assign(
        method=answer.method) for answer in predicted if answer.family == "surrogate"]
    table = (pd.concat(per_family, ignore_index=True) if per_family else
             pd.DataFrame(columns=list(FAMILY_COLUMNS)))
    table = table[["method", *FAMILY_COLUMNS]]
    return [(out_lab["accuracy"], errors), (out_lab["statistics"], statistics),
            (out_lab["calibration"], _calibration_frame(calibration)),
            (out_lab["families"], table)]


def _calibration_frame(calibration: list) -> pd.DataFrame:
    return pd.DataFrame([row for row, _, _ in calibration],
                        columns=None if calibration else ["method", "n_moulds"])


def spread_maps(ensemble, calibration: list, out_png, n: int = 3) -> None:
    """For the first surrogate with a spread head, on `n` test moulds: the predicted T and Sx2,
    their predicted spread and the replicas' standard deviation (raw units)."""
    rows = []
    if calibration:
        (row, raw, spread), replica_std = calibration[0], np.nanstd(ensemble.raw, axis=1, ddof=1)
        for m in range(min(n, len(raw))):
            images = []
            for k, name in ((1, "T"), (2, "Sx2")):
                images += [(f"{name} predicted", raw[m, k]),
                           (f"{name} spread, predicted", spread[m, k]),
                           (f"{name} std of {ensemble.replica_counts[m]} replicas",
                            replica_std[m, k])]
            rows.append((f"mould {int(ensemble.moulds[m])}", images))
        title = (f"{row['method']}: the reproducibility map (predicted spread of one simulation) "
                 "against the replicas' scatter")
    else:
        rows.append(("no surrogate with a spread head", [("expected T", np.nanmean(ensemble.raw[0, :, 1], axis=0))]))
        title = "no reproducibility map"
    plots.image_grid(rows, out_png, title)


def ladder(config: Config, store, moulds_jsons, out_csv) -> pd.DataFrame:
    """The anneal ladder on the first `report.ladder_moulds` study moulds."""
    report = config.report
    ensemble = reference_ensemble(store, config.study_moulds()[: report["ladder_moulds"]])
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


def fidelity(config: Config, checkpoints: dict, out_csv) -> pd.DataFrame:
    """The dataset's solver, and beside it the faithful solver (simulate.FAITHFUL_SOLVER) and
    the L-BFGS quench, against the paper reference of
    the config's scene and seed (`simulation.replicas.test` seeds a mould); then each surrogate
    of `checkpoints` ({variant: path}) on the reference moulds it did not train on. The
    columns only when the product holds no reference of them."""
    solver, budget = config.solver()
    solvers = [(solver, budget)] + [(other, None) for other in (FAITHFUL_SOLVER, "lbfgs")
                                    if other != solver]
    table = fidelity_table(config.scene, config.seed, solvers,
                           int(config.simulation["replicas"]["test"]), log=log.info)
    reference = paper_ensemble(config.scene, config.seed)
    if reference is not None:
        moulds, ref_fields, _, label = reference
        splits = config.splits()
        # a reference mould beyond n_moulds is not in the dataset: held out too
        held = [i for i, m in enumerate(moulds) if m >= len(splits) or splits[m] != "train"]
        rows = []
        for name, path in checkpoints.items() if held else ():
            predictor = Predictor(path, device="cpu")
            shapes = [mould_of(config.scene, config.seed, moulds[i]) for i in held]
            masks = np.stack([input_channels(m, config.scene.pixels) for m in shapes])
            predicted = predictor(masks, **predictor.mould_arguments(shapes)).normalised
            rows.append(prediction_row(f"surrogate {name}", config.scene.name, label,
                                       predicted, ref_fields[held], [moulds[i] for i in held]))
        table = pd.concat([table, pd.DataFrame(rows)], ignore_index=True)
    table.to_csv(out_csv, index=False)
    if table.empty:
        log.info("fidelity: no paper reference of scene %s, seed %s", config.scene.name,
                 config.seed)
    return table
