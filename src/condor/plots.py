"""Every figure condor draws, with one matplotlib setup (the page `condor predict` draws is
condor.prediction_page, on this setup).

Computing modules return arrays and tables; the stages call these functions to draw them.
matplotlib is imported on first use (it costs a second of start-up that most commands do not
need) and always with the file-only Agg backend (no display on workers).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from condor.data.fields import FIELD_NAMES
from condor.files import atomic_path
from condor.measures.bars import SAME_STATES
from condor.measures.metrics import BEST_WORST_FIELDS, best_worst

_PLT = None


def pyplot():
    """matplotlib.pyplot with the Agg backend."""
    global _PLT
    if _PLT is None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        _PLT = plt
    return _PLT


def save(fig, path, dpi: int = 110) -> Path:
    """Write `fig` to `path` (folders made; whole or not at all: condor.files) and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
    finally:
        pyplot().close(fig)
    return path


# --- moulds -----------------------------------------------------------------------------------

def draw_mould(ax, mould, title: bool = True, edge: bool = True) -> None:
    """The footprint (filled, holes open) and tethers of a condor.moulds.mould.Mould on an Axes;
    `edge`: a darker line on the outline (none where the picture is read back: a line drawn
    on the edge would widen the mould by half its width)."""
    from matplotlib.patches import Circle, PathPatch
    from matplotlib.path import Path as MplPath

    rings = [mould.polygon.exterior, *mould.polygon.interiors]
    vertices, codes = [], []
    for ring in rings:
        xy = np.asarray(ring.coords)
        vertices.append(xy)
        codes.append([MplPath.MOVETO] + [MplPath.LINETO] * (len(xy) - 2) + [MplPath.CLOSEPOLY])
    path = MplPath(np.concatenate(vertices), np.concatenate(codes))
    ax.add_patch(PathPatch(path, facecolor="#9ecae1", edgecolor="#08519c" if edge else "none",
                           lw=0.8 if edge else 0.0))
    for x, y, r in np.asarray(mould.tethers).reshape(-1, 3):
        ax.add_patch(Circle((x, y), r, facecolor="#d62728", edgecolor="none"))
    ax.set_xlim(0, mould.box)
    ax.set_ylim(0, mould.box)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    if title:
        ax.set_title(f"{mould.symmetry}, {mould.order}, {mould.removal}" if mould.is_generated
                     else f"{mould.family} ({mould.n_tethers} posts)", fontsize=7)


def mould_gallery(moulds, path, ncols: int = 6, dpi: int = 100) -> Path:
    """A PNG grid of moulds."""
    moulds = list(moulds)
    if not moulds:
        raise ValueError("moulds is empty: nothing to draw")
    plt = pyplot()
    ncols = max(1, min(ncols, len(moulds)))
    nrows = math.ceil(len(moulds) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(2.2 * ncols, 2.3 * nrows), squeeze=False)
    for ax in axes.flat[len(moulds):]:
        ax.axis("off")
    for ax, mould in zip(axes.flat, moulds):
        draw_mould(ax, mould)
    fig.tight_layout()
    return save(fig, path, dpi=dpi)


def mould_picture(mould, path) -> Path:
    """One mould, drawn alone; a .png states in its text where the box is drawn
    (condor.moulds.read_picture.picture_metadata), so that condor reads it back at its scale."""
    from condor.moulds.read_picture import picture_metadata

    dpi = 120
    fig, ax = pyplot().subplots(figsize=(4, 4), dpi=dpi)
    draw_mould(ax, mould, edge=False)
    fig.tight_layout()
    fig.canvas.draw()
    (left, bottom), (right, top) = ax.transData.transform([(0.0, 0.0), (mould.box, mould.box)])
    height = fig.get_figheight() * dpi
    metadata = picture_metadata(mould.box, (left, height - top, right, height - bottom)) \
        if Path(path).suffix.lower() == ".png" else None
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, metadata=metadata)
    pyplot().close(fig)
    return path


# --- fields -----------------------------------------------------------------------------------

def image_grid(rows, path, title: str = "", dpi: int = 100, cmaps=None) -> Path:
    """Rows of labelled images: `rows` = [(row label, [(title, image (H, W)), ...]), ...], each
    image with its colour bar, y up. `cmaps` maps a title to a colour map (default viridis)."""
    rows = list(rows)
    if not rows:
        raise ValueError("no rows to draw")
    plt = pyplot()
    ncols = max(len(images) for _, images in rows)
    fig, axes = plt.subplots(len(rows), ncols, figsize=(1.65 * ncols, 1.75 * len(rows) + 0.4),
                             squeeze=False)
    for ax_row, (label, images) in zip(axes, rows):
        for k, (ax, (name, image)) in enumerate(zip(ax_row, images)):
            im = ax.imshow(image, origin="lower", cmap=(cmaps or {}).get(name, "viridis"))
            ax.set_title(f"{label}: {name}" if k == 0 and label else name, fontsize=7)
            fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02).ax.tick_params(labelsize=5)
        for ax in ax_row[len(images):]:
            ax.axis("off")
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return save(fig, path, dpi=dpi)


def field_panels(rows, path, title: str = "", field_names=FIELD_NAMES, dpi: int = 100) -> Path:
    """One row per entry of `rows` = (label, inputs (2, H, W) or None, fields (F, H, W)):
    the mould (grey: mould, black: tethers) and each field."""
    grid = []
    for label, inputs, fields in rows:
        images = [] if inputs is None else [("mould", inputs[0] + 2 * inputs[1])]
        grid.append((label, images + list(zip(field_names, fields))))
    return image_grid(grid, path, title, dpi, cmaps={"mould": "Greys"})


# --- studies ------------------------------------------------------------------------------------

# The paper's reported costs: 24-36 core-hours per CONDOR simulation, ~0.1 s per prediction.
PAPER_SIMULATION_SECONDS = (24 * 3600.0, 36 * 3600.0)
PAPER_PREDICTION_SECONDS = 0.1
FAMILY_COLOURS = {"long anneal": "black", "anneal": "tab:red", "minimise": "tab:blue",
                  "hybrid": "tab:green", "dataset solver": "tab:olive",
                  "surrogate": "tab:orange", "baseline": "tab:brown"}


def _label_points(ax, points, fontsize: float = 7, bars=None) -> None:
    """Annotate (x, y, label) points, each label at the first of a few offsets around its
    point where its drawn box overlaps no label already placed, no marker and no error bar
    (`bars`: (x, y_lo, y_hi) per point, data units) and stays inside the axes; where none is
    clear, at the offset with the fewest clashes (a cluster of methods at similar cost and
    error stays readable). Call after the limits and the layout are final."""
    from matplotlib.transforms import Bbox

    renderer = ax.figure.canvas.get_renderer()
    inside = ax.get_window_extent(renderer)
    offsets = ((4, 3, "left"), (4, -10, "left"), (-4, 3, "right"), (-4, -10, "right"),
               (4, 12, "left"), (4, -19, "left"), (-4, 12, "right"), (-4, -19, "right"),
               (4, 21, "left"), (4, -28, "left"), (-4, 21, "right"), (-4, -28, "right"),
               (4, 30, "left"), (4, -37, "left"), (-4, 30, "right"), (-4, -37, "right"),
               (4, 39, "left"), (4, -46, "left"), (-4, 39, "right"), (-4, -46, "right"))
    # markers (~6 pt) and error bars (a few px wide), in display units
    obstacles = [Bbox.from_extents(*(ax.transData.transform((x, y)) - 4),
                                   *(ax.transData.transform((x, y)) + 4)) for x, y, _ in points]
    for x, lo, hi in bars or ():
        (x0, y0), (_, y1) = ax.transData.transform([(x, lo), (x, hi)])
        obstacles.append(Bbox.from_extents(x0 - 2, y0, x0 + 2, y1))

    def clashes(box) -> int:
        outside = not (inside.contains(box.x0, box.y0) and inside.contains(box.x1, box.y1))
        return int(outside) + sum(box.overlaps(other) for other in placed + obstacles)

    placed = []
    for x, y, label in sorted(points, key=lambda p: (p[0], p[1])):
        tried = []  # (clashes, offset index, box) of each offset tried
        for k, (dx, dy, ha) in enumerate(offsets):
            text = ax.annotate(label, (x, y), fontsize=fontsize, xytext=(dx, dy), ha=ha,
                               textcoords="offset points")
            box = text.get_window_extent(renderer)
            text.remove()
            tried.append((clashes(box), k, box))
            if tried[-1][0] == 0:
                break
        _, k, box = min(tried, key=lambda t: t[:2])  # clear, else the least crowded offset
        dx, dy, ha = offsets[k]
        # set further off, a leader line says which point a label names
        leader = dict(arrowstyle="-", lw=0.5, color="0.45", shrinkA=0, shrinkB=4) \
            if k >= 4 else None
        ax.annotate(label, (x, y), fontsize=fontsize, xytext=(dx, dy), ha=ha,
                    textcoords="offset points", arrowprops=leader)
        placed.append(box)


def accuracy_chart(table, path, title: str = "") -> Path:
    """Field error against the expected fields (noise removed; bars: 95% bootstrap interval
    over moulds) against CPU seconds per mould (log x), one point per method. The row "single
    simulation" is also drawn as the ceiling line (band: its interval); shaded, the paper's
    cost per simulation; dashed, its cost per prediction."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9.5, 5.4))
    ceiling = table[table["method"] == "single simulation"]
    if len(ceiling):
        c = ceiling.iloc[0]
        ax.axhline(c["field_error"], color="tab:olive", lw=1.2, ls="-", zorder=0)
        ax.axhspan(c["field_error_lo"], c["field_error_hi"], color="tab:olive", alpha=0.15,
                   zorder=0)
        ax.annotate("one simulation (the noise ceiling)", (0.01, c["field_error"]),
                    xycoords=("axes fraction", "data"), xytext=(0, 3), textcoords="offset points",
                    fontsize=7, color="tab:olive")
    for row in table.itertuples():
        x = max(float(row.cpu_s_per_mould), 1e-5)
        err = [[max(row.field_error - row.field_error_lo, 0)],
               [max(row.field_error_hi - row.field_error, 0)]]
        ax.errorbar(x, row.field_error, yerr=err, fmt="o", ms=6, elinewidth=1, capsize=2,
                    color=FAMILY_COLOURS.get(row.family, "grey"))
    ax.axvspan(*PAPER_SIMULATION_SECONDS, color="tab:red", alpha=0.10)
    ax.axvline(PAPER_PREDICTION_SECONDS, color="tab:orange", ls="--", lw=1)
    ax.set_xscale("log")
    lo = min(float(table["cpu_s_per_mould"].clip(lower=1e-5).min()), PAPER_PREDICTION_SECONDS)
    ax.set_xlim(lo / 3, PAPER_SIMULATION_SECONDS[1] * 3)
    ax.set_ylim(bottom=0)
    top = ax.get_ylim()[1]
    ax.text(PAPER_SIMULATION_SECONDS[0] / 1.15, 0.97 * top,  # left of the band: in the axes
            "paper: 24-36 core-h\nper simulation", ha="right", va="top", fontsize=7,
            color="tab:red")
    ax.text(PAPER_PREDICTION_SECONDS * 1.15, 0.97 * top, "paper: ~0.1 s\nper prediction",
            va="top", fontsize=7, color="tab:orange")
    ax.set_xlabel("cost per mould, CPU seconds (one core)")
    ax.set_ylabel("field error vs the expected fields\n(RMS of normalised fields, noise removed)")
    handles = [plt.Line2D([], [], color=c, marker="o", ls="", label=f)
               for f, c in FAMILY_COLOURS.items() if f in set(table["family"])]
    ax.legend(handles=handles, fontsize=8, loc="center right")
    ax.grid(alpha=0.3, which="both", lw=0.4)
    ax.set_title(title or "cost per mould against error, every method, same test moulds",
                 fontsize=9)
    fig.tight_layout()
    _label_points(ax, [(max(float(r.cpu_s_per_mould), 1e-5), float(r.field_error), r.method)
                       for r in table.itertuples()],
                  bars=[(max(float(r.cpu_s_per_mould), 1e-5), float(r.field_error_lo),
                         float(r.field_error_hi)) for r in table.itertuples()])
    return save(fig, path, dpi=120)


# The curves' x axes: training moulds, parameters, epochs (experiments/surrogate/curves.py).
CURVE_AXES = {"data": ("n_train", "training moulds", True),
              "size": ("parameters", "parameters", True),
              "epochs": ("epochs", "epochs", False)}


def learning_curves(curves, path) -> Path:
    """The surrogate's field error against the expected fields (bars: 95% interval over test
    moulds) against training moulds, model size and epochs, one panel per curve in `curves`
    (name -> DataFrame with the x column of CURVE_AXES, field_rms, field_rms_lo, field_rms_hi,
    ceiling_rms); the single-simulation ceiling dashed."""
    plt = pyplot()
    names = [n for n in CURVE_AXES if n in curves]
    if not names:
        raise ValueError(f"no learning curve among {sorted(curves)}; expected {list(CURVE_AXES)}")
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.6), squeeze=False)
    for ax, name in zip(axes[0], names):
        df = curves[name].sort_values(CURVE_AXES[name][0])
        x_col, label, log_x = CURVE_AXES[name]
        err = [(df["field_rms"] - df["field_rms_lo"]).clip(lower=0),
               (df["field_rms_hi"] - df["field_rms"]).clip(lower=0)]
        ax.errorbar(df[x_col], df["field_rms"], yerr=err, fmt="o-", ms=5, capsize=2,
                    color="tab:blue", label="surrogate")
        ax.axhline(float(df["ceiling_rms"].iloc[0]), color="tab:olive", ls="--", lw=1.2,
                   label="one simulation (ceiling)")
        if log_x:
            ax.set_xscale("log")
            ax.minorticks_off()
        ax.set_xticks(df[x_col], [f"{v:,.0f}" for v in df[x_col]], fontsize=7)
        ax.set_ylim(bottom=0)
        ax.set_xlabel(label)
        ax.set_ylabel("field error vs expected fields")
        ax.grid(alpha=0.3, which="both", lw=0.4)
        ax.set_title(f"against {label}", fontsize=9)
    axes[0][0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return save(fig, path, dpi=110)


def convergence_chart(df, path) -> Path:
    """Systematic field change per channel (noise removed) against depth and box size; dashed:
    half the scatter of one simulation (a change below it is justified)."""
    plt = pyplot()
    studies = list(dict.fromkeys(df["study"]))
    fig, axes = plt.subplots(1, len(studies), figsize=(5.2 * len(studies), 3.8), squeeze=False)
    channels = ["P", "T", "Sx2", "Sy2", "Sz2"]
    for ax, study in zip(axes[0], studies):
        d = df[df["study"] == study]
        for k, ch in enumerate(channels):
            med = d.groupby("value")[f"change_{ch}"].median()
            line, = ax.plot(med.index, med.values, marker="o", label=ch, color=f"C{k}")
            ax.axhline(SAME_STATES * d[f"noise_{ch}"].median(), color=line.get_color(), ls="--", lw=0.8)
        ax.set_xlabel("depth, l0" if study == "depth" else "box side, l0")
        ax.set_ylabel("systematic change vs the reference configuration\n(relative RMS, noise removed)")
        ax.set_title(f"{study} (dashed: half one simulation's scatter)", fontsize=9)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return save(fig, path, dpi=120)


# --- design --------------------------------------------------------------------------------------

def design_confirmation(table, summary, path, title: str = "") -> Path:
    """Predicted against simulated objective of the confirmed designs (`confirmation_table`):
    top and random designs apart, the replica spread as error bars, the identity line and, when
    the summary has one, the best baseline mould's simulated objective."""
    plt = pyplot()
    row = summary.iloc[0]
    fig, ax = plt.subplots(figsize=(4.6, 4.2))
    for role, marker, colour in (("random", "o", "#6baed6"), ("top", "*", "#d62728")):
        part = table[table["role"] == role]
        if len(part):
            ax.errorbar(part["predicted_objective"], part["simulated_objective"],
                        yerr=part.get("simulated_objective_std"), fmt=marker, color=colour,
                        ms=9 if marker == "*" else 5, capsize=2, label=f"{role} ({len(part)})")
    values = np.concatenate([table["predicted_objective"], table["simulated_objective"]])
    values = values[np.isfinite(values)]
    if values.size:
        low, high = values.min(), values.max()
        pad = 0.05 * (high - low or 1.0)
        ax.plot([low - pad, high + pad], [low - pad, high + pad], color="grey", lw=0.8, ls="--")
    if "best_baseline" in row and np.isfinite(row["best_baseline"]):
        ax.axhline(row["best_baseline"], color="#31a354", lw=1,
                   label=f"best baseline mould ({row['best_baseline']:.3g})")
    ax.set_xlabel("predicted objective (surrogate)")
    ax.set_ylabel("simulated objective (replica mean)")
    rho = f"Spearman {row['spearman']:.2f} [{row['spearman_low']:.2f}, {row['spearman_high']:.2f}]"
    ax.set_title(f"{title}\n{rho}, bias {row['bias']:+.3f}" if title else rho, fontsize=9)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    return save(fig, path)


def design_search_history(history, path) -> Path:
    """Best score so far and each generation's median against designs evaluated."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(4.6, 3.2))
    ax.plot(history["evaluations"], history["best_score"], label="best so far")
    ax.plot(history["evaluations"], history["generation_median"], lw=0.8,
            label="generation median")
    ax.set_xlabel("designs evaluated")
    ax.set_ylabel("score (predicted)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save(fig, path)


# --- surrogate evaluation ------------------------------------------------------------------------

def plot_mae_distribution(mae, path, title: str = ""):
    """Histogram of per-sample MAE, one panel per field."""
    plt = pyplot()
    fields = [c for c in mae.columns if c != "mean"]
    fig, axes = plt.subplots(2, (len(fields) + 1) // 2, figsize=(12, 5))
    for ax, name in zip(axes.flat, fields):
        ax.hist(mae[name], bins=min(20, max(5, len(mae) // 3)), color="tab:blue")
        ax.set_title(f"{name}: median {mae[name].median():.3g}", fontsize=9)
        ax.set_xlabel("MAE")
    fig.suptitle(title or "per-sample MAE (test split)")
    fig.tight_layout()
    save(fig, path, dpi=100)


def plot_best_worst(mae, true: np.ndarray, pred: np.ndarray, field: str, path,
                    which: str = "best", n: int = 6):
    """Rows: the n best (or worst) samples by MAE of `field`; columns: simulation,
    prediction, difference (prediction - simulation). true/pred rows follow mae's index."""
    plt = pyplot()
    best, worst = best_worst(mae, field, n)
    ids = best if which == "best" else worst
    k = FIELD_NAMES.index(field)
    position = {sid: i for i, sid in enumerate(mae.index)}
    fig, axes = plt.subplots(len(ids), 3, figsize=(7.5, 2.3 * len(ids)), squeeze=False)
    for row, sid in zip(axes, ids):
        sim, prd = true[position[sid], k], pred[position[sid], k]
        lo, hi = min(sim.min(), prd.min()), max(sim.max(), prd.max())
        diff = prd - sim
        span = np.abs(diff).max() or 1.0
        for ax, image, label, kw in ((row[0], sim, "simulation", {"vmin": lo, "vmax": hi}),
                                     (row[1], prd, "prediction", {"vmin": lo, "vmax": hi}),
                                     (row[2], diff, "difference", {"vmin": -span, "vmax": span,
                                                                   "cmap": "RdBu_r"})):
            im = ax.imshow(image, origin="lower", **kw)
            ax.set_xticks([]), ax.set_yticks([])
            ax.set_title(f"{sid}: {label}" + (f" (MAE {mae.loc[sid, field]:.3g})"
                                               if label == "difference" else ""), fontsize=8)
            fig.colorbar(im, ax=ax, fraction=0.046)
    fig.suptitle(f"{field}: {n} {which} test samples by MAE")
    fig.tight_layout()
    save(fig, path, dpi=90)


def plot_statistics_scatter(ev, path):
    """Simulated vs predicted whole-mould statistics, with r and a dashed y = x."""
    plt = pyplot()
    names = list(ev.sim_statistics.columns)
    fig, axes = plt.subplots(2, (len(names) + 1) // 2, figsize=(3 * ((len(names) + 1) // 2), 6))
    for ax, name in zip(axes.flat, names):
        x, y = ev.sim_statistics[name], ev.pred_statistics[name]
        ax.scatter(x, y, s=10)
        lo, hi = np.nanmin([x.min(), y.min()]), np.nanmax([x.max(), y.max()])
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
        ax.set_title(f"{name}: r = {ev.correlations.loc[name, 'r']:.3f}", fontsize=9)
        ax.set_xlabel("simulation", fontsize=8)
        ax.set_ylabel("prediction", fontsize=8)
    fig.suptitle(f"whole-mould statistics, {ev.method}")
    fig.tight_layout()
    save(fig, path, dpi=100)


def evaluation_figures(ev, true: np.ndarray, pred: np.ndarray, out_dir) -> list[Path]:
    """The paper's evaluation figures of one method (a condor.surrogate.evaluate.Evaluation):
    MAE distribution, statistics scatter, and the best / worst moulds for Sx2 and T."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{ev.method}_mae_distribution.png", out / f"{ev.method}_statistics.png"]
    plot_mae_distribution(ev.mae, paths[0], f"per-sample MAE, {ev.method}")
    plot_statistics_scatter(ev, paths[1])
    for field in BEST_WORST_FIELDS:
        for which in ("best", "worst"):
            paths.append(out / f"{ev.method}_{field}_{which}.png")
            plot_best_worst(ev.mae, true, pred, field, paths[-1], which)
    return paths
