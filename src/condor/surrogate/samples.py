"""Dataset access for the surrogate: usable samples, [-1, 1] scaling, resampling.

The dataset is an xarray.Dataset with `inputs` (sample, channel, y, x) 0/1, `lattice`
(sample, cell, y, x; condor.data.inputs), `fields`
(sample, field, y, x) float32, `split` and `status` per sample (see docs/surrogate.md).
Samples are read one at a time (one zarr chunk per sample) unless the selection is small
enough to hold in memory.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import torch

from condor.data.dataset import usable_samples  # noqa: F401  (the one home; re-exported here)
from condor.data.fields import FIELD_NAMES
from condor.data.inputs import derived_channels
from condor.data.store import CHANNELS as CHANNEL_NAMES
from condor.data.store import SPLITS  # noqa: F401

# What a model reads, and the field pairs the transpose swaps (one range each): their home is
# settings.py (no torch); exported here too, as before
from .settings import (DERIVED_INPUTS, INPUT_VARIABLES, PAIRED_FIELDS,  # noqa: F401
                       VARIABLE_CHANNELS, n_input_channels)

PRELOAD_BYTES = 512 * 2 ** 20  # hold a selection in memory when it is smaller than this
# Input channel order after x <-> y, per kind whose channels are not all scalars: the stress
# channels sigma_xx, sigma_yy swap (sigma_xy stays).
_INPUTS_TRANSPOSED = {"mechanics": (0, 1, 2, 3, 5, 4), "mechanics_shear": (0, 1, 2, 3, 5, 4, 6)}
# Input channels that change sign under each mirror: sigma_xy.
_INPUTS_ODD = {"mechanics_shear": (6,)}


class DataError(ValueError):
    """Training or evaluation data that cannot be used; the message names the samples."""


def _unreadable(ds, position) -> list[str]:
    """The arrays of sample `position` that cannot be read (a corrupt or lost chunk)."""
    sel = ds.isel(sample=int(position))
    bad = []
    for name in ("inputs", "fields"):
        try:
            np.asarray(sel[name].values)
        except Exception:
            bad.append(name)
    return bad


def _readable(ds, position) -> bool:
    return not _unreadable(ds, position)


def _named(ds, positions) -> list:
    positions = np.atleast_1d(np.asarray(positions))
    ids = ds["sample"].values[positions] if "sample" in ds.coords else positions
    return [int(i) for i in ids[:12]]


def check_dataset(ds) -> None:
    """Raise ValueError when `ds` lacks a variable or the channel/field names differ."""
    for name in ("inputs", "fields", "split", "status"):
        if name not in ds:
            raise ValueError(f"dataset has no variable {name!r}")
    if "field" in ds.coords and tuple(map(str, ds["field"].values)) != FIELD_NAMES:
        raise ValueError(f"dataset fields {list(map(str, ds['field'].values))} != {FIELD_NAMES}")
    if "channel" in ds.coords and tuple(map(str, ds["channel"].values)) != CHANNEL_NAMES:
        raise ValueError(f"dataset channels {list(map(str, ds['channel'].values))} != "
                         f"{CHANNEL_NAMES}")


def dataset_pixel_size(ds) -> float:
    """Pixel side in l0 from the dataset's attributes ("pixel_size", or the scene)."""
    for key in ("pixel_size", "pixel_size_l0"):
        if key in ds.attrs:
            return float(ds.attrs[key])
    scene = ds.attrs.get("scene")
    if isinstance(scene, dict) and "box" in scene:
        return float(scene["box"]) / int(ds.sizes["x"])
    if isinstance(scene, str):
        from condor.model.scenes import get_scene
        return get_scene(scene).box / int(ds.sizes["x"])
    raise ValueError(f"cannot tell the pixel size: dataset attributes {sorted(ds.attrs)} have no "
                     "'pixel_size' or 'scene'; pass pixel_size=")


# --- resampling ----------------------------------------------------------------------------

def _factor(size_from: int, size_to: int) -> tuple[int, bool]:
    """Integer ratio between two grid sides and whether it is an upsampling."""
    big, small = max(size_from, size_to), min(size_from, size_to)
    if small < 1 or big % small:
        raise ValueError(f"cannot resample {size_from} px to {size_to} px: not an integer ratio")
    return big // small, size_to > size_from


def _block(a: np.ndarray, f: int) -> np.ndarray:
    h, w = a.shape[-2:]
    return a.reshape(*a.shape[:-2], h // f, f, w // f, f)


def resample_masks(masks: np.ndarray, size: int) -> np.ndarray:
    """Masks (..., H, W) 0/1 -> (..., size, size): nearest (pixel replication) when
    upsampling, majority of each block (area >= 1/2) when downsampling."""
    f, up = _factor(masks.shape[-1], size)
    if f == 1:
        return masks
    if up:
        return masks.repeat(f, axis=-2).repeat(f, axis=-1)
    return (_block(masks, f).mean(axis=(-3, -1)) >= 0.5).astype(masks.dtype)


def resample_inputs(inputs: np.ndarray, size: int, kind: str = "mask") -> np.ndarray:
    """Model inputs (..., C, H, W) of `kind` -> (..., C, size, size): masks by
    resample_masks; lattice channels (cells per pixel in column units, a density) by
    replication up, block means down."""
    if kind in ("both", "mechanics", "mechanics_shear"):  # masks, then lattice, stress
        return np.concatenate([resample_masks(inputs[..., :2, :, :], size),
                               resample_inputs(inputs[..., 2:, :, :], size, "lattice")], axis=-3)
    if kind == "mask":
        return resample_masks(inputs, size)
    f, up = _factor(inputs.shape[-1], size)
    if f == 1:
        return inputs
    if up:
        return inputs.repeat(f, axis=-2).repeat(f, axis=-1)
    return _block(inputs, f).mean(axis=(-3, -1)).astype(inputs.dtype)


def check_input_variables(ds, kind: str) -> None:
    """ValueError for an unknown kind, DataError when `ds` lacks a variable `kind` reads."""
    if kind not in INPUT_VARIABLES:
        raise ValueError(f"inputs kind {kind!r} is not one of {tuple(INPUT_VARIABLES)}")
    for name in INPUT_VARIABLES[kind]:
        name = DERIVED_INPUTS.get(name, name)
        if name not in ds:
            raise DataError(f"the dataset has no {name!r} variable, which a model with inputs "
                            f"{kind!r} reads (a store from before format 3?): rebuild the "
                            "store, or train with inputs 'mask'")


def _input_arrays(sel, kind: str) -> np.ndarray:
    def array(name):
        if name in DERIVED_INPUTS:
            return derived_channels(np.asarray(sel[DERIVED_INPUTS[name]].values), name)
        return np.asarray(sel[name].values, dtype=np.float32)

    return np.concatenate([array(name) for name in INPUT_VARIABLES[kind]], axis=-3)


def model_inputs(ds, positions, kind: str = "mask") -> np.ndarray:
    """The inputs a model of `kind` reads for samples `positions`: (S, C, H, W) float32 from
    the store variables INPUT_VARIABLES[kind]; DataError when the dataset lacks one."""
    check_input_variables(ds, kind)
    return _input_arrays(ds.isel(sample=np.asarray(positions)), kind)


def resample_fields(fields: np.ndarray, size: int) -> np.ndarray:
    """Fields (..., H, W) -> (..., size, size), conserving each field's sum over any block
    (the fields are pixel integrals): block sums when downsampling, replication divided by the
    pixel-area ratio when upsampling. Down(up(f)) == f exactly."""
    f, up = _factor(fields.shape[-1], size)
    if f == 1:
        return fields
    if up:
        return fields.repeat(f, axis=-2).repeat(f, axis=-1) / fields.dtype.type(f * f)
    return _block(fields, f).sum(axis=(-3, -1))


# --- symmetries --------------------------------------------------------------------------
# The model and the square, centred box are symmetric under D4 (mirrors in x and y, the x<->y
# transpose) times the z-reflection of the slab: 16 transforms, numbered 0..15 by the bits
# TRANSPOSE, MIRROR_X, MIRROR_Y, FLIP_Z (0 = identity). Transform k applies its generators in
# that order; each generator is an involution, so the inverse applies them in reverse.
TRANSPOSE, MIRROR_X, MIRROR_Y, FLIP_Z = 1, 2, 4, 8
N_SYMMETRIES = 16
# Fields whose sign flips under each reflection (a tensor component s_a s_b is odd under the
# reflection of axis a when exactly one of a, b is that axis).
_ODD = {MIRROR_X: ("SxSy", "SxSz"), MIRROR_Y: ("SxSy", "SySz"), FLIP_Z: ("SxSz", "SySz")}
# Field order after x <-> y: Sx2 <-> Sy2, SxSz <-> SySz.
_TRANSPOSED = ("P", "T", "Sy2", "Sx2", "Sz2", "SxSy", "SySz", "SxSz")
ODD_FIELDS = ("SxSy", "SxSz", "SySz")  # odd under some reflection: scaling must be symmetric


def _field_signs(generator: int) -> np.ndarray:
    return np.array([-1.0 if f in _ODD[generator] else 1.0 for f in FIELD_NAMES])


def _check_symmetry(k: int) -> int:
    if not 0 <= int(k) < N_SYMMETRIES or int(k) != k:
        raise ValueError(f"symmetry index {k!r} is not an integer in [0, {N_SYMMETRIES})")
    return int(k)


def _generators(k: int) -> list[int]:
    return [g for g in (TRANSPOSE, MIRROR_X, MIRROR_Y, FLIP_Z) if k & g]


def _apply_generator(g: int, inputs, fields, input_kind: str = "mask"):
    """One generator on inputs (..., C, H, W) of `input_kind` (or None) and fields
    (..., 8, H, W) (or None), numpy or torch; fields in physical units or under a symmetric
    scaling."""
    is_torch = torch.is_tensor(fields if fields is not None else inputs)

    def flip(a, axis):
        return None if a is None else (torch.flip(a, (axis,)) if is_torch else np.flip(a, axis))

    def swap(a):
        return None if a is None else a.transpose(-1, -2) if is_torch else np.swapaxes(a, -1, -2)

    if g == TRANSPOSE:
        inputs, fields = swap(inputs), swap(fields)
        if inputs is not None and input_kind in _INPUTS_TRANSPOSED:
            inputs = inputs[..., list(_INPUTS_TRANSPOSED[input_kind]), :, :]
        if fields is not None:
            order = [FIELD_NAMES.index(f) for f in _TRANSPOSED]
            fields = fields[..., order, :, :]
    elif g in (MIRROR_X, MIRROR_Y):
        axis = -1 if g == MIRROR_X else -2
        inputs, fields = flip(inputs, axis), flip(fields, axis)
        if inputs is not None and input_kind in _INPUTS_ODD:
            signs = np.ones(inputs.shape[-3])
            signs[list(_INPUTS_ODD[input_kind])] = -1
            signs = signs.reshape(-1, 1, 1)
            inputs = inputs * (torch.as_tensor(signs, dtype=inputs.dtype, device=inputs.device)
                               if is_torch else signs.astype(inputs.dtype))
    if fields is not None and g in _ODD:
        signs = _field_signs(g).reshape(-1, 1, 1)
        fields = fields * (torch.as_tensor(signs, dtype=fields.dtype, device=fields.device)
                           if is_torch else signs.astype(fields.dtype))
    return inputs, fields


def apply_symmetry(k: int, inputs=None, fields=None, inverse: bool = False,
                   input_kind: str = "mask"):
    """Transform k (0..15, see TRANSPOSE/MIRROR_X/MIRROR_Y/FLIP_Z) of a sample: inputs
    (..., C, H, W) and/or fields (..., 8, H, W), numpy or torch (either may be None). Fields
    must be physical (unscaled) or scaled by a `FieldScaling.symmetrised()` scaling. Returns
    (inputs, fields); `inverse` applies the inverse transform. `input_kind` (a
    TrainConfig.inputs kind) says which input channels the transpose swaps."""
    gens = _generators(_check_symmetry(k))
    for g in (reversed(gens) if inverse else gens):
        inputs, fields = _apply_generator(g, inputs, fields, input_kind)
    return inputs, fields


# --- scaling -------------------------------------------------------------------------------

@dataclass
class FieldScaling:
    """Per-field affine map of [lo, hi] (training-split min/max, at the model resolution) to
    [-1, 1]. A constant field (hi == lo) maps to -1 and back to lo."""

    lo: np.ndarray  # (n_fields,)
    hi: np.ndarray
    field_names: tuple = FIELD_NAMES

    def __post_init__(self):
        self.lo = np.asarray(self.lo, dtype=np.float64)
        self.hi = np.asarray(self.hi, dtype=np.float64)
        if self.lo.shape != self.hi.shape or self.lo.shape != (len(self.field_names),):
            raise ValueError(f"scaling lo {self.lo.shape} / hi {self.hi.shape} do not match "
                             f"{len(self.field_names)} fields")
        if np.any(self.hi < self.lo):
            raise ValueError(f"scaling hi {self.hi} below lo {self.lo}")

    def _span(self) -> np.ndarray:
        return np.where(self.hi > self.lo, self.hi - self.lo, 1.0)

    def _shape(self, a, values):
        # Broadcast per-field values over (..., field, y, x).
        v = values.reshape(-1, 1, 1)
        return torch.as_tensor(v, dtype=a.dtype, device=a.device) if torch.is_tensor(a) \
            else v.astype(a.dtype)

    def scale(self, fields):
        """(..., n_fields, H, W) physical values -> [-1, 1] (numpy or torch)."""
        return (fields - self._shape(fields, self.lo)) * self._shape(fields, 2.0 / self._span()) - 1

    def unscale(self, scaled):
        return (scaled + 1) * self._shape(scaled, self._span() / 2.0) + self._shape(scaled, self.lo)

    def symmetrised(self) -> "FieldScaling":
        """The smallest scaling containing this one that commutes with every symmetry
        (`apply_symmetry`): odd fields get [-m, m] with m = max(|lo|, |hi|), and the fields
        swapped by the transpose share the union of their ranges."""
        lo, hi = self.lo.copy(), self.hi.copy()
        idx = {f: i for i, f in enumerate(self.field_names)}
        for a, b in PAIRED_FIELDS:
            lo[[idx[a], idx[b]]] = min(lo[idx[a]], lo[idx[b]])
            hi[[idx[a], idx[b]]] = max(hi[idx[a]], hi[idx[b]])
        for f in ODD_FIELDS:
            m = max(abs(lo[idx[f]]), abs(hi[idx[f]]))
            lo[idx[f]], hi[idx[f]] = -m, m
        return FieldScaling(lo, hi, self.field_names)

    def to_dict(self) -> dict:
        return {"lo": self.lo.tolist(), "hi": self.hi.tolist(), "field_names": list(self.field_names)}

    @classmethod
    def from_dict(cls, d: dict) -> "FieldScaling":
        return cls(np.array(d["lo"]), np.array(d["hi"]), tuple(d["field_names"]))


def _chunks(indices: np.ndarray, n: int):
    for start in range(0, len(indices), n):
        yield indices[start:start + n]


def compute_scaling(ds, indices: np.ndarray, size: int | None = None, chunk: int = 16) -> FieldScaling:
    """Min/max per field over the samples `indices` (the training split), after resampling to
    `size` (the model's resolution) when given. Reads `chunk` samples at a time."""
    if len(indices) == 0:
        raise ValueError("cannot compute a field scaling from zero samples")
    lo = np.full(len(FIELD_NAMES), np.inf)
    hi = np.full(len(FIELD_NAMES), -np.inf)
    for part in _chunks(np.asarray(indices), chunk):
        f = np.asarray(ds["fields"].isel(sample=part).values, dtype=np.float32)
        if size is not None:
            f = resample_fields(f, size)
        lo = np.minimum(lo, f.min(axis=(0, 2, 3)))
        hi = np.maximum(hi, f.max(axis=(0, 2, 3)))
    return FieldScaling(lo, hi)


# --- samples -------------------------------------------------------------------------------

def read_samples(ds, positions, read):
    """read(ds.isel(sample=positions)); DataError naming the unreadable samples when a chunk
    cannot be read."""
    try:
        return read(ds.isel(sample=positions))
    except Exception as err:  # zarr/numcodecs raise many types for a corrupt chunk
        bad = {p: _unreadable(ds, p) for p in np.atleast_1d(positions)}
        bad = {p: arrays for p, arrays in bad.items() if arrays}
        where = f"sample(s) {_named(ds, list(bad) or positions)}" + (" (" + "; ".join(
            f"sample {i}, array {', '.join(bad[p])}" for p, i in zip(bad, _named(ds, list(bad))))
            + ")" if bad else "")
        raise DataError(f"cannot read {where} of the dataset ({type(err).__name__}: "
                        f"{str(err)[:200]}); condor check-store --deep lists the damaged chunks "
                        "and moves them aside, and the next workflow run rebuilds them") from None


def data_fingerprint(ds, selections: dict, kind: str = "mask", replica_mean: bool = False,
                     chunk: int = 16) -> str:
    """sha256 (hex) of what training reads of `ds`: for each named selection ({"train":
    positions, "val": positions}) its sample ids and, `chunk` samples at a time, the bytes,
    dtype and shape of the store variables a model of inputs `kind` reads, the fields and N_c;
    with `replica_mean`, the replica means of the training moulds. Any changed value, sample
    or split gives another fingerprint."""
    check_input_variables(ds, kind)
    names = [DERIVED_INPUTS.get(name, name) for name in INPUT_VARIABLES[kind]]
    names = [name for name in dict.fromkeys([*names, "fields", "n_cells"]) if name in ds]
    digest = hashlib.sha256()

    def add(label: str, values) -> None:
        a = np.ascontiguousarray(values)
        if a.dtype == object:  # the bytes of an object array are addresses, not values
            a = a.astype(str)
        digest.update(f"{label} {a.dtype.str} {a.shape};".encode())
        digest.update(a.tobytes())

    for role, positions in selections.items():
        positions = np.asarray(positions, dtype=np.int64)
        add(f"{role} sample", ds["sample"].values[positions] if "sample" in ds.coords else positions)
        for start in range(0, len(positions), chunk):
            part = positions[start:start + chunk]
            for name, values in zip(names, read_samples(
                    ds, part, lambda sel: [np.asarray(sel[n].values) for n in names])):
                add(f"{role} {name}", values)
    if replica_mean and "fields_mean" in ds and "train" in selections:
        moulds = set(np.asarray(ds["mould"].values)[np.asarray(selections["train"])].tolist())
        rows = [k for k, m in enumerate(np.asarray(ds["replicated"].values)) if int(m) in moulds]
        for name in ("replicated", "n_replicas_ok"):
            add(name, np.asarray(ds[name].values)[rows])
        add("fields_mean", ds["fields_mean"].isel(replicated=rows).values)
    return digest.hexdigest()


class SampleSource:
    """Model-ready samples: inputs (2, S, S) float32 (the masks, or the lattice channels:
    `inputs`, a TrainConfig.inputs kind) and scaled fields (8, S, S) float32 at the model
    resolution S. Holds them in memory when they fit in PRELOAD_BYTES, else reads one sample
    per access."""

    def __init__(self, ds, indices, scaling: FieldScaling | None, size: int | None = None,
                 preload: bool | None = None, replica_mean: bool = False,
                 inputs: str = "mask"):
        self.ds = ds
        self.inputs = inputs
        check_input_variables(ds, inputs)  # a missing variable, named before any reading
        # The target of a sample whose mould has replicas: its fields, or (replica_mean) the
        # mean of the mould's ok replicas (the store's fields_mean).
        self.mean_row = {}
        if replica_mean and "fields_mean" in ds:
            ok = np.asarray(ds["n_replicas_ok"].values) >= 2
            self.mean_row = {int(m): k for k, m in enumerate(ds["replicated"].values) if ok[k]}
        self.indices = np.asarray(indices, dtype=np.int64)
        self.scaling = scaling
        self.native = int(ds.sizes["x"])
        self.size = self.native if size is None else int(size)
        _factor(self.native, self.size)  # validate the ratio early
        n_bytes = len(self.indices) * 10 * self.size ** 2 * 4
        self.preload = n_bytes <= PRELOAD_BYTES if preload is None else preload
        self._cache = None
        self._native_inputs = None
        # N_c per sample (the lattice count), for the physics head; NaN when not stored
        self.n_cells = (np.asarray(ds["n_cells"].values, dtype=np.float64)[self.indices]
                        if "n_cells" in ds else np.full(len(self.indices), np.nan))
        if self.preload and len(self.indices):
            self._cache = self._read(self.indices)

    def __len__(self) -> int:
        return len(self.indices)

    def native_inputs(self) -> np.ndarray:
        """Every sample's model inputs (S, C, H, W) at the native resolution, read (and the
        stress channels solved) once: validation runs after every epoch."""
        if self._native_inputs is None:
            if self._cache is not None and self.size == self.native:  # preloaded as they are
                self._native_inputs = self._cache[0].numpy()
            else:
                self._native_inputs = model_inputs(self.ds, self.indices, self.inputs)
        return self._native_inputs

    def _read(self, positions: np.ndarray):
        raw_inputs, fields = read_samples(
            self.ds, positions, lambda sel: (_input_arrays(sel, self.inputs),
                                             np.asarray(sel["fields"].values, dtype=np.float32)))
        if self.mean_row:
            moulds = np.atleast_1d(np.asarray(self.ds["mould"].values)[positions])
            for row, mould in enumerate(moulds):
                if int(mould) in self.mean_row:
                    fields[row] = self.ds["fields_mean"].isel(
                        replicated=self.mean_row[int(mould)]).values
        bad = ~np.isfinite(fields).all(axis=tuple(range(1, fields.ndim)))
        if bad.any():
            raise DataError(f"sample(s) {_named(self.ds, positions[bad])} marked ok hold NaN or "
                            "inf fields (a lost chunk?): run condor check-store")
        inputs = resample_inputs(raw_inputs, self.size, self.inputs)
        if self.scaling is not None:
            fields = self.scaling.scale(resample_fields(fields, self.size)).astype(np.float32)
        return torch.from_numpy(np.ascontiguousarray(inputs)), torch.from_numpy(np.ascontiguousarray(fields))

    def batch(self, items) -> tuple[torch.Tensor, torch.Tensor]:
        """Items (positions into this source) -> (inputs (B,2,S,S), scaled fields (B,8,S,S))."""
        items = np.asarray(items, dtype=np.int64)
        if self._cache is not None:
            return self._cache[0][items], self._cache[1][items]
        parts = [self._read(self.indices[[i]]) for i in items]
        return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])

    def native_fields(self, items) -> np.ndarray:
        """Unscaled fields at the native resolution, (B, 8, H, W) float32."""
        return np.asarray(self.ds["fields"].isel(sample=self.indices[np.asarray(items)]).values,
                          dtype=np.float32)
