"""The dataset store: one Zarr group described by xarray (contract in DESIGN.md).

Layout. Every array has `sample` first with one sample per chunk, so writers for different
samples touch disjoint files and never resize, append or re-consolidate: all arrays are
created, full size, by `create_store` and consolidated once. A sample becomes visible in
stages, each finished by a flag written last:

- the mould stage writes `inputs` and the mould metadata, then `inputs_ready = 1`;
- the fields stage writes `fields` and the simulation metadata, then `status` ("ok", or the
  reason the simulation failed, in which case `fields` stays empty).

A job killed part-way leaves at most chunks whose flag is unset: `check_store` reports them
and a rerun overwrites them. Zarr's local store writes each chunk atomically (temporary file
then rename), so no chunk is ever half-written.
"""

from __future__ import annotations

import json
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zarr

from condor import __version__
from condor.fields import FIELD_NAMES

FORMAT = "condor-dataset"
FORMAT_VERSION = 1
CHANNELS = ("mould", "tether")
SPLITS = ("train", "val", "test")

# Per-sample metadata: name -> (dtype, fill value). Strings are fixed-width (numpy "<U"),
# which xarray and numpy read as ordinary str arrays; failure reasons are cut to 160 chars.
STATUS_WIDTH = 160
SAMPLE_VARIABLES: dict[str, tuple[object, object]] = {
    "seed": ("int64", -1),
    "symmetry": ("<U24", ""),
    "order": ("int16", -1),
    "removal": ("<U24", ""),
    "n_tethers": ("int16", -1),
    "inputs_ready": ("uint8", 0),
    "n_cells": ("int32", -1),
    "energy": ("float64", np.nan),
    "solver": ("<U24", ""),
    "solver_seconds": ("float64", np.nan),
    "status": (f"<U{STATUS_WIDTH}", ""),
    "split": ("<U8", ""),
}
MOULD_VARIABLES = ("seed", "symmetry", "order", "removal", "n_tethers")
SIMULATION_VARIABLES = ("n_cells", "energy", "solver", "solver_seconds")


class StoreError(RuntimeError):
    """The store is missing, foreign, truncated or incompatible with the request."""


@dataclass(frozen=True)
class StoreSpec:
    """What a store is built for; a store is reused only if its spec matches."""

    n_samples: int
    pixels: int
    seed: int
    split: tuple[str, ...]  # one of SPLITS per sample
    attrs: dict  # JSON-safe: scene, pixel size, sigma, model parameters

    def check(self) -> None:
        if self.n_samples < 1:
            raise ValueError(f"n_samples must be >= 1, got {self.n_samples}")
        if self.pixels < 4:
            raise ValueError(f"pixels must be >= 4, got {self.pixels}")
        if len(self.split) != self.n_samples:
            raise ValueError(f"split has {len(self.split)} entries for {self.n_samples} samples")
        bad = sorted(set(self.split) - set(SPLITS))
        if bad:
            raise ValueError(f"unknown split name(s) {bad}; expected {SPLITS}")


def assign_splits(n_samples: int, n_test: int, val_fraction: float, seed: int) -> tuple[str, ...]:
    """Deterministic split: a seeded permutation gives `n_test` test samples, then
    `val_fraction` of the rest (rounded) for validation, the remainder for training."""
    if not 0 <= n_test < n_samples:
        raise ValueError(f"split.test must be in [0, n_moulds), got {n_test} for {n_samples} moulds")
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"split.val_fraction must be in [0, 1), got {val_fraction}")
    order = np.random.default_rng([seed, 0x5B117]).permutation(n_samples)
    n_val = int(round(val_fraction * (n_samples - n_test)))
    labels = np.full(n_samples, "train", dtype=object)
    labels[order[:n_test]] = "test"
    labels[order[n_test : n_test + n_val]] = "val"
    return tuple(labels)


@contextmanager
def _quiet():
    """Silence zarr's notices that consolidated metadata and string dtypes are not yet in the
    v3 spec: xarray reads both, and users should not see them on every write."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*string.*", category=UserWarning)
        warnings.filterwarnings("ignore", category=FutureWarning, module="zarr")
        warnings.filterwarnings("ignore", message=".*[Cc]onsolidated metadata.*")
        yield


def create_store(path: str | Path, spec: StoreSpec) -> bool:
    """Create the store at `path` for `spec`; return True if created, False if a matching
    store already exists (its samples are kept). A store built for another spec is never
    touched: StoreError names the difference."""
    spec.check()
    path = Path(path)
    if path.is_dir() and not any(path.iterdir()):
        path.rmdir()  # an empty folder (Snakemake makes output folders before the job) holds nothing
    if path.exists():
        _check_compatible(path, spec)
        return False
    tmp = path.with_name(path.name + ".creating")
    if tmp.exists():
        import shutil

        shutil.rmtree(tmp)  # debris of an interrupted creation: holds no samples
    with _quiet():
        group = zarr.open_group(tmp, mode="w-", zarr_format=3)
        group.attrs.update(
            {
                "format": FORMAT,
                "format_version": FORMAT_VERSION,
                "code_version": __version__,
                "n_samples": spec.n_samples,
                "pixels": spec.pixels,
                "seed": spec.seed,
                **spec.attrs,
            }
        )
        n, p = spec.n_samples, spec.pixels
        _coordinate(group, "sample", np.arange(n, dtype="int64"))
        _coordinate(group, "channel", np.array(CHANNELS))
        _coordinate(group, "field", np.array(FIELD_NAMES))
        group.create_array(
            "inputs", shape=(n, 2, p, p), chunks=(1, 2, p, p), dtype="uint8", fill_value=0,
            dimension_names=("sample", "channel", "y", "x"),
        )
        group.create_array(
            "fields", shape=(n, len(FIELD_NAMES), p, p), chunks=(1, len(FIELD_NAMES), p, p),
            dtype="float32", fill_value=np.nan, dimension_names=("sample", "field", "y", "x"),
        )
        for name, (dtype, fill) in SAMPLE_VARIABLES.items():
            group.create_array(
                name, shape=(n,), chunks=(1,), dtype=dtype, fill_value=fill,
                dimension_names=("sample",),
            )
        group["split"][:] = np.array(spec.split)
        zarr.consolidate_metadata(tmp)
    tmp.rename(path)  # the store appears whole or not at all
    return True


def _coordinate(group, name: str, values: np.ndarray) -> None:
    arr = group.create_array(
        name, shape=values.shape, chunks=values.shape, dtype=values.dtype,
        fill_value="" if values.dtype.kind == "U" else 0, dimension_names=(name,),
    )
    arr[:] = values


def open_group(path: str | Path, mode: str = "r") -> zarr.Group:
    """Open a condor store's Zarr group, with a clear StoreError when it is not one."""
    path = Path(path)
    if not path.exists():
        raise StoreError(f"no dataset store at {path} (run the workflow to build it)")
    with _quiet():
        try:
            group = zarr.open_group(path, mode=mode)
        except Exception as err:  # zarr raises several types for unreadable metadata
            raise StoreError(f"{path} is not a readable Zarr store: {err}") from err
        if group.attrs.get("format") != FORMAT:
            raise StoreError(
                f"{path} is a Zarr store but not a condor dataset "
                f"(attribute 'format' is {group.attrs.get('format')!r}, expected {FORMAT!r})"
            )
        if group.attrs.get("format_version") != FORMAT_VERSION:
            raise StoreError(
                f"{path} has store format version {group.attrs.get('format_version')}, "
                f"this code reads version {FORMAT_VERSION}"
            )
        expected = {"inputs", "fields", "sample", "channel", "field", *SAMPLE_VARIABLES}
        # Consolidated metadata still lists an array whose folder was deleted: look on disk.
        missing = sorted(name for name in expected if not (path / name / "zarr.json").is_file())
        if missing:
            raise StoreError(f"{path} is truncated: missing array(s) {missing}")
    return group


def _check_compatible(path: Path, spec: StoreSpec) -> None:
    attrs = open_group(path).attrs
    wanted = {"n_samples": spec.n_samples, "pixels": spec.pixels, "seed": spec.seed, **spec.attrs}
    diffs = [
        f"{key}: store has {attrs.get(key)!r}, config asks {value!r}"
        for key, value in wanted.items()
        if json.loads(json.dumps(attrs.get(key))) != json.loads(json.dumps(value))
    ]
    if diffs:
        raise StoreError(
            f"{path} was built for a different configuration ({'; '.join(diffs)}); "
            "point `store` at a new path or delete the old store"
        )


def open_dataset(path: str | Path):
    """The store as a lazily loaded xarray.Dataset (validated first)."""
    import xarray as xr

    open_group(path)
    with _quiet():
        try:
            return xr.open_zarr(path, consolidated=True)
        except Exception as err:
            raise StoreError(f"{path}: xarray could not open the store: {err}") from err


def _sample_index(group: zarr.Group, sample: int) -> int:
    n = group.attrs["n_samples"]
    if not 0 <= sample < n:
        raise StoreError(f"sample {sample} is outside the store's range 0..{n - 1}")
    return sample


def write_inputs(path: str | Path, sample: int, inputs: np.ndarray, mould_meta: dict) -> None:
    """Write one mould's input channels and metadata, then mark them ready."""
    group = open_group(path, mode="r+")
    i = _sample_index(group, sample)
    pixels = group.attrs["pixels"]
    if inputs.shape != (2, pixels, pixels):
        raise ValueError(f"inputs for sample {sample} have shape {inputs.shape}, store needs (2, {pixels}, {pixels})")
    with _quiet():
        group["inputs"][i] = inputs.astype("uint8")
        for name in MOULD_VARIABLES:
            group[name][i] = mould_meta[name]
        group["inputs_ready"][i] = 1


def write_sample(path: str | Path, sample: int, fields: np.ndarray | None, sim_meta: dict,
                 status: str) -> None:
    """Write one simulated sample: fields (None when it failed), metadata, then `status`."""
    if status == "ok" and fields is None:
        raise ValueError(f"sample {sample}: status 'ok' needs fields")
    if not status:
        raise ValueError(f"sample {sample}: status must be 'ok' or a failure reason, got ''")
    group = open_group(path, mode="r+")
    i = _sample_index(group, sample)
    with _quiet():
        if fields is not None:
            shape = group["fields"].shape[1:]
            if fields.shape != shape:
                raise ValueError(f"fields for sample {sample} have shape {fields.shape}, store needs {shape}")
            if not np.all(np.isfinite(fields)):
                raise ValueError(f"fields for sample {sample} contain NaN or inf")
            group["fields"][i] = fields.astype("float32")
        for name in SIMULATION_VARIABLES:
            group[name][i] = sim_meta[name]
        group["status"][i] = status[:STATUS_WIDTH]


def check_store(path: str | Path, deep: bool = False):
    """Per-sample state: a pandas DataFrame with columns sample, split, inputs_ready, status
    and `state`: "missing" (no inputs yet), "pending" (inputs, no simulation), "ok", "failed"
    or "corrupt" (a chunk cannot be decoded). `deep` also decodes every ok sample's fields."""
    import pandas as pd

    group = open_group(path)
    n = group.attrs["n_samples"]
    rows = []
    with _quiet():
        ready, status, split = (_read_each(group[k], n) for k in ("inputs_ready", "status", "split"))
        for i in range(n):
            if ready[i] is None or status[i] is None:
                state = "corrupt"
            elif not ready[i]:
                state = "missing"
            elif status[i] == "":
                state = "pending"
            elif status[i] == "ok":
                state = "ok" if not deep or _fields_readable(group, i) else "corrupt"
            else:
                state = "failed"
            rows.append({"sample": i, "split": split[i], "inputs_ready": ready[i],
                         "status": status[i], "state": state})
    return pd.DataFrame(rows)


def _read_each(array, n: int) -> list:
    """Read a per-sample array chunk by chunk so one corrupt chunk spoils only its sample."""
    try:
        return list(array[:])
    except Exception:
        values = []
        for i in range(n):
            try:
                values.append(array[i])
            except Exception:
                values.append(None)
        return values


def _fields_readable(group, i: int) -> bool:
    try:
        return bool(np.all(np.isfinite(group["fields"][i])))
    except Exception:
        return False
