"""The dataset store: one Zarr group described by xarray (layout: docs/architecture.md).

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

- the mould stage writes `inputs`, `lattice`, the mould metadata and the mould's geometry
  (its outline and tethers, GEOMETRY_ARRAYS) of every replica, then `inputs_ready = 1`;
- the fields stage writes `fields` and the simulation metadata, then `status` ("ok", or the
  reason the simulation failed, in which case `fields` stays empty).

A job killed part-way leaves at most chunks whose flag is unset: `check_store` reports them
and a rerun overwrites them. Zarr's local store writes each chunk atomically (temporary file
then rename), so no chunk is ever half-written. The store is created with its layout (the
coordinates and each sample's mould, replica and split) and the dataset stage derives the
expected fields; `restore_layout` writes the layout again where it was damaged.

Checks and repair (`check_store`, `scan_store`, `restore_layout`): condor.data.store_check.
"""

from __future__ import annotations

import json
import shutil
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr
import zarr
from zarr.codecs import Crc32cCodec, ZstdCodec

from condor.version import __version__
from condor.data.fields import FIELD_NAMES
from condor.data.geometry_arrays import (MAX_TETHERS, MAX_VERTICES, outline_arrays,
                                          tether_arrays)
from condor.data.inputs import LATTICE_CHANNELS

FORMAT = "condor-dataset"
FORMAT_VERSION = 6  # 3: the lattice channels (`lattice`) beside the masks; 4: x and y
# coordinates (pixel centres, l0) and CF attributes (units, long_name) on every array; 5: each
# mould's geometry (GEOMETRY_ARRAYS: its outline and its tethers, l0); 6: each mould's family
# (the paper's generator or a lab family)
FORMAT_CHANGES = {3: "the lattice channels", 4: "x and y coordinates and CF attributes",
                  5: "the mould geometry (outline_x, outline_y, tether_x, tether_y, tether_r)",
                  6: "each mould's family (paper, or a lab family)"}
CHANNELS = ("mould", "tether")
SPLITS = ("train", "val", "test")

# Per-sample metadata: name -> (dtype, fill value). Strings are fixed-width (numpy "<U"),
# which xarray and numpy read as ordinary str arrays; failure reasons are cut to 160 chars.
STATUS_WIDTH = 160
SAMPLE_VARIABLES: dict[str, tuple[object, object]] = {
    "mould": ("int64", -1),
    "replica": ("int16", -1),
    "seed": ("int64", -1),
    "family": ("<U24", ""),
    "symmetry": ("<U24", ""),
    "order": ("int16", -1),
    "removal": ("<U24", ""),
    "n_tethers": ("int16", -1),
    "outline_vertices": ("int32", -1),
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
MOULD_VARIABLES = ("seed", "family", "symmetry", "order", "removal", "n_tethers")
# The mould's geometry, per sample like its metadata (every replica carries it), in l0 in the
# frame of the x and y coordinates, encoded by condor.data.geometry_arrays: its outline in
# outline_x/outline_y along `vertex` (MAX_VERTICES), outline_vertices of them in use; its
# tethers (x, y, radius) along `tether` (MAX_TETHERS), n_tethers of them.
GEOMETRY_ARRAYS = ("outline_x", "outline_y", "outline_vertices", "tether_x", "tether_y",
                   "tether_r")
SIMULATION_VARIABLES = ("sim_seed", "n_cells", "energy", "max_force", "solver", "solver_seconds",
                        "hardware")
EXPECTED_VARIABLES = ("fields_mean", "fields_std", "n_replicas_ok")
# Who writes each array, and so which step rewrites a damaged chunk of it: the mould stage
# (write_inputs), the fields stage (write_sample), the store's creation (the layout, which
# restore_layout rewrites) and the dataset stage (write_expected, EXPECTED_VARIABLES).
MOULD_ARRAYS = ("inputs", "lattice", *MOULD_VARIABLES, *GEOMETRY_ARRAYS, "inputs_ready")
SAMPLE_ARRAYS = ("fields", *SIMULATION_VARIABLES, "status")
COORDINATES = ("sample", "channel", "cell", "field", "replicated", "x", "y")
# CF attributes of every array (units "1": dimensionless; "l0": the cells' spacing, the
# length unit of the model; the fields are kernel-weighted sums over cells, per pixel).
_FIELDS_LONG = ("per pixel, the kernel-weighted sum over cells of P (cells), T, Sx2, Sy2, Sz2, "
                "SxSy, SxSz, SySz (the orientation tensor s_a s_b)")
VARIABLE_ATTRS = {
    "sample": {"long_name": "simulation (replica 0 of moulds 0..n-1, then the extra replicas)"},
    "channel": {"long_name": "input channel"},
    "cell": {"long_name": "lattice channel: mobile or fixed cells"},
    "field": {"long_name": "field name"},
    "replicated": {"long_name": "mould id of a mould simulated with several seeds"},
    "x": {"units": "l0", "long_name": "x of the pixel centre from the box's left edge, in cell "
          "spacings l0", "standard_name": "projection_x_coordinate", "axis": "X"},
    "y": {"units": "l0", "long_name": "y of the pixel centre from the box's lower edge, in cell "
          "spacings l0", "standard_name": "projection_y_coordinate", "axis": "Y"},
    "inputs": {"units": "1", "long_name": "input masks: mould, tether (0/1; the paper's inputs)"},
    "lattice": {"units": "1", "long_name": "the mould's initial mobile and fixed cells, "
                "rasterised with the fields' kernel, in units of a full FCC column"},
    "fields": {"units": "1", "long_name": "fields of one simulation: " + _FIELDS_LONG},
    "fields_mean": {"units": "1", "long_name": "expected fields: the mean over the mould's ok "
                    "replicas; " + _FIELDS_LONG},
    "fields_std": {"units": "1", "long_name": "standard deviation of one replica's fields "
                   "about their mean (ddof 1)"},
    "n_replicas_ok": {"units": "1", "long_name": "ok replicas of the mould"},
    "mould": {"long_name": "mould id"}, "replica": {"long_name": "replica number (seed index)"},
    "seed": {"long_name": "the generator's seed of the mould"},
    "family": {"long_name": "the mould's source: 'paper' (the paper's generator) or a lab "
               "family (condor.moulds.lab)"},
    "symmetry": {"long_name": "the generator's symmetry regime"},
    "order": {"units": "1", "long_name": "rotation order of the mould's symmetry"},
    "removal": {"long_name": "the generator's tether removal rule"},
    "n_tethers": {"units": "1", "long_name": "tethers (posts) of the mould"},
    **{f"outline_{axis}": {
        "units": "l0", "long_name": f"{axis} of the mould outline's vertices: the exterior ring "
        "(closed, its first vertex repeated last), then each hole's ring (closed) after one "
        "NaN; outline_vertices in use, NaN after",
        "frame": f"box coordinates, the frame of the {axis} coordinate: from the box's "
        f"{'left' if axis == 'x' else 'lower'} edge, in cell spacings l0"} for axis in "xy"},
    "outline_vertices": {"units": "1", "long_name": "entries of outline_x and outline_y in use "
                         "(the rings' vertices and the NaN between rings)"},
    **{f"tether_{axis}": {
        "units": "l0", "long_name": f"{axis} of each tether's (post's) centre; n_tethers in "
        "use, NaN after",
        "frame": f"box coordinates, the frame of the {axis} coordinate: from the box's "
        f"{'left' if axis == 'x' else 'lower'} edge, in cell spacings l0"} for axis in "xy"},
    "tether_r": {"units": "l0", "long_name": "radius of each tether (post); n_tethers in use, "
                 "NaN after"},
    "inputs_ready": {"long_name": "flag: the mould's inputs are written"},
    "sim_seed": {"long_name": "the simulation's seed"},
    "n_cells": {"units": "1", "long_name": "cells of the mould (N_c, the lattice's sites)"},
    "energy": {"units": "1", "long_name": "final CONDOR energy per cell"},
    "max_force": {"units": "1", "long_name": "largest residual force of the final state"},
    "solver": {"long_name": "simulator"},
    "solver_seconds": {"units": "s", "long_name": "the solver's CPU time"},
    "hardware": {"long_name": "machine the simulation ran on"},
    "status": {"long_name": "ok, or why the simulation failed"},
    "split": {"long_name": "train, val or test"},
}
LAYOUT_VARIABLES = ("split", "mould", "replica")
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


def assign_splits(n_samples: int, n_test: int, val_fraction: float, seed: int,
                  pinned=()) -> tuple[str, ...]:
    """Deterministic split: a seeded permutation gives `n_test` test samples, then
    `val_fraction` of the rest (rounded) for validation, the remainder for training.
    `pinned` samples (those below n_samples; the moulds with a paper reference) are moved to
    the front of the permutation, so they are always test samples; when they are test
    samples of the plain permutation already, the split is the plain one."""
    if not 0 <= n_test < n_samples:
        raise ValueError(f"split.test must be in [0, n_moulds), got {n_test} for {n_samples} moulds")
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"split.val_fraction must be in [0, 1), got {val_fraction}")
    order = np.random.default_rng([seed, 0x5B117]).permutation(n_samples)
    pinned = sorted({int(p) for p in pinned if 0 <= int(p) < n_samples})
    if len(pinned) > n_test:
        raise ValueError(f"split.test must hold the {len(pinned)} moulds with a paper reference "
                         f"({pinned}), got {n_test}")
    if pinned:
        front = np.isin(order, pinned)
        order = np.concatenate([order[front], order[~front]])
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


def expected_arrays(spec: StoreSpec) -> dict:
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
    for name, dim, size in (("outline_x", "vertex", MAX_VERTICES),
                            ("outline_y", "vertex", MAX_VERTICES),
                            *((f"tether_{a}", "tether", MAX_TETHERS) for a in "xyr")):
        arrays[name] = ((n, size), (1, size), "float64", ("sample", dim))
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
    with quiet_zarr():
        group = zarr.open_group(tmp, mode="w-", zarr_format=3)
        group.attrs.update({
            "Conventions": "CF-1.10", "format": FORMAT, "format_version": FORMAT_VERSION, "code_version": __version__,
            "n_moulds": spec.n_moulds, "n_samples": spec.n_samples, "pixels": spec.pixels,
            "seed": spec.seed, "replicas": list(spec.replica_counts), **spec.attrs,
        })
        layout = layout_values(spec, spec.split)
        for name in COORDINATES:
            if name in layout:
                _coordinate(group, name, layout[name])
        for name, (shape, chunks, dtype, dims) in expected_arrays(spec).items():
            fill = SAMPLE_VARIABLES[name][1] if name in SAMPLE_VARIABLES else (
                np.nan if dtype.startswith("float") else 0)
            group.create_array(name, shape=shape, chunks=chunks, dtype=dtype, fill_value=fill,
                               dimension_names=dims, attributes=VARIABLE_ATTRS.get(name, {}),
                               **CODECS)
        for name in LAYOUT_VARIABLES:
            group[name][:] = layout[name]
        zarr.consolidate_metadata(tmp)
    tmp.rename(path)  # the store appears whole or not at all
    return True


def layout_values(spec: StoreSpec, split=None) -> dict[str, np.ndarray]:
    """What create_store writes and no later stage rewrites: the coordinates, and each
    sample's mould, replica and (given the per-mould `split`) split."""
    mould_of, replica_of = sample_layout(spec.replica_counts)
    values = {"sample": np.arange(spec.n_samples, dtype="int64"), "channel": np.array(CHANNELS),
              "cell": np.array(LATTICE_CHANNELS), "field": np.array(FIELD_NAMES)}
    replicated = np.flatnonzero(np.asarray(spec.replica_counts) > 1)
    if len(replicated):
        values["replicated"] = replicated.astype("int64")
    if spec.attrs.get("pixel_size") is not None:  # pixel centres, l0
        values["x"] = values["y"] = (np.arange(spec.pixels) + 0.5) * float(spec.attrs["pixel_size"])
    values["mould"], values["replica"] = mould_of, replica_of
    if split is not None:
        values["split"] = np.array(split)[mould_of]
    return values


def _coordinate(group, name: str, values: np.ndarray) -> None:
    arr = group.create_array(
        name, shape=values.shape, chunks=values.shape, dtype=values.dtype,
        fill_value="" if values.dtype.kind == "U" else 0, dimension_names=(name,),
        attributes=VARIABLE_ATTRS.get(name, {}),
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
            version = attrs.get("format_version")
            added = [text for v, text in sorted(FORMAT_CHANGES.items())
                     if isinstance(version, int) and v > version]
            raise StoreError(
                f"{path} has store format version {version}, this code "
                f"reads version {FORMAT_VERSION}" + (f" (which adds {'; '.join(added)})"
                                                     if added else "")
                + ": rebuild it (a new `results` folder)"
            )
        expected = {"sample", "channel", "cell", "field", *expected_arrays(spec_of(group)).keys()}
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
    extra = {"pixel_size": attrs["pixel_size"]} if "pixel_size" in attrs else {}
    return StoreSpec(n_moulds, pixels, seed, ("train",) * n_moulds, extra, replicas)


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
                 lattice: np.ndarray, *, polygon, tethers) -> None:
    """Write one mould's input channels (masks), lattice channels (condor.data.inputs),
    metadata and geometry (its outline `polygon`, shapely, and `tethers` (n, 3): x, y, radius
    in l0, box coordinates; GEOMETRY_ARRAYS) into every replica, then mark them ready.
    Everything is checked before anything is written."""
    group = open_group(path, mode="r+")
    pixels = group.attrs["pixels"]
    for name, array in (("inputs", inputs), ("lattice", lattice)):
        if np.shape(array) != (2, pixels, pixels):
            raise ValueError(f"{name} for mould {mould} have shape {np.shape(array)}, store "
                             f"needs (2, {pixels}, {pixels})")
    if not np.all(np.isfinite(lattice)):
        raise ValueError(f"lattice channels of mould {mould} hold NaN or inf")
    try:
        outline_x, outline_y, vertices = outline_arrays(polygon)
        tether_x, tether_y, tether_r = tether_arrays(tethers)
    except ValueError as err:
        raise ValueError(f"mould {mould}: {err}") from err
    n_tethers = int(np.isfinite(tether_r).sum())
    if n_tethers != mould_meta["n_tethers"]:
        raise ValueError(f"mould {mould}: {n_tethers} tethers given, its metadata says "
                         f"n_tethers = {mould_meta['n_tethers']}")
    geometry = {"outline_x": outline_x, "outline_y": outline_y, "outline_vertices": vertices,
                "tether_x": tether_x, "tether_y": tether_y, "tether_r": tether_r}
    samples = replica_samples(path, mould)
    with quiet_zarr():
        for i in samples:
            group["inputs"][i] = inputs.astype("uint8")
            group["lattice"][i] = np.asarray(lattice, dtype="float32")
            for name in MOULD_VARIABLES:  # a writer from before families gives none
                group[name][i] = mould_meta.get(name, "") if name == "family" else \
                    mould_meta[name]
            for name in GEOMETRY_ARRAYS:
                group[name][i] = geometry[name]
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
            samples = ok_replicas(spec, int(mould), status)
            counts[k] = len(samples)
            if len(samples) >= 2:
                mean, std = expected_fields([group["fields"][s] for s in samples])
                group["fields_mean"][k] = mean
                group["fields_std"][k] = std
        group["n_replicas_ok"][:] = counts
    return len(moulds)


def ok_replicas(spec: StoreSpec, mould: int, status) -> list[int]:
    """The samples of `mould`'s replicas whose `status` (per sample) is "ok"."""
    return [s for s in (sample_index(spec.replica_counts, mould, r)
                        for r in range(spec.replica_counts[mould])) if status[s] == "ok"]


def expected_fields(replicas) -> tuple[np.ndarray, np.ndarray]:
    """(fields_mean, fields_std) of one mould from its ok replicas' fields (two or more):
    the mean and the standard deviation (ddof 1), in float64, stored as float32. The one rule
    that write_expected writes and the deep check (condor.data.store_check) recomputes."""
    stack = np.stack(list(replicas)).astype(np.float64)
    return stack.mean(axis=0).astype("float32"), stack.std(axis=0, ddof=1).astype("float32")
