"""The physics the surrogate's output respects by construction, its spread head and loss.

`PhysicsHead` maps the generator's 16 unbounded output channels, and the mould's cell count
N_c, to the 8 fields and a per-pixel, per-field spread:

- P = N_c * softmax over the grid of channel 0: P >= 0 and sum(P) = N_c exactly (every cell
  is rasterised with unit weight and the moulds keep a margin from the box edge, so the
  simulated P sums to N_c within 1e-6);
- T = P * tau_0 * channel 1: a per-pixel mean tension per cell times the density (T -> 0
  where there are no cells); tau_0 (the training set's mean tension per cell) sets its scale;
- the orientation tensor S = [[Sx2, SxSy, SxSz], [SxSy, Sy2, SySz], [SxSz, SySz, Sz2]] =
  P * Q with Q = (L L^T + eps I) / trace, L lower-triangular from channels 2-7 (diagonal
  offset by 1 so that Q starts isotropic): Sx2 + Sy2 + Sz2 = P and S positive semidefinite,
  exactly, as for the simulated fields (a kernel-weighted sum of s s^T over unit vectors s);
- spread_f = s_f * (softplus(channel 8 + f) + floor): the standard deviation of one
  simulation's field f around the expected field, per pixel (s_f: the field's RMS).

Every expected field satisfies these relations (sums, traces, positivity are linear or convex
constraints that survive averaging over seeds), so they cost no accuracy. The loss is the
squared error of the mean, per field divided by s_f^2 (its minimiser is the conditional mean,
the expected field, unlike L1's median), plus the Gaussian negative log-likelihood of the
residual under the spread with the mean detached (so the spread never pulls the mean).

With sum_weight > 0 the loss adds, per mould, the Huber loss of the relative error of its
total tension: (sum T - sum T') / sqrt((|sum T| + f)(|sum T'| + f)), f = SUM_FLOOR x tau_0 x
N_c (T' the target). A mould's tension per cell spans 400x over the training moulds
(tau_0 x [0.01, 5]), so the pixel error alone weighs low-tension moulds by almost nothing and
shrinks their mean T towards the average (docs/surrogate.md "The mould's total tension").

field_weights (8,) weigh each field's squared error (normalised to mean 1; transpose pairs
equal, so the loss commutes with every symmetry). The default weighs the four fields of the
whole-mould statistics (P, T, Sx2, Sy2) above the off-diagonal ones, whose expected field is
near 0 and whose single-simulation target is mostly the seed's domains (docs/surrogate.md
"Weighing the fields, and the tissue's area").

With tension_floor f set, T's squared error is weighed per mould by ((1 + f) / (t + f))^2,
t = the target's tension per cell sum(T') / N_c in units of tau_0: the error relative to the
mould's own tension instead of the training set's. A mould's tension per cell spans 400x, so
the absolute error lets the network shrink every mould towards the average tension, which
over-predicts the many low-tension moulds and biases the median of predicted / simulated
mean T high (docs/surrogate.md "The mould's own tension").

With noise_weight g > 0 each mould's squared error of the mean is weighed by its predicted
noise (the field-weighted mean of (spread / s_f)^2, detached) to the power -g, over the batch's
mean and clipped to NOISE_WEIGHT_RANGE: at 1, each mould's error against its own scatter, as
the noise ceiling scores it (PhysicsHead.noise_weights).

With area_weight > 0 the loss adds, per mould, the relative error of its tissue area, counted
softly: sum of sigmoid((P - a) / (AREA_WIDTH a)) over the pixels for prediction and target
alike, a = the paper's N(P>0.2) threshold in cells per training pixel. The squared error of P
weighs an edge's pixels by their error, not by whether they cross the threshold, and the area
N(P>0.2) is what the statistic counts.

N_c of a mould is its lattice site count (`n_cells_of_mould`); for a bare input image,
`estimate_n_cells` counts the same FCC sites over the occupied pixels (docs/surrogate.md
gives its measured error).
"""

from __future__ import annotations

import numba
import numpy as np
import torch
from torch.nn import functional as F

from .samples import FIELD_NAMES, PAIRED_FIELDS
from .settings import PHYSICS_OUTPUTS, check_field_weights  # noqa: F401  (check_: re-exported)

N_OUTPUTS = PHYSICS_OUTPUTS  # 8 channels for the fields, 8 for their spread
SPREAD_FLOOR = 1e-3  # spread floor, in units of the field's RMS (keeps the NLL bounded)
TENSOR_EPS = 1e-4  # isotropic part of Q, keeps the trace positive
SUM_FLOOR = 0.05  # tension per cell, in units of tau_0, below which sum(T)'s error is absolute
SUM_HUBER = 0.1  # relative sum(T) error above which its loss grows linearly
NOISE_WEIGHT_RANGE = (0.1, 10.0)  # a mould's noise weight against the batch mean (noise_weight)
AREA_WIDTH = 0.125  # width of the soft area count's sigmoid, in units of the threshold
CALIBRATION_LEVEL = 0.9  # the interval whose coverage calibrate_spread matches
TISSUE_REACH_PX = 3  # pixels beyond the mould within which fields are non-zero (kernel reach)
_IDX = {f: i for i, f in enumerate(FIELD_NAMES)}


class PhysicsHead:
    """Output map and loss of a surrogate with built-in physics (see the module docstring).

    field_scale (8,): RMS of each field over the training split (pairs swapped by the
    transpose share one value, so the loss commutes with every symmetry); tension_scale:
    the training split's sum(T) / sum(P)."""

    kind = "physics"
    n_outputs = N_OUTPUTS

    def __init__(self, field_scale, tension_scale: float, nll_weight: float = 1.0,
                 spread_factor=None, sum_weight: float = 0.0, field_weights=None,
                 area_weight: float = 0.0, area_threshold: float | None = None,
                 tension_floor: float | None = None, noise_weight: float = 0.0):
        self.field_scale = np.asarray(field_scale, dtype=np.float64)
        self.field_weights = check_field_weights(
            np.ones(len(FIELD_NAMES)) if field_weights is None else field_weights)
        self.area_weight = float(area_weight)
        self.area_threshold = None if area_threshold is None else float(area_threshold)
        self.tension_scale = float(tension_scale)
        self.nll_weight = float(nll_weight)
        self.sum_weight = float(sum_weight)
        self.tension_floor = None if tension_floor is None else float(tension_floor)
        self.noise_weight = float(noise_weight)
        if not (np.isfinite(self.noise_weight) and self.noise_weight >= 0):
            raise ValueError(f"noise_weight must be finite and >= 0, got {noise_weight}")
        if self.tension_floor is not None and not (np.isfinite(self.tension_floor)
                                                   and self.tension_floor > 0):
            raise ValueError(f"tension_floor must be finite and > 0 (in units of tau_0), got "
                             f"{tension_floor}")
        # Per-field factor on the predicted spread, fitted on the validation split after
        # training (calibrate_spread): the training residuals are those of moulds the model
        # has seen, smaller than a new mould's.
        self.spread_factor = np.ones(len(FIELD_NAMES)) if spread_factor is None else \
            np.asarray(spread_factor, dtype=np.float64)
        if self.field_scale.shape != (len(FIELD_NAMES),) or np.any(self.field_scale <= 0):
            raise ValueError(f"field_scale must be {len(FIELD_NAMES)} positive values, got "
                             f"{self.field_scale}")
        if not (np.isfinite(self.sum_weight) and self.sum_weight >= 0):
            raise ValueError(f"sum_weight must be finite and >= 0, got {sum_weight}")
        if not (np.isfinite(self.area_weight) and self.area_weight >= 0):
            raise ValueError(f"area_weight must be finite and >= 0, got {area_weight}")
        if self.area_weight > 0 and not (self.area_threshold is not None
                                         and np.isfinite(self.area_threshold)
                                         and self.area_threshold > 0):
            raise ValueError(f"area_weight > 0 needs a positive area_threshold (cells per "
                             f"pixel), got {area_threshold}")
        if not (np.isfinite(self.tension_scale) and self.tension_scale != 0):
            raise ValueError(f"tension_scale must be finite and non-zero, got {tension_scale}")

    # the data pipeline hands targets through unchanged (physical units)
    def scale(self, fields):
        return fields

    def unscale(self, fields):
        return fields

    def _scale_tensor(self, like: torch.Tensor) -> torch.Tensor:
        return torch.as_tensor(self.field_scale, dtype=like.dtype, device=like.device)[None, :, None, None]

    def decode(self, out: torch.Tensor, n_cells: torch.Tensor,
               calibrated: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """out (B, 16, H, W), n_cells (B,) -> (fields (B, 8, H, W), spread (B, 8, H, W));
        `calibrated` applies spread_factor (the loss trains the uncalibrated spread)."""
        if out.shape[1] != N_OUTPUTS:
            raise ValueError(f"physics head needs {N_OUTPUTS} channels, got {out.shape[1]}")
        b, _, h, w = out.shape
        n_cells = torch.as_tensor(n_cells, dtype=out.dtype, device=out.device).reshape(b, 1, 1)
        density = n_cells * torch.softmax(out[:, 0].reshape(b, -1), dim=1).reshape(b, h, w)
        tension = density * self.tension_scale * out[:, 1]
        l11, l21, l22, l31, l32, l33 = (out[:, 2 + k] for k in range(6))
        l11, l22, l33 = l11 + 1, l22 + 1, l33 + 1
        qxx, qyy, qzz = l11 * l11, l21 * l21 + l22 * l22, l31 * l31 + l32 * l32 + l33 * l33
        qxy, qxz, qyz = l11 * l21, l11 * l31, l21 * l31 + l22 * l32
        weight = density / (qxx + qyy + qzz + 3 * TENSOR_EPS)
        fields = torch.stack([density, tension, weight * (qxx + TENSOR_EPS),
                              weight * (qyy + TENSOR_EPS), weight * (qzz + TENSOR_EPS),
                              weight * qxy, weight * qxz, weight * qyz], dim=1)
        spread = self._scale_tensor(out) * (F.softplus(out[:, 8:]) + SPREAD_FLOOR)
        if calibrated:
            spread = spread * torch.as_tensor(self.spread_factor, dtype=out.dtype,
                                              device=out.device)[None, :, None, None]
        return fields, spread

    def loss(self, out: torch.Tensor, target: torch.Tensor, n_cells) -> tuple[torch.Tensor, dict]:
        """Squared error of the mean / field_scale^2 x field_weights, plus nll_weight x the
        Gaussian NLL of the (detached) residual under the spread, both averaged over pixels and
        fields, plus sum_weight x the batch mean of the Huber loss of each mould's relative
        error in sum(T), plus area_weight x the batch mean of |relative error| of its soft
        tissue area."""
        fields, spread = self.decode(out, n_cells, calibrated=False)
        scale = self._scale_tensor(out)
        weights = torch.as_tensor(self.field_weights, dtype=out.dtype,
                                  device=out.device)[None, :, None, None]
        squared = weights * ((fields - target) / scale) ** 2
        if self.tension_floor is not None:
            t = _IDX["T"]
            squared = torch.cat([squared[:, :t], squared[:, t:t + 1] * self.tension_weights(
                target, n_cells)[:, None, None, None], squared[:, t + 1:]], dim=1)
        if self.noise_weight > 0:
            mse = (squared.mean(dim=(1, 2, 3)) * self.noise_weights(spread, scale, weights)).mean()
        else:
            mse = squared.mean()
        residual = (target - fields).detach()
        z = residual / spread
        nll = (0.5 * z * z + torch.log(spread / scale)).mean()
        loss = mse + self.nll_weight * nll
        parts = {"mse": mse.item(), "nll": nll.item()}
        if self.sum_weight > 0:
            t = _IDX["T"]
            floor = SUM_FLOOR * abs(self.tension_scale) * torch.as_tensor(
                n_cells, dtype=out.dtype, device=out.device).reshape(-1)
            true_sum = target[:, t].sum(dim=(1, 2))
            pred_sum = fields[:, t].sum(dim=(1, 2))
            # the error relative to the geometric mean of the two sums: its minimiser is the
            # median ratio of the target; relative to |true_sum| alone it would be shrunk low
            relative = (pred_sum - true_sum) / torch.sqrt((pred_sum.abs() + floor)
                                                          * (true_sum.abs() + floor))
            # Huber: a few moulds far off early in training must not outweigh the pixel error
            sum_error = F.huber_loss(relative, torch.zeros_like(relative), delta=SUM_HUBER)
            loss = loss + self.sum_weight * sum_error
            parts["sum_T"] = sum_error.item()
        if self.area_weight > 0:
            p = _IDX["P"]
            pred_area, true_area = self.soft_area(fields[:, p]), self.soft_area(target[:, p])
            area_error = ((pred_area - true_area).abs() / (true_area + 1)).mean()
            loss = loss + self.area_weight * area_error
            parts["area"] = area_error.item()
        return loss, parts

    def tension_weights(self, target: torch.Tensor, n_cells) -> torch.Tensor:
        """(B,) weights of each mould's T error, ((1 + f) / (|t| + f))^2 with t its target's
        tension per cell in units of tau_0 and f = tension_floor (1 at t = 1)."""
        n = torch.as_tensor(n_cells, dtype=target.dtype, device=target.device).reshape(-1)
        per_cell = target[:, _IDX["T"]].sum(dim=(1, 2)) / (n * self.tension_scale)
        f = self.tension_floor
        return ((1 + f) / (per_cell.abs() + f)) ** 2

    def noise_weights(self, spread: torch.Tensor, scale: torch.Tensor,
                      weights: torch.Tensor) -> torch.Tensor:
        """(B,) weights of each mould's squared error: its predicted noise (the field-weighted
        mean of (spread / field_scale)^2 over its pixels, detached) to the power -noise_weight,
        over the batch's mean, clipped to NOISE_WEIGHT_RANGE: with noise_weight 1 the loss
        weighs each mould's error against its own scatter, as the error / noise ceiling does."""
        with torch.no_grad():
            noise = (weights * (spread / scale) ** 2).mean(dim=(1, 2, 3)).clamp_min(1e-12)
            w = noise ** (-self.noise_weight)
            return (w / w.mean()).clamp(*NOISE_WEIGHT_RANGE)

    def soft_area(self, density: torch.Tensor) -> torch.Tensor:
        """(B, H, W) densities -> (B,) pixels above area_threshold, counted softly (a sigmoid
        AREA_WIDTH x the threshold wide): differentiable, and the hard count as it narrows."""
        a = self.area_threshold
        return torch.sigmoid((density - a) / (AREA_WIDTH * a)).sum(dim=(1, 2))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "field_scale": self.field_scale.tolist(),
                "tension_scale": self.tension_scale, "nll_weight": self.nll_weight,
                "spread_factor": self.spread_factor.tolist(), "sum_weight": self.sum_weight,
                "field_weights": self.field_weights.tolist(), "area_weight": self.area_weight,
                "area_threshold": self.area_threshold, "tension_floor": self.tension_floor,
                "noise_weight": self.noise_weight}

    @classmethod
    def from_dict(cls, d: dict) -> "PhysicsHead":
        return cls(d["field_scale"], d["tension_scale"], d.get("nll_weight", 1.0),
                   d.get("spread_factor"), d.get("sum_weight", 0.0), d.get("field_weights"),
                   d.get("area_weight", 0.0), d.get("area_threshold"), d.get("tension_floor"),
                   d.get("noise_weight", 0.0))

    def calibrate_spread(self, fields, spread, truth, mask, level: float = CALIBRATION_LEVEL):
        """Set spread_factor so that, per field, the central `level` interval fields -/+ z
        spread covers `level` of the single-simulation values `truth` over the `mask` pixels
        ((S, 8, H, W) arrays of held-out moulds, spread as predicted with the current factor;
        mask (S, H, W) bool). Returns the new factor."""
        from .calibration import z_of

        z = np.abs(np.asarray(truth, np.float64) - fields) / np.asarray(spread, np.float64)
        z = np.moveaxis(z, 1, 0)[:, np.asarray(mask, bool)]  # (8, pixels)
        factor = np.quantile(z, level, axis=1) / z_of(level)
        for a, b in PAIRED_FIELDS:  # one factor per pair, so that it commutes with symmetries
            pair = [_IDX[a], _IDX[b]]
            factor[pair] = np.quantile(z[pair].ravel(), level) / z_of(level)
        self.spread_factor = self.spread_factor * np.where(np.isfinite(factor) & (factor > 0),
                                                           factor, 1.0)
        return self.spread_factor


def area_threshold_per_pixel(pixel_size: float) -> float:
    """The paper's N(P>0.2) threshold (statistics.DENSITY_THRESHOLD cells per paper pixel) in
    cells per pixel of side `pixel_size` (l0), as statistics.mould_statistics applies it."""
    from condor.data.statistics import DENSITY_THRESHOLD, PAPER_PIXEL_SIZE
    return DENSITY_THRESHOLD * (float(pixel_size) / PAPER_PIXEL_SIZE) ** 2


def fit_physics_head(ds, indices, chunk: int = 32, nll_weight: float = 1.0,
                     sum_weight: float = 0.0, field_weights=None, area_weight: float = 0.0,
                     pixel_size: float | None = None,
                     tension_floor: float | None = None,
                     noise_weight: float = 0.0) -> PhysicsHead:
    """PhysicsHead scales from the samples `indices` (the training split): each field's RMS
    over all pixels (transpose pairs averaged) and sum(T) / sum(P). pixel_size (l0, of the
    training grid) sets the area threshold (needed with area_weight > 0)."""
    indices = np.asarray(indices)
    if len(indices) == 0:
        raise ValueError("cannot fit a physics head on zero samples")
    sq = np.zeros(len(FIELD_NAMES))
    sums = np.zeros(len(FIELD_NAMES))
    n = 0
    for start in range(0, len(indices), chunk):
        f = np.asarray(ds["fields"].isel(sample=indices[start:start + chunk]).values, dtype=np.float64)
        sq += (f * f).sum(axis=(0, 2, 3))
        sums += f.sum(axis=(0, 2, 3))
        n += f.shape[0] * f.shape[2] * f.shape[3]
    rms = np.sqrt(sq / n)
    for a, b in PAIRED_FIELDS:
        rms[[_IDX[a], _IDX[b]]] = 0.5 * (rms[_IDX[a]] + rms[_IDX[b]])
    rms = np.where(rms > 0, rms, 1.0)
    tension = sums[_IDX["T"]] / sums[_IDX["P"]]
    return PhysicsHead(rms, tension if tension != 0 else 1.0, nll_weight, sum_weight=sum_weight,
                       field_weights=field_weights, area_weight=area_weight,
                       area_threshold=None if pixel_size is None
                       else area_threshold_per_pixel(pixel_size), tension_floor=tension_floor,
                       noise_weight=noise_weight)


# --- the cell count N_c -----------------------------------------------------------------------

def n_cells_of_mould(polygon, tethers, depth: float) -> int:
    """N_c of a mould: its lattice site count (condor.model.lattice.build_lattice), exactly the
    number of cells the simulation rasterises."""
    from condor.model.lattice import build_lattice

    return int(build_lattice(polygon, tethers, depth).n_cells)


def estimate_n_cells(inputs: np.ndarray, pixel_size: float, depth: float) -> np.ndarray | float:
    """N_c estimated from input channels (2, H, W) or (S, 2, H, W) (mould, tether; 0/1): the
    FCC sites of condor.model.lattice.build_lattice (origin at the centre of the occupied pixels'
    bounding box) whose (x, y) falls in an occupied pixel (condor.data.inputs.mask_sites). Exact up
    to the pixelation of the outline (measured error in docs/surrogate.md); prefer
    n_cells_of_mould when the geometry is known."""
    from condor.data.inputs import mask_sites

    inputs = np.asarray(inputs)
    single = inputs.ndim == 3
    batch = inputs[None] if single else inputs
    if batch.ndim != 4 or batch.shape[1] != 2:
        raise ValueError(f"inputs must be (2, H, W) or (S, 2, H, W), got shape {inputs.shape}")
    if not (np.isfinite(pixel_size) and pixel_size > 0 and np.isfinite(depth) and depth > 0):
        raise ValueError(f"pixel_size ({pixel_size}) and depth ({depth}) must be positive")
    out = np.array([mask_sites(channels, pixel_size, depth)[1].sum() for channels in batch])
    return float(out[0]) if single else out


def tissue_mask(inputs: torch.Tensor, reach: int = TISSUE_REACH_PX) -> torch.Tensor:
    """(B, 2, H, W) 0/1 inputs -> (B, 1, H, W) float: the mould and tethers dilated by
    `reach` pixels (where the fields are non-zero)."""
    occupied = inputs.amax(dim=1, keepdim=True)
    return F.max_pool2d(occupied, 2 * reach + 1, stride=1, padding=reach)


# --- the symmetrised sum (condor.surrogate.symmetrise.symmetrised) ------------------------------

@numba.njit(cache=True)
def symmetrised_sum_kernel(fields, spread, pixel_source, field_source, weight, variance_weight,
                           mean, variance):
    """The symmetrisation's sums over the planar transforms, each output moved back as it is
    read. fields, spread (K, M, 8, H*W) float32: decode's fields and spreads of transform k's
    output of mould m, pixels row-major; pixel_source (K, H*W): the pixel of transform k's
    output that apply_symmetry(k, inverse=True) moves onto each pixel; field_source, weight,
    variance_weight (K, 8): symmetrise._FIELD_MAPS. Adds into mean and variance (M, 8, H*W)
    float64: over k, weight[k, f] x field field_source[k, f] moved back, and variance_weight
    x its spread squared."""
    k_count, m_count, _, n_pixels = fields.shape
    for m in range(m_count):
        for k in range(k_count):
            source = pixel_source[k]
            for f in range(mean.shape[1]):
                g = field_source[k, f]
                w, v = weight[k, f], variance_weight[k, f]
                values, spreads = fields[k, m, g], spread[k, m, g]
                for p in range(n_pixels):
                    q = source[p]
                    mean[m, f, p] += w * values[q]
                    variance[m, f, p] += v * (float(spreads[q]) * float(spreads[q]))
