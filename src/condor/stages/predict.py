"""The predict stage (`condor predict`): one mould's fields from a checkpoint, with what a user
reads beside them.

`predict_mould` places a mould file (JSON, SVG, DXF, or a picture of the mould: PNG, TIFF,
JPEG, vectorised by condor.moulds.read_picture) in the checkpoint's scene, or reads its input
channels as a .npy array; warns where the mould lies outside the training moulds and
gives the domain verdict measured outside the run (condor.findings' out-of-domain table);
predicts the fields and their spread; checks the prediction by simulation where that is
cheap (condor.stages.check), and then answers with the best estimate of the prediction and the
simulations combined; summarises the answer's whole-mould statistics with one simulation's
predicted spread, calibrated by the spread factors measured outside the run (the findings'
spread calibration); and writes a CF Zarr store (with every attribute) or a picture.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from condor.data.store import FORMAT
from condor.findings import load_findings
from condor.model.scenes import PRESETS, Scene, same_length
from condor.moulds.domain import training_domain_check
from condor.moulds.mould import input_channels
from condor.moulds.read import load_placement
from condor.moulds.read_picture import PICTURE_SUFFIXES
from condor.prediction_page import prediction_panels
from condor.stages.check import AUTO, check_count, check_prediction, checked_answer
from condor.surrogate.modes import DEFAULT_PRECISION

# a mould itself (a picture is read as one: condor.moulds.read_picture); a .npy is its masks
MOULD_FILES = (".json", ".svg", ".dxf") + PICTURE_SUFFIXES
OUTPUTS = (".zarr", ".png")


class PredictError(ValueError):
    """A prediction that cannot be made or written; the message names the file and why."""


@dataclass
class PredictedMould:
    """What predict_mould wrote and says: the answer (`prediction`: the surrogate's prediction,
    or after a check the best estimate of it and the simulations combined), its whole-mould
    statistics (None without a pixel size), the note on their spread's calibration, the domain
    verdict (a mould file's), the checkpoint's grid and mode, the check and the surrogate's own
    prediction."""

    out: Path
    prediction: object  # condor.surrogate.predict.Prediction: the answer written
    table: pd.DataFrame | None
    calibrated: str | None
    verdict: str | None
    native: int
    mode: str
    check: object = None  # condor.stages.check.Check, when predict was asked to check
    surrogate: object = None  # the surrogate's own Prediction (the answer when not checked)

    def lines(self) -> list[str]:
        """What `condor predict` prints when it is done."""
        from condor.surrogate.answer import format_mould_summary

        lines = [f"{self.out}: 8 fields at {self.native} px, predicted N_c = "
                 f"{self.prediction.n_cells:.1f} ({self.mode} mode)"]
        if self.table is not None:
            what = ("predicted" if self.check is None else
                    f"best estimate of the prediction and {self.check.n} simulations")
            lines += [f"whole-mould statistics, {what} (+- one simulation's predicted spread):",
                      format_mould_summary(self.table)]
            if self.calibrated is not None:
                lines.append(f"  {self.calibrated}")
        if self.verdict is not None:
            lines.append(f"training domain: {self.verdict}")
        if self.check is not None:
            lines += self.check.lines()
        return lines


def predict_mould(checkpoint, mould, out, *, l0_um: float | None = None, fit=None,
                  units: str | None = None, device=None, mode: str | None = None,
                  precision: str = DEFAULT_PRECISION, force: bool = False, check: int | str = AUTO,
                  picture=None, say=print, warn=print) -> PredictedMould:
    """Predict mould `mould` (a mould file or a picture of it, or its input channels as a
    .npy) with `checkpoint` and write `out` (.zarr or .png). `l0_um`, `fit`, `units`,
    `picture` (condor.moulds.read_picture.PictureOptions): how a drawing or a picture is read
    and placed (condor.moulds.read.load_placement); `check`: simulate the mould that many
    times and score the prediction against them (condor.stages.check; a mould file only),
    after which the answer written is the best estimate of the two (checked_answer); AUTO,
    the default as on the command line: AUTO_CHECK simulations where they take seconds;
    `say(line)`: how it was read, and each check simulation; `warn(line)`: each warning.
    Nothing that exists is replaced without `force`, and never a dataset store or a folder
    that predict did not write."""
    from condor.surrogate.predict import Predictor

    from condor.surrogate.novelty import bank_of, training_ranges

    out = check_output(out, force)
    predictor = Predictor(checkpoint, device=device, mode=mode, precision=precision)
    bank = bank_of(predictor.state)  # None: a checkpoint trained before novelty was kept
    placement, verdict, novelty = None, None, None
    if Path(mould).suffix.lower() in MOULD_FILES:
        scene = checkpoint_scene(predictor)
        placement = load_placement(mould, scene, l0_um=l0_um, fit=fit, units=units,
                                   picture=picture)
        say(f"{mould}: {placement.describe()}")
        for warning in training_domain_check(placement.mould, scene, training_ranges(bank)):
            warn(warning)
        if bank is None:
            verdict = mould_domain_verdict(placement.mould, scene)
    if check and check != AUTO and placement is None:
        raise PredictError(f"--check simulates the mould, which needs its geometry: give "
                           f"{mould} as a mould file or a picture of it (JSON, SVG, DXF, PNG, "
                           "TIFF, JPEG), not its masks")
    inputs, n_cells, lattice = mould_inputs(predictor, mould, placement, warn)
    prediction = predictor(inputs, n_cells=n_cells, lattice=lattice)  # None: from the pixels
    n_check = check_count(check, float(prediction.n_cells), scene) if placement else 0
    if bank is not None:
        verdict, novelty = mould_novelty_verdict(predictor, bank, inputs, lattice, prediction,
                                                 checking=bool(n_check))
    scale = placement.scale if placement is not None else 1.0
    checked = None
    if n_check:
        say(f"checking by {n_check} simulations of the mould ({scene.name} scene)")
        try:
            checked = check_prediction(placement.mould, scene, prediction.normalised,
                                       float(prediction.n_cells), n_check, say=say,
                                       automatic=check == AUTO)
        except ValueError as err:
            if check != AUTO:
                raise
            warn(f"the automatic check did not run: {err}")
    answer = checked_answer(prediction, checked)
    table, calibrated = statistics_with_spread(predictor, answer, inputs, l0_um, warn, scale)
    if out.suffix.lower() == ".png":
        what = "predicted" if checked is None else "best estimate of the"
        prediction_panels(inputs, answer, out, summary=table, verdict=verdict,
                          pixel_size=predictor.pixel_size, l0_um=l0_um, scale=scale,
                          title=f"{Path(mould).name}: {what} organisation, "
                                f"{float(prediction.n_cells):.0f} cells", check=checked,
                          surrogate=prediction)
    else:
        from condor.surrogate.prediction_zarr import write_prediction

        attrs = store_attributes(checkpoint, mould, predictor.mode, placement, verdict, table,
                                 calibrated)
        if novelty is not None:
            attrs["novelty"] = novelty
        write_prediction(out, answer, inputs, predictor.pixel_size, attrs, overwrite=force,
                         l0_um=l0_um, scale=scale, check=checked, surrogate=prediction)
    return PredictedMould(out, answer, table, calibrated, verdict, predictor.native,
                          predictor.mode, checked, prediction)


def check_output(out, force: bool) -> Path:
    """`out` as a prediction's path: a .zarr or .png that is not there (or `force`), in a
    folder that is, and never a dataset store or a folder predict did not write."""
    out = Path(out)
    if out.suffix.lower() not in OUTPUTS:
        raise PredictError(f"--out {str(out)!r} must end in .zarr or .png")
    refuse_dataset(out)
    if out.exists() and not force:
        raise PredictError(f"--out {str(out)!r} exists; pass --force to overwrite it")
    if out.parent != Path("") and not out.parent.is_dir():
        raise PredictError(f"--out {str(out)!r}: folder {str(out.parent)!r} does not exist")
    return out


def refuse_dataset(path: Path) -> None:
    """A prediction is never written over a dataset store, nor over a folder that is not a
    prediction `predict` wrote (a Zarr store of its attributes), --force or not."""
    if not path.is_dir():
        return
    meta = path / "zarr.json"
    text = meta.read_text(errors="replace") if meta.is_file() else ""
    if FORMAT in text:
        raise PredictError(f"--out {str(path)!r} is a condor dataset store; a prediction never "
                           "replaces one (choose another path)")
    try:
        attributes = json.loads(text).get("attributes", {})
    except (ValueError, AttributeError):
        attributes = {}
    if not {"checkpoint", "n_cells"} <= set(attributes):
        raise PredictError(f"--out {str(path)!r} is a folder that condor predict did not write; "
                           "--force replaces only a prediction (choose another path)")


def checkpoint_scene(predictor) -> Scene:
    """The scene a checkpoint was trained on: the preset with its grid (box and pixels), else
    a scene of its recorded grid and depth (depth NaN when the checkpoint lacks it)."""
    for scene in PRESETS.values():
        if scene.pixels == predictor.native and predictor.box is not None and \
                same_length(scene.box, predictor.box):
            return scene
    if predictor.box is None:
        raise PredictError(f"checkpoint {predictor.path!r} records no pixel size: moulds cannot "
                           "be placed on its grid (predict takes a (2, H, W) .npy or .png "
                           "instead)")
    depth = predictor.depth if predictor.depth is not None else float("nan")
    return Scene("checkpoint", box=predictor.box, depth=depth, pixels=predictor.native)


def mould_domain_verdict(mould, scene: Scene) -> str:
    """Where `mould` sits against the training moulds, in words, with what was measured
    outside the run on such moulds (experiments/out_of_domain's table)."""
    from condor.surrogate.answer import domain_table, domain_verdict

    measured = load_findings()["out_of_domain"]
    return domain_verdict(domain_table(mould, scene), measured.frame(),
                      f"{measured.experiment} at {measured.commit}")


def mould_novelty_verdict(predictor, bank: dict, inputs, lattice, prediction,
                          checking: bool = False) -> tuple[str, dict]:
    """How new the mould is to the checkpoint (condor.surrogate.novelty: its features' distance
    to the training moulds') and the verdict of the shipped calibration (condor.findings'
    "novelty", experiments/generalisation): by the score it calibrates, the feature distance or
    inverse_spread (one over the RMS of the prediction's spread map), with what was measured on
    moulds of that score: the verdict's lines and its numbers. `checking`: predict checks the
    mould by simulation, so the verdict points there instead of advising a check."""
    from condor.surrogate.novelty import (
        CHECK_ADVICE, CHECKED_ADVICE, SCORES, inverse_spread, mould_novelty, network_inputs,
        never_drawn_sentence, novelty_verdict, unseen_kinds_sentence,
    )

    x = network_inputs(predictor.inputs_kind, np.asarray(inputs)[None],
                       None if lattice is None else np.asarray(lattice).reshape(
                           (1,) + np.shape(inputs)))
    distance = float(mould_novelty(predictor.model, predictor.inputs_kind, bank, x)[0])
    findings = load_findings()  # read once: the calibration and the two sentences below
    finding = findings.get("novelty")
    if finding is None:  # a package without the calibration
        return (f"novelty {distance:.2f} (1 is typical of its training moulds; not calibrated)",
                {"novelty": distance})
    name = finding.values["score"]
    if name not in SCORES:
        raise ValueError(f"condor.findings' novelty calibrates {name!r}; predict computes "
                         f"{SCORES} (condor.surrogate.novelty)")
    if name == "inverse_spread" and prediction.spread is None:
        return (f"novelty {distance:.2f} (1 is typical of its training moulds; the verdict "
                "reads the spread map, which this checkpoint does not predict)",
                {"novelty": distance})
    score = distance if name == "feature_distance" else float(
        inverse_spread(np.asarray(prediction.spread)[None],
                       np.asarray(prediction.normalised)[None])[0])
    advice = CHECKED_ADVICE if checking else CHECK_ADVICE
    text, numbers = novelty_verdict(score, finding.frame(), float(finding.values["threshold"]),
                                    f"{finding.experiment} at {finding.commit}", name,
                                    distance, advice)
    measured, drawn = findings.get("generalisation"), findings.get("never_drawn")
    lines = [text]
    if measured is not None:
        lines.append(unseen_kinds_sentence(measured.frame(),
                                           f"{measured.experiment} at {measured.commit}",
                                           advice))
    if drawn is not None:
        lines.append(never_drawn_sentence(drawn.frame(), f"{drawn.experiment} at {drawn.commit}"))
    return "\n  ".join(line for line in lines if line), numbers


def mould_inputs(predictor, mould, placement, warn) -> tuple:
    """(inputs, n_cells, lattice) the network reads: a placed mould's exact ones, or the
    masks of a .npy (N_c then estimated, and the lattice channels with a warning)."""
    from condor.surrogate.answer import MASK_ONLY_MEASURED
    from condor.surrogate.pictures import read_mould_inputs

    if placement is not None:
        inputs = input_channels(placement.mould, predictor.native)
        exact = predictor.mould_arguments([placement.mould])  # N_c and lattice channels
        n_cells, lattice = exact.get("n_cells"), exact.get("lattice")
    else:
        inputs, n_cells = read_mould_inputs(mould, predictor.native, predictor.box), None
        lattice = None
    if not inputs.any():
        raise PredictError(f"{mould} holds no mould pixel: nothing to predict")
    if predictor.needs_lattice and lattice is None:
        warn(f"{mould} holds masks: the lattice channels this checkpoint reads are estimated "
             "from its pixels, which measured much worse than a mould's geometry: "
             f"{MASK_ONLY_MEASURED}. Give the mould as JSON, SVG, DXF or a picture of it "
             "(PNG, TIFF, JPEG: read as a mould) for the exact channels")
        lattice = predictor.estimate_lattice(inputs)
    return inputs, n_cells, lattice


def statistics_with_spread(predictor, prediction, inputs, l0_um, warn, scale: float = 1.0) -> tuple:
    """The whole-mould statistics with one simulation's predicted spread (None without the
    checkpoint's pixel size), and the note on that spread's calibration (None when the
    checkpoint predicts no spread); `scale`: the drawing's placement factor (areas in mm^2
    are the drawn mould's)."""
    from condor.design.search import prediction_spread
    from condor.surrogate.answer import checkpoint_spread_calibration, mould_summary
    from condor.surrogate.calibration import tissue_pixels

    pixel_size = predictor.pixel_size
    if pixel_size is None:
        return None, None
    spread = prediction_spread(prediction)  # in normalised units, like the fields
    factors, calibrated = None, None
    if spread is not None:  # the statistics' spread factors: experiments/spread_calibration
        factors, calibrated, warning = checkpoint_spread_calibration(
            load_findings()["spread_calibration"], predictor.state)
        if warning is not None:
            warn(warning)
    table = mould_summary(prediction.normalised, float(prediction.n_cells), pixel_size, spread,
                          tissue=tissue_pixels(inputs[None])[0],
                          sigma_px=predictor.sigma / pixel_size, l0_um=l0_um, factors=factors,
                          scale=scale)
    return table, calibrated


def store_attributes(checkpoint, mould, mode: str, placement, verdict, table, calibrated) -> dict:
    """The prediction store's attributes: the checkpoint, the mould, the mode, how the mould
    was placed, the domain verdict and each whole-mould statistic with its spread."""
    attrs = {"checkpoint": str(checkpoint), "mould": str(mould), "mode": mode}
    if placement is not None:
        attrs.update({k: v for k, v in placement.record().items() if v is not None})
    if verdict is not None:
        attrs["training_domain"] = verdict
    if table is not None and calibrated is not None:
        attrs["spread_calibration"] = calibrated
    if table is not None:
        attrs["statistics"] = {row.statistic: {"value": float(row.value),
                                               "spread": float(row.spread), "unit": row.unit}
                               for row in table.itertuples()}
    return attrs
