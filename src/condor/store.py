"""The dataset store: one Zarr group described by xarray (contract in DESIGN.md).

Samples and replicas. A mould may be simulated with several seeds (replicas). Every
simulation is one sample: samples 0..n_moulds-1 are replica 0 of moulds 0..n_moulds-1 (so
`sample == mould` for them), then the extra replicas follow, mould by mould (replicas 1..R-1
of the first mould with R > 1, then of the next). `mould` and `replica` (per sample) address
them; `sample_index(mould, replica)` inverts the layout. Every replica carries its mould's
inputs and split. For moulds with more than one replica the `dataset` stage derives, along the
dimension `replicated` (coordinate: the mould ids), `fields_mean` (the expected fields: the
mean over the mould's ok replicas), `fields_std` (their standard deviation, ddof 1) and
`n_replicas_ok`.

Layout. Every per-sample array has `sample` first with one sample per chunk, so writers for
different samples touch disjoint files and never resize, append or re-consolidate: all arrays
are created, full size, by `create_store` and consolidated once. Every chunk carries a CRC32C
checksum (zarr's crc32c codec), so a flipped bit is caught when the chunk is read. A sample
becomes visible in stages, each finished by a flag written last:

- the mould stage writes `inputs` and the mould metadata of every replica, then
  `inputs_ready = 1`;
- the fields stage writes `fields` and the simulation metadata, then `status` ("ok", or the
  reason the simulation failed, in which case `fields` stays empty).

A job killed part-way leaves at most chunks whose flag is unset: `check_store` reports them
and a rerun overwrites them. Zarr's local store writes each chunk atomically (temporary file
then rename), so no chunk is ever half-written. `check_store` also compares every array's
metadata with what the store was created with and lists chunk files (no decompression) to
find a chunk that vanished; `deep=True` decodes and checksums every chunk.
"""

from __future__ import annotations

import json
import os
import shutil
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
import zarr
from zarr.codecs import Crc32cCodec, ZstdCodec

from condor import __version__
from condor.fields import FIELD_NAMES
from condor.inputs import LATTICE_CHANNELS

FORMAT = "condor-dataset"
FORMAT_VERSION = 3  # 3: the lattice channels (`lattice`) beside the masks
CHANNELS = ("mould", "tether")
SPLITS = ("train", "val", "test")

# Per-sample metadata: name -> (dtype, fill value). Strings are fixed-width (numpy "<U"),
# which xarray and numpy read as ordinary str arrays; failure reasons are cut to 160 chars.
STATUS_WIDTH = 160
SAMPLE_VARIABLES: dict[str, tuple[object, object]] = {
    "mould": ("int64", -1),
    "replica": ("int16", -1),
    "seed": ("int64", -1),
    "symmetry": ("<U24", ""),
    "order": ("int16", -1),
    "removal": ("<U24", ""),
    "n_tethers": ("int16", -1),
    "inputs_ready": ("uint8", 0),
    "sim_seed": ("int64", -1),
    "n_cells": ("int32", -1),
    "energy": ("float64", np.nan),
    "max_force": ("float64", np.nan),
    "solver": ("<U24", ""),
    "solver_seconds": ("float64", np.nan),
    "hardware": ("<U64", ""),
    "status": (f"<U{STATUS_WIDTH}", ""),
    "split": ("<U8", ""),
}
MOULD_VARIABLES = ("seed", "symmetry", "order", "removal", "n_tethers")
SIMULATION_VARIABLES = ("sim_seed", "n_cells", "energy", "max_force", "solver", "solver_seconds",
                        "hardware")
EXPECTED_VARIABLES = ("fields_mean", "fields_std", "n_replicas_ok")
CODECS = {"compressors": [ZstdCodec(level=3), Crc32cCodec()]}


class StoreError(RuntimeError):
    """The store is missing, foreign, truncated or incompatible with the request."""


@dataclass(frozen=True)
class StoreSpec:
    """What a store is built for; a store is reused only if its spec matches.

    split: one of SPLITS per mould; replicas: simulations per mould (default 1 each)."""

    n_moulds: int
    pixels: int
    seed: int
    split: tuple[str, ...]
    attrs: dict  # JSON-safe: scene, pixel size, sigma, model parameters, data config
    replicas: tuple[int, ...] | None = None

    @property
    def replica_counts(self) -> tuple[int, ...]:
        return self.replicas if self.replicas is not None else (1,) * self.n_moulds

    @property
    def n_samples(self) -> int:
        return int(sum(self.replica_counts))

    def check(self) -> None:
        if self.n_moulds < 1:
            raise ValueError(f"n_moulds must be >= 1, got {self.n_moulds}")
        if self.pixels < 4:
            raise ValueError(f"pixels must be >= 4, got {self.pixels}")
        if len(self.split) != self.n_moulds:
            raise ValueError(f"split has {len(self.split)} entries for {self.n_moulds} moulds")
        bad = sorted(set(self.split) - set(SPLITS))
        if bad:
            raise ValueError(f"unknown split name(s) {bad}; expected {SPLITS}")
        if len(self.replica_counts) != self.n_moulds or min(self.replica_counts) < 1:
            raise ValueError(f"replicas must give >= 1 per mould for {self.n_moulds} moulds, "
                             f"got {self.replicas}")


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


def sample_layout(replicas) -> tuple[np.ndarray, np.ndarray]:
    """(mould, replica) of every sample for `replicas` simulations per mould (module docs)."""
    counts = np.asarray(replicas, dtype=np.int64)
    moulds = [np.arange(len(counts))]
    reps = [np.zeros(len(counts), dtype=np.int64)]
    for m in np.flatnonzero(counts > 1):
        moulds.append(np.full(counts[m] - 1, m))
        reps.append(np.arange(1, counts[m]))
    return np.concatenate(moulds), np.concatenate(reps)


def sample_index(replicas, mould: int, replica: int) -> int:
    """The sample that holds `replica` of `mould` under the layout of `replicas`."""
    counts = np.asarray(replicas, dtype=np.int64)
    if not 0 <= mould < len(counts) or not 0 <= replica < counts[mould]:
        raise StoreError(f"mould {mould} replica {replica} is not in the store "
                         f"({len(counts)} moulds)")
    if replica == 0:
        return int(mould)
    extra = np.maximum(counts - 1, 0)
    return int(len(counts) + extra[:mould].sum() + replica - 1)


@contextmanager
def quiet_zarr():
    """Silence zarr's notices that consolidated metadata and string dtypes are not yet in the
    v3 spec (xarray reads both, and users should not see them on every write), and write every
    chunk, even one equal to the fill value (an all-zero mould): a chunk file then exists for
    every written sample, so `check_store` can find a lost one by listing files."""
    with warnings.catch_warnings(), zarr.config.set({"array.write_empty_chunks": True}):
        warnings.filterwarnings("ignore", message=".*string.*", category=UserWarning)
        warnings.filterwarnings("ignore", category=FutureWarning, module="zarr")
        warnings.filterwarnings("ignore", message=".*[Cc]onsolidated metadata.*")
        yield


def _expected_arrays(spec: StoreSpec) -> dict:
    """name -> (shape, chunks, dtype, dims) of every array the store holds."""
    n, p, f = spec.n_samples, spec.pixels, len(FIELD_NAMES)
    replicated = int(sum(r > 1 for r in spec.replica_counts))
    arrays = {
        "inputs": ((n, 2, p, p), (1, 2, p, p), "uint8", ("sample", "channel", "y", "x")),
        "lattice": ((n, 2, p, p), (1, 2, p, p), "float32", ("sample", "cell", "y", "x")),
        "fields": ((n, f, p, p), (1, f, p, p), "float32", ("sample", "field", "y", "x")),
    }
    for name, (dtype, _) in SAMPLE_VARIABLES.items():
        arrays[name] = ((n,), (1,), dtype, ("sample",))
    if replicated:
        for name in ("fields_mean", "fields_std"):
            arrays[name] = ((replicated, f, p, p), (1, f, p, p), "float32",
                            ("replicated", "field", "y", "x"))
        arrays["n_replicas_ok"] = ((replicated,), (replicated,), "int16", ("replicated",))
    return arrays


def create_store(path: str | Path, spec: StoreSpec) -> bool:
    """Create the store at `path` for `spec`; return True if created, False if a matching
    store already exists (its samples are kept). A store built for another spec is never
    touched: StoreError names the difference."""
    spec.check()
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise StoreError(f"{path} exists and is not a directory: it cannot hold a dataset store")
    if path.is_dir() and not any(path.iterdir()):
        path.rmdir()  # an empty folder holds nothing
    if path.exists():
        _check_compatible(path, spec)
        return False
    tmp = path.with_name(path.name + ".creating")
    if tmp.exists():
        shutil.rmtree(tmp)  # debris of an interrupted creation: holds no samples
    mould_of, replica_of = sample_layout(spec.replica_counts)
    with quiet_zarr():
        group = zarr.open_group(tmp, mode="w-", zarr_format=3)
        group.attrs.update({
            "format": FORMAT, "format_version": FORMAT_VERSION, "code_version": __version__,
            "n_moulds": spec.n_moulds, "n_samples": spec.n_samples, "pixels": spec.pixels,
            "seed": spec.seed, "replicas": list(spec.replica_counts), **spec.attrs,
        })
        _coordinate(group, "sample", np.arange(spec.n_samples, dtype="int64"))
        _coordinate(group, "channel", np.array(CHANNELS))
        _coordinate(group, "cell", np.array(LATTICE_CHANNELS))
        _coordinate(group, "field", np.array(FIELD_NAMES))
        replicated = np.flatnonzero(np.asarray(spec.replica_counts) > 1)
        if len(replicated):
            _coordinate(group, "replicated", replicated.astype("int64"))
        for name, (shape, chunks, dtype, dims) in _expected_arrays(spec).items():
            fill = SAMPLE_VARIABLES[name][1] if name in SAMPLE_VARIABLES else (
                np.nan if dtype == "float32" else 0)
            group.create_array(name, shape=shape, chunks=chunks, dtype=dtype, fill_value=fill,
                               dimension_names=dims, **CODECS)
        group["split"][:] = np.array(spec.split)[mould_of]
        group["mould"][:] = mould_of
        group["replica"][:] = replica_of
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
    if not path.is_dir():
        raise StoreError(f"{path} is a file, not a dataset store (a directory)")
    with quiet_zarr():
        try:
            group = zarr.open_group(path, mode=mode)
        except Exception as err:  # zarr raises several types for unreadable metadata
            raise StoreError(f"{path} is not a readable Zarr store: {err}") from err
        attrs = group.attrs
        if attrs.get("format") != FORMAT:
            raise StoreError(
                f"{path} is a Zarr store but not a condor dataset "
                f"(attribute 'format' is {attrs.get('format')!r}, expected {FORMAT!r})"
            )
        if attrs.get("format_version") != FORMAT_VERSION:
            raise StoreError(
                f"{path} has store format version {attrs.get('format_version')}, this code "
                f"reads version {FORMAT_VERSION}: rebuild it (a new `results` folder)"
            )
        expected = {"sample", "channel", "cell", "field", *_expected_arrays(spec_of(group)).keys()}
        # Consolidated metadata still lists an array whose folder was deleted: look on disk.
        missing = sorted(name for name in expected if not (path / name / "zarr.json").is_file())
        if missing:
            raise StoreError(f"{path} is truncated: missing array(s) {missing}")
    return group


def spec_of(group: zarr.Group) -> StoreSpec:
    """The StoreSpec a store's attributes describe (split and attrs are not needed to check
    its arrays and are left empty)."""
    attrs = group.attrs
    try:
        n_moulds, pixels = int(attrs["n_moulds"]), int(attrs["pixels"])
        replicas = tuple(int(r) for r in attrs["replicas"])
        seed = int(attrs["seed"])
    except (KeyError, TypeError, ValueError) as err:
        raise StoreError(f"store attributes lack or garble {err}: not a condor dataset") from err
    if len(replicas) != n_moulds or int(attrs.get("n_samples", -1)) != sum(replicas):
        raise StoreError(f"store attributes disagree: n_moulds {n_moulds}, replicas "
                         f"{len(replicas)} entries, n_samples {attrs.get('n_samples')}")
    return StoreSpec(n_moulds, pixels, seed, ("train",) * n_moulds, {}, replicas)


def _check_compatible(path: Path, spec: StoreSpec) -> None:
    attrs = open_group(path).attrs
    wanted = {"n_moulds": spec.n_moulds, "pixels": spec.pixels, "seed": spec.seed,
              "replicas": list(spec.replica_counts), **spec.attrs}
    diffs = [
        f"{key}: store has {attrs.get(key)!r}, config asks {value!r}"
        for key, value in wanted.items()
        if json.loads(json.dumps(attrs.get(key))) != json.loads(json.dumps(value))
    ]
    if diffs:
        raise StoreError(
            f"{path} was built for a different configuration ({'; '.join(diffs)}); "
            "point `results` at a new folder or delete the old store"
        )


def open_store(path: str | Path) -> xr.Dataset:
    """The store as a lazily loaded xarray.Dataset (validated first)."""
    open_group(path)
    with quiet_zarr():
        try:
            return xr.open_zarr(path, consolidated=True)
        except Exception as err:
            raise StoreError(f"{path}: xarray could not open the store: {err}") from err


def _sample(group: zarr.Group, sample: int) -> int:
    n = group["sample"].shape[0]
    if not 0 <= sample < n:
        raise StoreError(f"sample {sample} is outside the store's range 0..{n - 1}")
    return sample


def replica_samples(path: str | Path, mould: int) -> list[int]:
    """The samples holding every replica of `mould`, replica 0 first."""
    counts = spec_of(open_group(path)).replica_counts
    if not 0 <= mould < len(counts):
        raise StoreError(f"mould {mould} is not in the store (moulds 0..{len(counts) - 1})")
    return [sample_index(counts, mould, r) for r in range(counts[mould])]


def write_inputs(path: str | Path, mould: int, inputs: np.ndarray, mould_meta: dict,
                 lattice: np.ndarray) -> None:
    """Write one mould's input channels (masks), lattice channels (condor.inputs) and metadata
    into every replica, then mark them ready."""
    group = open_group(path, mode="r+")
    pixels = group.attrs["pixels"]
    for name, array in (("inputs", inputs), ("lattice", lattice)):
        if np.shape(array) != (2, pixels, pixels):
            raise ValueError(f"{name} for mould {mould} have shape {np.shape(array)}, store "
                             f"needs (2, {pixels}, {pixels})")
    if not np.all(np.isfinite(lattice)):
        raise ValueError(f"lattice channels of mould {mould} hold NaN or inf")
    samples = replica_samples(path, mould)
    with quiet_zarr():
        for i in samples:
            group["inputs"][i] = inputs.astype("uint8")
            group["lattice"][i] = np.asarray(lattice, dtype="float32")
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
    missing = [k for k in SIMULATION_VARIABLES if k not in sim_meta]
    if missing:
        raise ValueError(f"sample {sample}: simulation metadata lacks {missing}")
    group = open_group(path, mode="r+")
    i = _sample(group, sample)
    with quiet_zarr():
        if fields is not None:
            shape = group["fields"].shape[1:]
            if fields.shape != shape:
                raise ValueError(f"fields for sample {sample} have shape {fields.shape}, store needs {shape}")
            if not np.all(np.isfinite(fields)):
                raise ValueError(f"fields for sample {sample} contain NaN or inf")
            group["fields"][i] = fields.astype("float32")
        for name in SIMULATION_VARIABLES:
            value = sim_meta[name]
            group[name][i] = value[:64] if name == "hardware" else value
        group["status"][i] = status[:STATUS_WIDTH]


def write_expected(path: str | Path) -> int:
    """Derive the expected fields and their spread of every replicated mould from its ok
    replicas (fields_mean, fields_std with ddof 1, n_replicas_ok); NaN where fewer than 2
    replicas are ok. Returns the number of replicated moulds."""
    group = open_group(path, mode="r+")
    spec = spec_of(group)
    if "replicated" not in group:
        return 0
    moulds = group["replicated"][:]
    status = group["status"][:]
    counts = np.zeros(len(moulds), dtype="int16")
    with quiet_zarr():
        for k, mould in enumerate(moulds):
            samples = [s for s in (sample_index(spec.replica_counts, int(mould), r)
                                   for r in range(spec.replica_counts[mould]))
                       if status[s] == "ok"]
            counts[k] = len(samples)
            if len(samples) >= 2:
                stack = np.stack([group["fields"][s] for s in samples]).astype(np.float64)
                group["fields_mean"][k] = stack.mean(axis=0).astype("float32")
                group["fields_std"][k] = stack.std(axis=0, ddof=1).astype("float32")
        group["n_replicas_ok"][:] = counts
    return len(moulds)


# --- checking a store ------------------------------------------------------------------------

def check_metadata(path: str | Path) -> list[str]:
    """Problems with the arrays' metadata: the shape, chunks and data type zarr reads (the
    consolidated metadata) against what the attributes imply, and each array's own zarr.json
    against the consolidated copy (an edit to either is found)."""
    path = Path(path)
    group = open_group(path)
    consolidated = json.loads((path / "zarr.json").read_text()).get(
        "consolidated_metadata", {}).get("metadata", {})
    problems = []
    with quiet_zarr():
        for name, (shape, chunks, dtype, _) in _expected_arrays(spec_of(group)).items():
            array = group[name]
            if array.shape != shape:
                problems.append(f"array {name}: shape {list(array.shape)}, expected {list(shape)}")
            if array.chunks != chunks:
                problems.append(f"array {name}: chunks {list(array.chunks)}, expected {list(chunks)}")
            if np.dtype(array.dtype) != np.dtype(dtype):
                problems.append(f"array {name}: data type {array.dtype}, expected {dtype}")
            try:
                own = json.loads((path / name / "zarr.json").read_text())
            except (OSError, ValueError) as err:
                problems.append(f"array {name}: unreadable zarr.json ({err})")
                continue
            if name in consolidated and _core(own) != _core(consolidated[name]):
                problems.append(f"array {name}: its zarr.json differs from the store's "
                                "consolidated metadata (edited?)")
    return problems


def _core(meta: dict) -> tuple:
    return tuple(json.dumps(meta.get(k), sort_keys=True)
                 for k in ("shape", "data_type", "chunk_grid", "codecs", "fill_value"))


def chunk_indices(path: str | Path, name: str) -> set[int]:
    """Indices along the first axis of array `name` with a chunk file (zarr v3 default keys
    c/<i>/...): a listing, no chunk is read."""
    root = Path(path) / name / "c"
    if not root.is_dir():
        return set()
    return {int(entry.name) for entry in os.scandir(root) if entry.name.isdigit()}


def check_store(path: str | Path, deep: bool = False) -> pd.DataFrame:
    """Per-sample state: a DataFrame with columns sample, mould, replica, split, inputs_ready,
    status, `lost` (the array whose chunk file vanished, or "") and `state`: "missing" (no inputs yet), "pending" (inputs, no simulation), "ok",
    "failed" or "corrupt" (a chunk the state needs is absent, cannot be decoded or fails its
    checksum). Without `deep`, chunk files are listed (no decompression); `deep` decodes every
    ok sample's inputs and fields and checks them for NaN."""
    path = Path(path)
    group = open_group(path)
    n = group["sample"].shape[0]
    present = {name: chunk_indices(path, name) for name in ("inputs", "lattice", "fields")}
    rows = []
    with quiet_zarr():
        cols = {k: _read_each(group[k], n) for k in
                ("inputs_ready", "status", "split", "mould", "replica")}
        for i in range(n):
            ready, status = cols["inputs_ready"][i], cols["status"][i]
            lost = ""
            if ready is None or status is None:
                state = "corrupt"
            elif not ready:
                state = "missing"
            elif i not in present["inputs"]:
                state, lost = "corrupt", "inputs"
            elif i not in present["lattice"]:
                state, lost = "corrupt", "lattice"
            elif status == "":
                state = "pending"
            elif status == "ok":
                if i not in present["fields"]:
                    state, lost = "corrupt", "fields"
                else:
                    state = "ok" if not deep or _sample_readable(group, i) else "corrupt"
            else:
                state = "failed"
            rows.append({"sample": i, "mould": cols["mould"][i], "replica": cols["replica"][i],
                         "split": cols["split"][i], "inputs_ready": ready, "status": status,
                         "state": state, "lost": lost})
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


def _sample_readable(group, i: int) -> bool:
    try:
        return (bool(np.all(np.isfinite(group["fields"][i]))) and group["inputs"][i].size > 0
                and bool(np.all(np.isfinite(group["lattice"][i]))))
    except Exception:
        return False
