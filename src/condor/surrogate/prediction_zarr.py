"""A prediction as an xarray Dataset with CF attributes, written as a Zarr store
(`write_prediction`): the fields raw and normalised (after a check, the best estimate, beside
the surrogate's own and the simulations'), their spread, the inputs, and x/y in mm given the
cell spacing. (A picture of it: condor.prediction_page.prediction_panels.)"""

from __future__ import annotations

import errno
from pathlib import Path

import numpy as np
import xarray as xr

from condor.data.store import quiet_zarr
from condor.files import atomic_path

from .predict import Prediction
from .samples import FIELD_NAMES

FIELD_LONG_NAMES = {
    "P": "cell density", "T": "tension", "Sx2": "orientation tensor s_x s_x",
    "Sy2": "orientation tensor s_y s_y", "Sz2": "orientation tensor s_z s_z",
    "SxSy": "orientation tensor s_x s_y", "SxSz": "orientation tensor s_x s_z (zero by the "
    "mould's z-mirror symmetry)", "SySz": "orientation tensor s_y s_z (zero by the mould's "
    "z-mirror symmetry)"}


def grid_coordinates(n: int, pixel_size: float | None, l0_um: float | None = None,
                     scale: float = 1.0) -> dict:
    """CF coordinates x and y of an n-pixel grid: pixel centres in mm given l0_um (with
    x_l0, y_l0 beside them), else in l0 (in pixels when pixel_size is None); each with
    units, long_name, standard_name and axis. `scale`: the factor the user's drawing was
    placed at (--fit): the mm are the drawing's, l0 / scale."""
    step = 1.0 if pixel_size is None else float(pixel_size)
    centres = (np.arange(n) + 0.5) * step
    unit = "pixel" if pixel_size is None else "l0"
    coords = {}
    for axis in ("x", "y"):
        base = {"standard_name": f"projection_{axis}_coordinate", "axis": axis.upper()}
        if l0_um is not None and pixel_size is not None:
            drawn = (f"; at the drawing's size: the mould was placed scaled by {scale:.4g}"
                     if scale != 1.0 else "")
            coords[axis] = (axis, centres * float(l0_um) / 1000.0 / scale,
                            {**base, "units": "mm", "long_name": f"{axis} of the pixel centre "
                             f"from the box's {'left' if axis == 'x' else 'lower'} edge "
                             f"(l0 = {float(l0_um):g} um{drawn})"})
            coords[f"{axis}_l0"] = (axis, centres, {"units": "l0", "long_name": f"{axis} in "
                                    "cell spacings l0"})
        else:
            coords[axis] = (axis, centres, {**base, "units": unit, "long_name": f"{axis} of "
                            f"the pixel centre from the box's {'left' if axis == 'x' else 'lower'} edge"
                            + (" (l0: the cells' spacing)" if unit == "l0" else "")})
    return coords


def prediction_dataset(prediction: Prediction, inputs: np.ndarray, pixel_size: float | None,
                       attrs: dict | None = None, l0_um: float | None = None,
                       scale: float = 1.0, check=None, surrogate: Prediction | None = None):
    """One answer as an xarray.Dataset: `raw` and `normalised` (field, y, x), `spread`
    (field, y, x; when the checkpoint predicts it), `inputs` (channel, y, x); with `check`
    (condor.stages.check.Check), whose best estimate `prediction` then is
    (condor.stages.check.checked_answer), the surrogate's own prediction `surrogate_raw` and
    `surrogate_normalised`, the simulations' `simulated`, `simulated_sd` and
    `simulated_normalised` (field, y, x) and the check's numbers (attribute `check`); the
    attribute `answer` says which the fields are; x/y pixel centres (grid_coordinates: in mm
    given l0_um, else l0; pixels when pixel_size is None), every variable and coordinate with
    CF `units` and `long_name`."""
    n = inputs.shape[-1]
    per_field = {"field_long_names": [FIELD_LONG_NAMES[f] for f in FIELD_NAMES]}
    checked = check is not None and check.best_normalised is not None
    what = (f"best estimate of the expected fields: the surrogate's prediction and the mean of "
            f"{check.n} simulations weighed by their measured errors "
            f"(condor.stages.check.best_estimate: {100 * check.weight:.0f}% the prediction's in "
            f"density and orientation, {100 * check.tension_weight:.0f}% in tension)"
            if checked else "predicted expected fields")
    variables = {
        "raw": (("field", "y", "x"), prediction.raw,
                {"long_name": f"{what}: per pixel, the kernel-weighted sum over cells (P in "
                 "cells; T in the model's tension units)", "units": "1", **per_field}),
        "normalised": (("field", "y", "x"), prediction.normalised,
                       {"long_name": f"{what}, normalised per cell (raw * N_pixels / N_c)",
                        "units": "1", **per_field}),
        "inputs": (("channel", "y", "x"), np.asarray(inputs, dtype=np.uint8),
                   {"long_name": "input masks: mould, tether (0/1)", "units": "1"})}
    if prediction.spread is not None:
        variables["spread"] = (("field", "y", "x"), prediction.spread,
                               {"long_name": "standard deviation of one simulation's field "
                                "around the expected (raw) field, per pixel", "units": "1",
                                "description": "standard deviation of one simulation's field "
                                               "around the expected (raw) field, per pixel"})
    if check is not None and check.simulated is not None:
        what = f"{check.n} simulations of the mould (condor predict --check)"
        variables["simulated"] = (("field", "y", "x"), check.simulated,
                                  {"long_name": f"mean raw fields of {what}", "units": "1",
                                   **per_field})
        variables["simulated_sd"] = (("field", "y", "x"), check.simulated_sd,
                                     {"long_name": f"standard deviation of the raw fields of {what}",
                                      "units": "1", **per_field})
        variables["simulated_normalised"] = (("field", "y", "x"), check.simulated_normalised,
                                             {"long_name": f"mean normalised fields of {what}",
                                              "units": "1", **per_field})
        if checked and surrogate is not None:
            for name, values in (("surrogate_raw", surrogate.raw),
                                 ("surrogate_normalised", surrogate.normalised)):
                variables[name] = (("field", "y", "x"), values,
                                   {"long_name": "the surrogate's own predicted expected "
                                    f"fields ({name.split('_')[1]}), before the check",
                                    "units": "1", "prediction_weight": float(check.weight),
                                    "prediction_tension_weight": float(check.tension_weight),
                                    **per_field})
        attrs = {**(attrs or {}), "check": check.attributes()}
    coords = {"field": ("field", list(FIELD_NAMES), {"long_name": "field name"}),
              "channel": ("channel", ["mould", "tether"], {"long_name": "input channel"}),
              **grid_coordinates(n, pixel_size, l0_um, scale)}
    length_unit = "pixel" if pixel_size is None else ("mm" if l0_um is not None else "l0")
    return xr.Dataset(
        variables, coords=coords,
        attrs={"Conventions": "CF-1.10", "n_cells": float(prediction.n_cells),
               "length_unit": length_unit, "answer": "best estimate" if checked else "surrogate",
               **(attrs or {})})


def write_prediction(path, prediction: Prediction, inputs: np.ndarray,
                     pixel_size: float | None = None, attrs: dict | None = None,
                     overwrite: bool = False, l0_um: float | None = None,
                     scale: float = 1.0, check=None,
                     surrogate: Prediction | None = None) -> None:
    """Write a prediction as a .zarr store (xarray, see prediction_dataset), whole or not at all
    (condor.files.atomic_path); an existing one is replaced only with `overwrite`."""
    path = Path(path)
    if path.suffix.lower() != ".zarr":
        raise ValueError(f"prediction store {str(path)!r} must end in .zarr")
    if path.exists() and not overwrite:
        raise FileExistsError(errno.EEXIST, f"prediction store {str(path)!r} exists", str(path))
    with quiet_zarr(), atomic_path(path) as tmp:
        prediction_dataset(prediction, inputs, pixel_size, attrs, l0_um, scale, check,
                           surrogate).to_zarr(tmp, mode="w-")
