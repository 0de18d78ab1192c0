"""Placing a drawing in a scene: the placement rule (the drawing keeps its size, centred in
the box) and the fits that scale it (`FIT_MODES`), with the scale factor recorded
(`Placement`). docs/user_moulds.md states every rule; the module's constants are their one
home."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from shapely import affinity
from shapely.geometry import Polygon

from condor.model.scenes import PRESETS, Scene
from condor.moulds.domain import TRAINING_TETHER_RADIUS
from condor.moulds.mould import DrawingError, InvalidMouldError, Mould, check_mould
from condor.moulds.shapes import HOW_TO_DRAW_A_HOLE
from condor.moulds.units import length_text

FIT_MODES = ("area", "extent")  # --fit: the training moulds' area (capped by the window), or the window
# What was read is questioned (Placement.questions) for a post whose radius is more than
# LARGE_POST times the training posts' largest (TRAINING_TETHER_RADIUS, box sides), or one
# larger than every training post that holds the outline's centroid and is at least
# MIDDLE_POST of the outline's smaller side across: most often a hole drawn as a circle. A
# middle post of a training post's size is a post (a strip's middle post, a ring's centre).
LARGE_POST = 1.5
MIDDLE_POST = 0.4


@dataclass(frozen=True)
class Placement:
    """A drawing placed in a scene: the mould, and how it got there.

    scale: the factor the drawing was scaled by (1.0 when it keeps its size); fit: None,
    "area" or "extent"; drawn_l0: (width, height) of the drawing before scaling, l0;
    l0_um: the cell spacing used, if any (for lengths in mm)."""

    mould: Mould
    scale: float = 1.0
    fit: str | None = None
    drawn_l0: tuple[float, float] = (float("nan"), float("nan"))
    l0_um: float | None = None
    reading: str = "l0 (a mould file)"  # how the file's units were read

    def describe(self) -> str:
        """One line: what was read (outline, holes, posts with their radii), how the units were
        read, the drawn and placed size, the scale factor, and any question on a post."""
        questions = self.questions()
        return (f"read {self.contents()} in {self.reading}; {self._size_text()}"
                + (f"; check: {' '.join(questions)}" if questions else ""))

    def contents(self) -> str:
        """What was read: "1 outline, 1 hole, 4 posts (radius 0.25 mm)", radii at the drawn
        size (in l0, and mm given l0_um)."""
        holes = len(self.mould.polygon.interiors)
        radii = np.asarray(self.mould.tethers, dtype=float).reshape(-1, 3)[:, 2] / self.scale
        text = f"1 outline, {holes} hole{'s' * (holes != 1)}, {len(radii)} post{'s' * (len(radii) != 1)}"
        if len(radii):
            distinct = sorted({f"{r:.3g}": float(r) for r in radii}.values())
            shown = ", ".join(length_text(r, self.l0_um) for r in distinct[:4])
            more = f", ... ({len(distinct)} radii)" if len(distinct) > 4 else ""
            placed = ", ".join(f"{r * self.scale:.3g}" for r in distinct[:4])
            text += (f" (radius {shown}{more} drawn, {placed} l0 placed)" if self.fit else
                     f" (radius {shown}{more})")
        return text

    def questions(self) -> list[str]:
        """Sentences that question what was read: a post far larger than any training post,
        or one that holds the mould's middle, is most often a hole drawn as a circle."""
        mould = self.mould
        tethers = np.asarray(mould.tethers, dtype=float).reshape(-1, 3)
        largest = TRAINING_TETHER_RADIUS[1] * float(mould.box)
        xmin, ymin, xmax, ymax = mould.polygon.bounds
        centroid = mould.polygon.centroid
        asked = []
        for k, (x, y, r) in enumerate(tethers, start=1):
            why = []
            if r > LARGE_POST * largest:
                why.append(f"is {r / largest:.2g} times the largest training post's radius "
                           f"({TRAINING_TETHER_RADIUS[1]:g} of the box)")
            if math.hypot(centroid.x - x, centroid.y - y) < r and r > largest and \
                    2 * r >= MIDDLE_POST * min(xmax - xmin, ymax - ymin):
                why.append("holds the middle of the mould")
            if why:
                asked.append(f"post {k} (radius {length_text(r / self.scale, self.l0_um)}) "
                             f"{' and '.join(why)}: is it a hole? If so, {HOW_TO_DRAW_A_HOLE}.")
        return asked

    def _size_text(self) -> str:
        width, height = self.drawn_l0
        placed = f"{length_text(width * self.scale, self.l0_um)} x {length_text(height * self.scale, self.l0_um)}"
        if self.fit is None:
            return f"placed at its drawn size, {placed}"
        return (f"scaled by {self.scale:.4g} (--fit {self.fit}): drawn "
                f"{length_text(width, self.l0_um)} x {length_text(height, self.l0_um)}, placed {placed}")

    def record(self) -> dict:
        """JSON-safe attributes for an output's metadata."""
        return {"fit": self.fit or "none", "fit_scale": float(self.scale),
                "drawn_width_l0": float(self.drawn_l0[0]),
                "drawn_height_l0": float(self.drawn_l0[1]),
                "l0_um": None if self.l0_um is None else float(self.l0_um),
                "units_read": self.reading, "read": self.contents()}


def window_text(scene: Scene, l0_um: float | None) -> str:
    """The scene's window: its box, and the training moulds' largest extent, in l0 and mm."""
    at = f" at l0 = {l0_um:g} um" if l0_um is not None else ""
    return (f"the {scene.name!r} scene's window is {length_text(scene.box, l0_um)} square{at} "
            f"(training moulds span at most {length_text(scene.max_extent * scene.box, l0_um)})")


def fit_factor(polygon: Polygon, scene: Scene, fit: str) -> float:
    """The scale factor of a fit: "extent" makes the larger of width and height
    scene.max_extent of the box (the training moulds' largest); "area" makes the area
    scene.area_fraction of the box, capped by the extent fit so that it always fits."""
    xmin, ymin, xmax, ymax = polygon.bounds
    extent = scene.max_extent * float(scene.box) / max(xmax - xmin, ymax - ymin)
    if fit == "extent":
        return extent
    return min(math.sqrt(scene.area_fraction * float(scene.box) ** 2 / polygon.area), extent)


def fit_mode(fit) -> str | None:
    if fit is False or fit is None:
        return None
    if fit is True:
        return "area"
    if fit not in FIT_MODES:
        raise DrawingError(f"fit = {fit!r}: choose one of {FIT_MODES} (--fit area, --fit extent)")
    return fit


def place_mould(polygon: Polygon, tethers, scene: Scene, fit=False,
                l0_um: float | None = None, source: str = "mould") -> Mould:
    """A user mould in `scene`'s box from an outline and tethers in l0 (anywhere); see
    `place_drawing` (this returns its mould)."""
    return place_drawing(polygon, tethers, scene, fit=fit, l0_um=l0_um, source=source).mould


def place_drawing(polygon: Polygon, tethers, scene: Scene, fit=False, l0_um: float | None = None,
          source: str = "mould") -> Placement:
    """A user mould in `scene`'s box from an outline and tethers in l0 (anywhere).

    The placement rule: the drawing keeps its size (cells have size l0) and its bounding
    box is centred in the box, as the generator centres its moulds. `fit` scales it first,
    about that centre, keeping its aspect ratio: "extent" (the CLI's --fit extent) so that
    its larger side is scene.max_extent of the box; "area" or True (--fit) so that its
    area is scene.area_fraction of the box, the training moulds', but never beyond the
    extent fit. Without a fit it is refused (InvalidMouldError naming `source`, the
    window in l0 and mm, the scale it would need and the flags that give it) when its width
    or height exceeds the box; with one or without, when check_mould refuses the placed
    mould. `l0_um` only adds mm to the messages."""
    mode = fit_mode(fit)
    tethers = np.asarray(tethers, dtype=np.float64).reshape(-1, 3)
    box = float(scene.box)
    if not isinstance(polygon, Polygon) or polygon.is_empty or not polygon.area > 0:
        raise InvalidMouldError(f"{source}: the outline must be a Polygon with positive area, "
                                f"got {getattr(polygon, 'geom_type', type(polygon).__name__)}")
    xmin, ymin, xmax, ymax = polygon.bounds
    drawn = (xmax - xmin, ymax - ymin)
    factor = 1.0
    if mode is not None:
        factor = fit_factor(polygon, scene, mode)
        centre = bbox_centre(polygon)
        polygon = affinity.scale(polygon, factor, factor, origin=tuple(centre))
        tethers = np.column_stack([centre + (tethers[:, :2] - centre) * factor,
                                   tethers[:, 2] * factor])
    width, height = drawn[0] * factor, drawn[1] * factor
    if max(width, height) > box * (1 + 1e-9):
        raise InvalidMouldError(
            f"{source}: it is {length_text(width, l0_um)} wide and {length_text(height, l0_um)} high; "
            f"{window_text(scene, l0_um)}. {_way_forward(drawn, scene, l0_um)}")
    shift = np.array([box / 2, box / 2]) - bbox_centre(polygon)
    polygon = affinity.translate(polygon, *shift)
    tethers = np.column_stack([tethers[:, :2] + shift, tethers[:, 2]])
    mould = Mould(box=box, polygon=polygon, tethers=tethers)
    try:
        check_mould(mould)
    except InvalidMouldError as error:
        note = f" (l0 = {l0_um:g} um)" if l0_um is not None else ""
        scaled = f" (scaled by {factor:.4g}, --fit {mode})" if mode is not None else ""
        raise InvalidMouldError(f"{source}{note}{scaled}: {error}") from error
    return Placement(mould=mould, scale=float(factor), fit=mode,
                     drawn_l0=(float(drawn[0]), float(drawn[1])), l0_um=l0_um)


def _way_forward(drawn, scene: Scene, l0_um: float | None) -> str:
    """What to do about a drawing larger than the scene's window: the scale that --fit
    extent would apply, the cell spacing at which it would fit, and a larger scene."""
    side = max(drawn)
    scale = scene.max_extent * scene.box / side
    ways = [f"Way forward: --fit extent scales it by {scale:.4g} to {scene.max_extent:g} of "
            "the window (--fit: to the training moulds' area)"]
    if l0_um is not None:
        ways.append(f"or a cell spacing --l0-um {l0_um * side / (scene.max_extent * scene.box):.3g} "
                    "(or more) keeps its shape at fewer, larger cells")
    larger = [s for s in PRESETS.values() if s.box * scene.max_extent >= side and s.box > scene.box]
    if larger:
        best = min(larger, key=lambda s: s.box)
        ways.append(f"or the {best.name!r} scene (window {length_text(best.box, l0_um)}) holds it "
                    f"at its drawn size (condor simulate --scene {best.name}; predict and design "
                    "take their checkpoint's scene, so a checkpoint trained on it)")
    else:
        biggest = max(PRESETS.values(), key=lambda s: s.box)
        ways.append(f"no scene holds it at its drawn size (the largest window, the "
                    f"{biggest.name!r} scene's, is {length_text(biggest.box, l0_um)})")
    return "; ".join(ways)


def bbox_centre(polygon) -> np.ndarray:
    xmin, ymin, xmax, ymax = polygon.bounds
    return np.array([0.5 * (xmin + xmax), 0.5 * (ymin + ymax)])
