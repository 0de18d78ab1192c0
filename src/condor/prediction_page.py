"""The page `condor predict --out p.png` draws for a biologist (`prediction_panels`): the mould
and the predicted fields under plain names, each with a colour bar in its unit; after a check
(condor.stages.check), the best estimate in their place and the simulations' mean beside it. Drawn with condor.plots' matplotlib
setup."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from condor.data.fields import FIELD_NAMES
from condor.plots import pyplot, save
from condor.surrogate.answer import direction_is_clear


# The page's panels (prediction_panels): plain names; a ratio (per cell, per orientation) is
# drawn where the density is at least PAGE_TISSUE of its largest (blank elsewhere, where it is
# the ratio of two small numbers).
PAGE_TISSUE = 0.25


def page_fields(raw, spread, pixel_size: float | None, l0_um: float | None) -> list:
    """(title, image, colour-bar label, colour map, limits) of the page's fields: density, mean
    cell tension, alignment along x and at 45 degrees, out of plane, and one simulation's
    scatter of density and tension (when predicted)."""
    raw = np.asarray(raw, dtype=np.float64)
    p, t, sx2, sy2, sz2, sxsy = (raw[FIELD_NAMES.index(n)] for n in
                                 ("P", "T", "Sx2", "Sy2", "Sz2", "SxSy"))
    tissue = p >= PAGE_TISSUE * max(float(p.max()), 1e-12)
    area = 1.0 if pixel_size is None else pixel_size ** 2
    per = "pixel" if pixel_size is None else "l0²"
    density_unit = 1.0
    if pixel_size is not None and l0_um is not None:
        area, per = (pixel_size * l0_um / 1000.0) ** 2, "mm²"
    in_plane = np.where(tissue, sx2 + sy2, np.nan)

    def masked(values):
        return np.where(tissue, values, np.nan)

    with np.errstate(divide="ignore", invalid="ignore"):
        panels = [
            ("density", p / area * density_unit, f"cells per {per} (through the depth)",
             "viridis", None),
            ("tension", masked(t / p), "mean cell tension (model units; + stretched)",
             "magma", None),
            ("alignment along x", (sx2 - sy2) / in_plane, "+1 along x, -1 along y", "RdBu_r",
             (-1, 1)),
            ("alignment at 45°", 2 * sxsy / in_plane, "+1 at 45°, -1 at -45°", "RdBu_r",
             (-1, 1)),
            ("out of plane", masked(sz2 / p), "share along z (1/3: random)", "cividis", (0, 1)),
        ]
        if spread is not None:
            spread = np.asarray(spread, dtype=np.float64)
            sp, st = spread[FIELD_NAMES.index("P")], spread[FIELD_NAMES.index("T")]
            panels += [("density scatter", masked(sp / area * density_unit),
                        f"one simulation's sd, cells per {per}", "viridis", None),
                       ("tension scatter", masked(st / p),
                        "one simulation's sd, model units", "magma", None)]
    return panels


def short_verdict(verdict: str | None) -> list[str]:
    """The training-domain verdict in two short lines for the page (the whole of it is in the
    text output and the Zarr's attributes): its first sentence without the brackets, and what
    to do."""
    import re

    if not verdict:
        return []
    first = verdict.splitlines()[0].split(". ")[0]
    first = re.sub(r"\s*\([^()]*(\([^()]*\)[^()]*)*\)", "", first).strip()
    first = first.replace("the training domain ", "").replace("training domain ", "")
    if len(first) > 110:
        first = first[:107].rstrip() + "..."
    outside = "outside" in verdict.lower()
    return [f"training domain: {first}",
            ("simulate it to be sure (condor simulate, or predict --check N); " if outside else "")
            + "the whole verdict is in predict's text output and the .zarr"]


def prediction_panels(inputs, prediction, path, title: str = "", summary=None,
                      verdict: str | None = None, pixel_size: float | None = None, l0_um: float | None = None,
                      scale: float = 1.0, check=None, surrogate=None) -> Path:
    """A prediction (condor.surrogate.predict.Prediction) of one mould on one page for a
    biologist: the mould and the fields under plain names (density, tension, alignment along x
    and at 45 degrees, out of plane, and one simulation's scatter), each with a colour bar
    with its unit, axes in mm given `l0_um` (the drawing's mm: `scale` is the factor the
    drawing was placed at) else in l0 (`pixel_size`, l0 a pixel) else pixels; the title holds
    the whole-mould statistics (`summary`, condor.surrogate.answer.mould_summary) and the
    training-domain verdict in two short lines (`short_verdict`). After a `check`
    (condor.stages.check.Check; `prediction` then its best estimate, `surrogate` the network's
    own prediction), two more rows: the simulations' mean of the first five fields and the
    density's difference, surrogate - simulated. Every field, raw, normalised and its spread,
    is in the .zarr `condor predict` writes."""
    plt = pyplot()
    n = np.asarray(inputs).shape[-1]
    if pixel_size is not None and l0_um is not None:
        side, unit = n * pixel_size * l0_um / 1000.0 / scale, "mm"
    elif pixel_size is not None:
        side, unit = n * pixel_size, "l0"
    else:
        side, unit = float(n), "pixels"
    extent = (0.0, side, 0.0, side)
    panels = page_fields(prediction.raw, prediction.spread, pixel_size, l0_um)
    mould = np.where(np.asarray(inputs[1]) > 0, 2.0, np.where(np.asarray(inputs[0]) > 0, 1.0,
                                                                 np.nan))
    from matplotlib.colors import ListedColormap

    if check is not None and check.simulated is not None:
        own = (None if surrogate is None  # the surrogate's own density, when it is not drawn
               else page_fields(surrogate.raw, None, pixel_size, l0_um)[0][1])
        panels, simulated = check_panels(panels, check, pixel_size, l0_um, own)
    else:
        simulated = []
    items = [("mould and posts", mould, "grey: mould, red: posts",
              ListedColormap(["#bdbdbd", "#d62728"]), (0.5, 2.5))] + panels + simulated
    ncols = 4
    nrows = math.ceil(len(items) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.3 * ncols, 2.9 * nrows), squeeze=False,
                             layout="constrained")
    for ax, (name, image, label, cmap, limits) in zip(axes.flat, items):
        im = ax.imshow(image, origin="lower", cmap=cmap, extent=extent,
                       vmin=None if limits is None else limits[0],
                       vmax=None if limits is None else limits[1])
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(f"x ({unit})", fontsize=7)
        ax.set_ylabel(f"y ({unit})", fontsize=7)
        ax.tick_params(labelsize=6)
        bar = fig.colorbar(im, ax=ax, shrink=0.9)
        bar.ax.tick_params(labelsize=6)
        if name == "mould and posts":
            bar.set_ticks([1, 2])
            bar.set_ticklabels(["mould", "posts"])
        else:
            bar.set_label(label, fontsize=7)
    for ax in axes.flat[len(items):]:
        ax.axis("off")
    lines = [(title or f"predicted organisation, {float(prediction.n_cells):.0f} cells")
             + (f" (axes at the drawing's size; it was simulated at {scale:.3g}x)"
                if scale != 1.0 and unit == "mm" else "")]
    if summary is not None:
        lines.append(plain_statistics(summary))
    lines += short_verdict(verdict)
    if simulated:
        lines.append(f"checked by {check.n} simulations: the surrogate alone lies "
                     f"{check.ratio:.2f}x one simulation's scatter from their mean"
                     + (" (off on this mould)" if check.ratio > 1 else
                        " (may be off on this mould)" if check.flagged else "")
                     + ("; the fields above combine the two, "
                        f"{100 * check.weight:.0f}% the surrogate's "
                        f"({100 * check.tension_weight:.0f}% in tension)"
                        if check.best_normalised is not None else ""))
    fig.set_figheight(2.9 * nrows + 0.18 * len(lines))
    fig.suptitle("\n".join(lines), fontsize=9, x=0.01, ha="left")
    return save(fig, path, dpi=100)


def check_panels(predicted: list, check, pixel_size, l0_um,
                 surrogate_density=None) -> tuple[list, list]:
    """(the predicted panels, the simulated ones): the simulations' mean of the page's first
    five fields, each under the same colour scale as its predicted panel, and the density's
    difference surrogate - simulated (a symmetric scale; `surrogate_density` the surrogate's
    own density panel, by default the first predicted panel's)."""
    simulated = page_fields(check.simulated, None, pixel_size, l0_um)[:5]
    mine, theirs = list(predicted), []
    for k, (name, image, label, cmap, limits) in enumerate(simulated):
        if limits is None:
            both = np.concatenate([np.ravel(image), np.ravel(mine[k][1])])
            limits = (float(np.nanmin(both)), float(np.nanmax(both)))
            mine[k] = mine[k][:4] + (limits,)
        theirs.append((f"simulated {name}\n(mean of {check.n} simulations)", image, label,
                       cmap, limits))
    own = predicted[0][1] if surrogate_density is None else surrogate_density
    density = own - simulated[0][1]
    top = max(float(np.nanmax(np.abs(density))), 1e-12)
    theirs.append(("density, surrogate - simulated", density, predicted[0][2], "RdBu_r",
                   (-top, top)))
    return mine, theirs


def plain_statistics(summary) -> str:
    """The whole-mould statistics in one line of plain words (names as predict prints them)."""
    rows = {r.statistic: r for r in summary.itertuples()}

    def value(name, digits=3):
        row = rows.get(name)
        if row is None or not np.isfinite(row.value):
            return None
        spread = f" ± {row.spread:.2g}" if np.isfinite(row.spread) else ""
        return f"{row.value:.{digits}g}{spread}"

    parts = []
    if value("alignment"):
        parts.append(f"alignment {value('alignment')} (0: random, 1: all one way) " +
                     (f"at {value('direction', 2)}° from x" if direction_is_clear(summary)
                      else "in no clear direction"))
    if value("mean_tension"):
        parts.append(f"mean_tension {value('mean_tension')}")
    area = value("tissue_area_mm2") or value("tissue_area")
    if area:
        parts.append(f"tissue_area {area} {'mm²' if value('tissue_area_mm2') else 'l0²'}")
    return "whole mould: " + "; ".join(parts) + " (± one simulation's predicted spread)"
