"""Comparisons of fields as the paper reports them: per-field MAE, whole-mould statistics and
their Pearson r, next to the paper's values; and the density normalisation of predicted fields.

Replica-aware accuracy (errors against the expected fields, ceilings, intervals) is
`condor.measures.estimators`; this module holds the paper's own measures.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from condor.measures.estimators import pearson_r
from condor.data.fields import FIELD_NAMES, normalise
from condor.data.statistics import STATISTICS, mould_statistics

# The paper's Pearson r (Results): 0.881 for mean density, "above 0.98" for the others.
PAPER_R_MEAN_DENSITY = 0.881
PAPER_R_OTHERS_ABOVE = 0.98
# The fields whose best and worst test moulds the paper shows: what matters most for design.
BEST_WORST_FIELDS = ("Sx2", "T")


def paper_r(statistic: str) -> tuple[float, str]:
    """The paper's r for a statistic and how it is stated: (0.881, "=") or (0.98, ">")."""
    if statistic == "mean_P":
        return PAPER_R_MEAN_DENSITY, "="
    return PAPER_R_OTHERS_ABOVE, ">"


def density_sums(raw: np.ndarray) -> np.ndarray:
    """N_c as a prediction states it: the sum of its density P, (...,) for raw (..., 8, H, W)."""
    return np.asarray(raw)[..., 0, :, :].sum(axis=(-2, -1), dtype=np.float64)


def normalise_predicted(raw: np.ndarray) -> np.ndarray:
    """Paper eq. (normalisation) for predicted fields: raw * N_p / N_c with N_c the predicted
    density sum; a prediction whose P sums to <= 0 gives NaN fields (float32)."""
    raw = np.asarray(raw)
    n_cells = density_sums(raw)
    ok = np.isfinite(n_cells) & (n_cells > 0)
    out = np.full(raw.shape, np.nan, dtype=np.float32)
    if raw.ndim == 3:
        return normalise(raw, n_cells).astype(np.float32) if ok else out
    out[ok] = normalise(raw[ok], n_cells[ok])
    return out


def mae_frame(pred: np.ndarray, true: np.ndarray, sample_ids, field_names=FIELD_NAMES) -> pd.DataFrame:
    """MAE = mean over pixels |Z_C - Z_ML| per sample (rows) and field (columns), plus "mean"
    over fields. pred, true: (S, 8, H, W)."""
    if pred.shape != true.shape:
        raise ValueError(f"prediction shape {pred.shape} != truth shape {true.shape}")
    mae = np.abs(pred.astype(np.float64) - true).mean(axis=(2, 3))
    frame = pd.DataFrame(mae, columns=list(field_names), index=pd.Index(list(sample_ids), name="sample"))
    frame["mean"] = frame[list(field_names)].mean(axis=1)
    return frame


def best_worst(mae: pd.DataFrame, field: str, n: int = 6) -> tuple[list, list]:
    """Sample ids of the n lowest and n highest MAE for `field` (best first, worst first)."""
    ordered = mae[field].sort_values(kind="stable")
    return list(ordered.index[:n]), list(ordered.index[::-1][:n])


def statistics_frame(fields: np.ndarray, pixel_size: float, sample_ids=None, n_cells=None,
                     statistics_fn=None) -> pd.DataFrame:
    """`statistics_fn` (default condor.data.statistics.mould_statistics) per sample (rows). n_cells None:
    each sample's own density sum (as for predictions). A sample it rejects (P summing to
    <= 0) gets NaN."""
    paper = statistics_fn is None
    statistics_fn = mould_statistics if paper else statistics_fn
    rows = []
    for s, f in enumerate(fields):
        try:
            rows.append(statistics_fn(f, pixel_size, None if n_cells is None else float(n_cells[s])))
        except ValueError:
            rows.append({})
    index = pd.Index(list(range(len(fields)) if sample_ids is None else sample_ids), name="sample")
    columns = list(STATISTICS) if paper else None
    return pd.DataFrame(rows, index=index, columns=columns)


def correlation_table(sim: pd.DataFrame, pred: pd.DataFrame) -> pd.DataFrame:
    """Per statistic: Pearson r of simulated against predicted values (samples with NaN
    dropped), n, and the paper's value."""
    rows = []
    for name in sim.columns:
        ok = np.isfinite(sim[name].to_numpy(float)) & np.isfinite(pred[name].to_numpy(float))
        reference, relation = paper_r(name)
        rows.append({"statistic": name, "r": pearson_r(sim[name][ok], pred[name][ok]),
                     "n": int(ok.sum()), "paper_r": reference, "paper_relation": relation})
    return pd.DataFrame(rows).set_index("statistic")
