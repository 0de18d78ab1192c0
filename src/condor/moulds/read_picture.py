"""A picture of a mould (PNG, TIFF, JPEG; a photo or a clean drawing, any resolution) read as
an outline, its holes and its round posts, with scikit-image (thresholds, labelled regions,
sub-pixel contours, circle fits): `read_picture` returns a `Drawing`, which is then placed
like any drawing (condor.moulds.place), so that the exact-lattice path serves it.

The rules (docs/user_moulds.md, "Pictures", states them for users):

- **Brightness.** The picture is read by its brightness (luminance; transparency counts as
  white), smoothed (SMOOTH_PER_PX of its smaller side, in SMOOTH_RANGE_PX pixels), and corrected for uneven lighting: a
  quadratic surface fitted to the background divides it out, where the picture's edge shows
  uneven lighting (its 5-95% range over EVEN_EDGE of the picture's range).
- **Background and polarity.** The background is the level of the picture's edge (its median
  there). The mould is the largest connected region that differs from it and does not touch
  the edge (a dark mould on a light background or a light one on a dark background alike).
  `invert=True` (`--invert`) takes the mould to be of the edge's level instead (a picture
  inside a frame of the mould's colour).
- **Holes and posts.** Inside the mould's outline, away from its edge, the regions that
  differ from the mould's own level by more than POST_CONTRAST of the mould's contrast with
  the background are its holes (of the background's level) and its posts: `posts="auto"`
  (`--posts auto`, the default): the round regions of a third level (neither the mould's
  nor the background's), darker or lighter; when there are none, the round holes no wider
  than HOLE_POST_MAX of the mould's larger side. `"dark"` / `"light"`: only the round
  regions darker / lighter than the mould; `"holes"`: every round hole; `"none"`: no posts
  (every enclosed region of the background's level is a hole). A region is round when its
  edge lies within ROUND_RESIDUAL of the radius (RMS; or ROUND_RESIDUAL_PX pixels) from the
  circle fitted to it. A non-round region of a post's
  level is ignored when it is a thin line (a stroke, text), and refused when it is thick
  (posts that touch or an oval post). Edges are traced at sub-pixel precision at the level
  halfway between the two sides (skimage.measure.find_contours); posts are circles fitted to
  their edge (skimage.measure.CircleModel).
- **Scale.** A picture `condor mould --png` wrote states its box and the axes' pixels in its
  PNG text (PICTURE_KEY): it is read at that scale. Otherwise `pixel_um` (`--pixel-um`, the
  side of a pixel in micrometres; needs the cell spacing `l0_um`) gives it, else the
  picture's larger side spans the scene's box (a picture of the masks on the checkpoint's
  grid reads as it always did).
- **Errors.** A picture with no closed outline (no region stands out from the edge's level,
  or the mould touches the picture's edge), a line drawing, or posts that touch: a
  DrawingError naming the file and the flag that helps.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from condor.moulds.mould import DrawingError
from condor.moulds.shapes import Circle, Drawing, Ring, Shapes, finish_drawing

PICTURE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")
POST_MODES = ("auto", "dark", "light", "holes", "none")
EVEN_EDGE = 0.02  # lighting is corrected when the edge's 5-95% range exceeds this of the range
PICTURE_KEY = "condor:picture"  # PNG text of condor's own pictures: {"box_l0", "axes_px"}

SMOOTH_PER_PX = 1 / 400  # Gaussian smoothing before telling the levels apart: this much of
SMOOTH_RANGE_PX = (0.5, 2.0)  # the picture's smaller side, within these pixels
CONTOUR_SMOOTH_PX = 0.5  # ... before tracing the outline and holes (posts: their circle's
# radius is corrected for the smoothing, which moves its half level in by sigma^2 / 2r)
MAX_SIDE_PX = 2400  # larger pictures are reduced to this side first (their scale kept)
POST_CONTRAST = 0.35  # a hole or post differs from the mould by this much of |mould - background|
BACKGROUND_MATCH = 0.2  # a region within this much of |mould - background| of the background's level is of its shade
ROUND_RESIDUAL = 0.08  # a region is round when its edge lies within this much of its
ROUND_RESIDUAL_PX = 0.25  # fitted circle's radius (RMS), or within this many pixels
HOLE_POST_MAX = 0.15  # auto: a round hole at most this wide (of the mould's larger side) is a post
THIN_PX = 2.0  # a region whose largest inscribed disk has a radius below this is a line


@dataclass(frozen=True)
class PictureOptions:
    """How to read a picture: `invert` (the mould is of the edge's level), `posts` (one of
    POST_MODES), `pixel_um` (a pixel's side in micrometres, None: the picture states it or
    spans the box)."""

    invert: bool = False
    posts: str = "auto"
    pixel_um: float | None = None

    def check(self) -> None:
        if self.posts not in POST_MODES:
            raise DrawingError(f"--posts {self.posts!r}: choose one of {POST_MODES}")
        if self.pixel_um is not None and not (isinstance(self.pixel_um, (int, float))
                                              and math.isfinite(self.pixel_um)
                                              and self.pixel_um > 0):
            raise DrawingError(f"--pixel-um {self.pixel_um!r} must be a positive number of "
                               "micrometres")


def is_picture(path) -> bool:
    return Path(path).suffix.lower() in PICTURE_SUFFIXES


def picture_metadata(box_l0: float, axes_px) -> dict:
    """The PNG text condor writes into its own mould pictures (plots.mould_picture): the box
    side in l0 and the axes' pixel box (left, top, right, bottom; y down), where [0, box]^2 is
    drawn."""
    return {PICTURE_KEY: json.dumps({"box_l0": float(box_l0),
                                     "axes_px": [float(v) for v in axes_px]})}


# --------------------------------------------------------------------------- reading


def _load(path: Path) -> tuple[np.ndarray, dict]:
    """(luminance (H, W) in [0, 1], PNG text) of a picture; transparency is white."""
    from PIL import Image, UnidentifiedImageError

    try:
        image = Image.open(path)
    except UnidentifiedImageError as error:
        raise DrawingError(f"{path} is not a picture condor can read (PNG, TIFF or JPEG): "
                           f"{error}") from error
    with image:
        text = dict(getattr(image, "text", {}) or {})
        if image.mode in ("I", "I;16", "I;16B", "I;16L", "F"):
            grey = np.asarray(image, dtype=np.float64)
            low, high = float(grey.min()), float(grey.max())
            grey = (grey - low) / (high - low) if high > low else np.zeros_like(grey)
        else:
            rgba = np.asarray(image.convert("RGBA"), dtype=np.float64) / 255.0
            alpha = rgba[..., 3:4]
            rgb = rgba[..., :3] * alpha + (1.0 - alpha)  # over white
            grey = rgb @ np.array([0.2125, 0.7154, 0.0721])  # skimage.color.rgb2gray's weights
    if grey.ndim != 2 or min(grey.shape) < 8:
        raise DrawingError(f"{path}: a picture of {grey.shape} px is too small to read a mould "
                           "from")
    return grey, text


def _frame(path: Path, grey: np.ndarray, text: dict, scene_box: float, options: PictureOptions,
           l0_um) -> tuple[np.ndarray, float, str, str, tuple[float, float]]:
    """(grey cropped to what holds the mould, drawing units per pixel, unit "l0" or "mm", how
    the scale was read, (x, y) offset in pixels of the crop's first pixel)."""
    stated = text.get(PICTURE_KEY)
    if stated is not None:
        try:
            meta = json.loads(stated)
            box = float(meta["box_l0"])
            left, top, right, bottom = (float(v) for v in meta["axes_px"])
        except (ValueError, KeyError, TypeError) as error:
            raise DrawingError(f"{path}: its {PICTURE_KEY!r} text is not condor's "
                               f"({error})") from error
        inset = 3  # the axes' frame line, drawn on the box's edge
        r0, r1 = int(math.ceil(top)) + inset, int(math.floor(bottom)) - inset
        c0, c1 = int(math.ceil(left)) + inset, int(math.floor(right)) - inset
        crop = grey[r0:r1, c0:c1]
        per_px = box / (right - left)
        # pixel (row r, column c) of the crop has its centre at x = (c0 + c + 0.5 - left) px
        return (crop, per_px, "l0",
                f"condor's own picture: its box, {box:g} l0, is stated in the file",
                (c0 - left, r0 - top))
    if options.pixel_um is not None:
        if l0_um is None:
            raise DrawingError(f"{path}: --pixel-um {options.pixel_um:g} gives the picture's "
                               "size in micrometres: give the cell spacing l0 too (--l0-um, "
                               "e.g. --l0-um 16)")
        return (grey, options.pixel_um / 1000.0, "mm",
                f"--pixel-um {options.pixel_um:g}: {options.pixel_um:g} um a pixel", (0.0, 0.0))
    per_px = scene_box / max(grey.shape)
    return (grey, per_px, "l0",
            f"it states no scale, so its larger side spans the scene's box, {scene_box:g} l0 "
            "(--pixel-um gives its true scale, --fit scales it)", (0.0, 0.0))


def _lighting(smooth: np.ndarray, classes: np.ndarray):
    """A function that divides uneven lighting out of a picture: a quadratic surface S
    (median 1) fitted to `smooth` as level(class) * S, over the two classes of `classes`
    (bool: the two sides of a first threshold), so that each class has one level again."""
    h, w = smooth.shape
    flat = np.linspace(0, h * w - 1, min(h * w, 60000)).astype(int)
    rows, cols = np.unravel_index(flat, (h, w))
    value, side = smooth[rows, cols], classes[rows, cols]
    y, x = rows / h - 0.5, cols / w - 0.5
    terms = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
    surface = np.ones(len(value))
    coef = np.array([1.0, 0, 0, 0, 0, 0])
    for _ in range(3):
        levels = {k: float(np.median(value[side == k] / surface[side == k]))
                  if np.any(side == k) else 0.0 for k in (False, True)}
        scale = np.where(side, levels[True], levels[False])
        if not np.any(scale > 0):
            return lambda image: image
        coef, *_ = np.linalg.lstsq(terms * scale[:, None], value, rcond=None)
        surface = terms @ coef
    yy, xx = np.mgrid[0:h, 0:w]
    yy, xx = yy / h - 0.5, xx / w - 0.5
    full = (coef[0] + coef[1] * xx + coef[2] * yy + coef[3] * xx * xx + coef[4] * xx * yy
            + coef[5] * yy * yy)
    full = full / np.median(full)
    if not np.all(np.isfinite(full)) or full.min() <= 0.1:  # not a lighting: leave it
        return lambda image: image
    return lambda image: image / full


def _edge(shape) -> np.ndarray:
    edge = np.zeros(shape, dtype=bool)
    edge[:2, :], edge[-2:, :], edge[:, :2], edge[:, -2:] = True, True, True, True
    return edge


def _disk(radius: int) -> np.ndarray:
    from skimage.morphology import disk

    return disk(max(int(radius), 1))


@dataclass
class _Region:
    mask: np.ndarray  # bool (H, W)
    level: float  # its median brightness
    round: bool
    thin: bool
    circle: tuple[float, float, float] | None  # x, y, r in pixels (column, row)


def _circle_fit(points: np.ndarray):
    """(xc, yc, r) of the least-squares circle through (k, 2) points, or None."""
    from skimage.measure import CircleModel

    if len(points) < 3:
        return None
    if hasattr(CircleModel, "from_estimate"):
        model = CircleModel.from_estimate(points)
        if not model:
            return None
        (xc, yc), r = model.center, model.radius
    else:  # scikit-image < 0.26
        model = CircleModel()
        if not model.estimate(points):
            return None
        xc, yc, r = model.params
    return float(xc), float(yc), float(r)


def _contour(field: np.ndarray, region: np.ndarray, band: int,
             others: np.ndarray | None = None) -> np.ndarray | None:
    """The closed 0.5-level contour (k, 2) as (x, y) pixel centres' coordinates of `field`
    (1 inside `region`, 0 outside, in between at its edge), traced in a band of `band` px
    about the region's edge (`others`, other regions, held at 0); the one enclosing the most
    area, None when there is none."""
    from scipy import ndimage
    from skimage.measure import find_contours

    inner = ndimage.binary_erosion(region, _disk(band), border_value=0)
    outer = ndimage.binary_dilation(region, _disk(band))
    if others is not None:
        outer &= ~ndimage.binary_dilation(others, _disk(1))
    forced = np.where(inner, 1.0, np.where(outer, np.clip(field, 0.0, 1.0), 0.0))
    padded = np.pad(forced, 1)  # contours close at the picture's edge
    closed = [c for c in find_contours(padded, 0.5) if len(c) > 3 and np.allclose(c[0], c[-1])]
    if not closed:
        return None
    best = max(closed, key=lambda c: abs(_area(c)))
    return np.column_stack([best[:, 1] - 1.0, best[:, 0] - 1.0])  # (x = column, y = row)


def _area(points: np.ndarray) -> float:
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))


def read_picture(path, scene_box: float, l0_um: float | None = None,
                 options: PictureOptions | None = None) -> Drawing:
    """The outline, holes and posts of a picture of a mould (module docstring: the rules),
    in l0, y up, not yet placed. `scene_box`: the scene's box side (l0), which a picture
    that states no scale spans; DrawingError (one line naming the file and the flag that
    helps) when no mould can be read from it, InvalidMouldError (finish_drawing) when what
    was read is not a valid mould."""
    from scipy import ndimage
    from skimage import filters, transform

    options = options or PictureOptions()
    options.check()
    path = Path(path)
    path.stat()  # a missing file is an OSError naming it
    grey, text = _load(path)
    grey, per_px, unit, scale_how, offset = _frame(path, grey, text, scene_box, options, l0_um)
    side = max(grey.shape)
    if side > MAX_SIDE_PX:  # keep the work bounded: a photo of 6000 px holds no more mould
        factor = MAX_SIDE_PX / side
        grey = transform.rescale(grey, factor, anti_aliasing=True)
        per_px /= factor
        offset = (offset[0] * factor, offset[1] * factor)
    h, w = grey.shape
    sigma = float(np.clip(min(h, w) * SMOOTH_PER_PX, *SMOOTH_RANGE_PX))
    smooth = filters.gaussian(grey, sigma=sigma, preserve_range=True)
    edge = _edge(grey.shape)

    if np.ptp(smooth) < 0.02:
        raise DrawingError(f"{path}: no closed outline: the picture is all one shade (a "
                           "picture of a mould needs the mould in another shade than its "
                           "background)")
    # the background: the edge's level; uneven lighting divided out (twice, from a first
    # guess) where the edge shows it: the lighting model has two levels, so on an evenly lit
    # picture of three (condor's own: background, mould, posts) it would bend the background
    corrected, correct = smooth, (lambda image: image)
    uneven = np.subtract(*np.percentile(smooth[edge], [95, 5])) > EVEN_EDGE * np.ptp(smooth)
    if uneven:
        for _ in range(2):
            threshold = filters.threshold_otsu(corrected) if np.ptp(corrected) > 0 else 0.0
            correct = _lighting(smooth, corrected > threshold)
            corrected = correct(smooth)
    # edges are traced on a finer smoothing, so that they sit where they are drawn
    fine = correct(filters.gaussian(grey, sigma=CONTOUR_SMOOTH_PX, preserve_range=True))
    b = float(np.median(corrected[edge]))
    distance = np.abs(corrected - b)
    contrast_threshold = filters.threshold_otsu(distance) if np.ptp(distance) > 1e-6 else np.inf
    differs = distance > contrast_threshold
    if options.invert:
        differs = ~differs
    speck = max(1, int((min(h, w) / 200.0) ** 2))  # noise: regions of at most this many px
    differs = _without_specks(differs, speck)
    labels, n = ndimage.label(differs)
    if n == 0:
        raise DrawingError(f"{path}: no closed outline: nothing in the picture stands out from "
                           "its edge's level (the background); a picture of a mould needs "
                           "the mould in another shade than its background (or --invert)")
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    touching = set(np.unique(labels[edge])) - {0}
    free = [k for k in range(1, n + 1) if k not in touching]
    if not free:
        raise DrawingError(f"{path}: no closed outline: the mould touches the picture's edge; "
                           "crop it with a margin of background all round (or --invert when "
                           "the mould is the shade at the picture's edge)")
    mould_label = max(free, key=lambda k: sizes[k])
    if touching and max(sizes[k] for k in touching) > 4 * sizes[mould_label]:
        biggest = max(touching, key=lambda k: sizes[k])
        if not _frame_like(labels == biggest):
            raise DrawingError(f"{path}: no closed outline: the largest shape touches the "
                               "picture's edge; crop it with a margin of background all round "
                               "(or --invert when the mould is the shade at the picture's edge)")
    component = labels == mould_label
    filled = ndimage.binary_fill_holes(component)
    if component.sum() < 0.2 * filled.sum() and \
            ndimage.distance_transform_edt(component).max() < THIN_PX:
        raise DrawingError(f"{path}: the mould is drawn as a line, not filled; fill it (a "
                           "photo, or a drawing with the mould filled in), or give the drawing "
                           "as SVG or DXF")
    m = float(np.median(corrected[component]))
    band = int(math.ceil(2 * sigma)) + 1
    around = ndimage.binary_dilation(filled, _disk(2 * band)) & \
        ~ndimage.binary_dilation(filled, _disk(band))
    if around.any():  # the mould's own surroundings: the background where it lies
        b = float(np.median(corrected[around]))
    if abs(m - b) < 1e-6:
        raise DrawingError(f"{path}: the mould has the background's shade; use --invert when "
                           "the mould is the shade at the picture's edge")

    # inside the outline: holes and posts (regions that reach its rim are its blurred edge)
    other = filled & (np.abs(corrected - m) > POST_CONTRAST * abs(m - b))
    other = _without_specks(other, speck)
    inner_labels, k = ndimage.label(other)
    rim = set(np.unique(inner_labels[ndimage.binary_dilation(~filled)])) - {0}
    regions = []
    for label in range(1, k + 1):
        if label in rim:
            continue
        mask = ndimage.binary_fill_holes(inner_labels == label)
        level = _level(fine, inner_labels == label, m)
        others = (inner_labels > 0) & ~mask
        regions.append(_region(mask, level, corrected, m, others, band, sigma))
    background_kind = [abs(r.level - b) <= BACKGROUND_MATCH * abs(m - b) for r in regions]
    larger_side = max(np.ptp(np.nonzero(filled)[0]), np.ptp(np.nonzero(filled)[1])) + 1
    posts, holes, ignored = [], [], 0
    third = [r for r, bg in zip(regions, background_kind) if not bg]
    for region in third:
        darker = region.level < m
        wanted = {"auto": True, "dark": darker, "light": not darker, "holes": False,
                  "none": False}[options.posts]
        if not wanted:
            ignored += 1
            continue
        if region.round:
            posts.append(region)
        elif region.thin:
            ignored += 1
        else:
            y, x = (float(v) for v in ndimage.center_of_mass(region.mask))
            raise DrawingError(
                f"{path}: the post-coloured region at ({x + offset[0]:.0f}, {y + offset[1]:.0f}) "
                "px (from the top left) is not round: posts that touch or overlap cannot be "
                "told apart (nor an oval post); draw them apart, or read that shade as part of "
                "the mould with --posts none (or --posts dark / --posts light for the other "
                "shade)")
    for region, bg in zip(regions, background_kind):
        if not bg:
            continue
        small = region.circle is not None and 2 * region.circle[2] <= HOLE_POST_MAX * larger_side
        as_post = region.round and (options.posts == "holes" or
                                    (options.posts == "auto" and not third and small))
        (posts if as_post else holes).append(region)

    # sub-pixel edges: the outline and holes at the level halfway between mould and background
    mould_field = (fine - b) / (m - b)
    shell = _contour(mould_field, filled, band)
    if shell is None:
        raise DrawingError(f"{path}: no closed outline could be traced round the mould; crop "
                           "the picture with a margin of background all round")
    hole_rings = []
    for region in holes:
        ring = _contour(1.0 - mould_field, region.mask, band,
                        np.any([r.mask for r in regions if r is not region], axis=0)
                        if len(regions) > 1 else None)
        if ring is not None:
            hole_rings.append(ring)
    circles = []
    for region in posts:
        x, y, r = region.circle
        circles.append((x, y, r))

    def name(what: str, x: float, y: float) -> str:
        return f"the {what} at ({x + offset[0]:.0f}, {y + offset[1]:.0f}) px"

    def shift(points: np.ndarray) -> np.ndarray:
        return points + np.array([0.5 + offset[0], 0.5 + offset[1]])

    shapes = Shapes(str(path), unit, "px",
                    shell=Ring("the outline", _simplify(shift(shell))),
                    holes=[Ring(name("hole", *ring.mean(axis=0)), _simplify(shift(ring)))
                           for ring in hole_rings],
                    circles=[Circle(name("post", x, y), x + 0.5 + offset[0],
                                    y + 0.5 + offset[1], r) for x, y, r in circles])
    levels = (f"background {_shade(b)} (its edge), mould {'darker' if m < b else 'lighter'}"
              + (f", posts {'a third shade' if third and posts else 'round holes'}"
                 if posts else ", no posts"))
    how = f"a picture of {w} x {h} px: {levels}; {scale_how}"
    drawing = finish_drawing(shapes, per_px, l0_um, flip_y=True, how=how)
    return drawing


def _level(image: np.ndarray, mask: np.ndarray, m: float) -> float:
    """A region's own shade: the median of its core (2 px in from its edge, where the
    smoothing of its edge does not reach), or, for a region too small for a core, its 10%
    quantile on the side away from the mould's shade `m`."""
    from scipy import ndimage

    core = ndimage.binary_erosion(mask, _disk(2), border_value=0)
    if core.sum() >= 5:
        return float(np.median(image[core]))
    values = image[mask]
    side = np.median(values) < m
    return float(np.quantile(values, 0.1 if side else 0.9))


def _without_specks(mask: np.ndarray, speck: int) -> np.ndarray:
    """`mask` without its connected regions of at most `speck` pixels (noise)."""
    from scipy import ndimage

    labels, n = ndimage.label(mask)
    if n == 0:
        return mask
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    keep = sizes > speck
    keep[0] = False
    return keep[labels]


def _shade(level: float) -> str:
    return "light" if level >= 0.5 else "dark"


def _frame_like(mask: np.ndarray) -> bool:
    """Whether a region touching the picture's edge is a thin frame (a border line), which
    holds no mould."""
    from scipy import ndimage

    return ndimage.distance_transform_edt(np.pad(mask, 1)).max() < 2 * THIN_PX


def _region(mask: np.ndarray, level: float, corrected: np.ndarray, m: float,
            others: np.ndarray, band: int, sigma: float) -> _Region:
    """A region inside the mould: whether it is a line, whether it is round, and its circle
    fitted to its edge at the level halfway between it and the mould."""
    from scipy import ndimage

    thin = ndimage.distance_transform_edt(np.pad(mask, 1)).max() < THIN_PX
    circle, points = None, None
    if abs(level - m) > 1e-9:
        field = (corrected - m) / (level - m)
        points = _contour(field, mask, band, others)
        if points is not None:
            circle = _circle_fit(points)
        if circle is not None:  # the smoothing moves a circle's half level in by s^2 / 2r
            circle = (circle[0], circle[1], circle[2] + sigma ** 2 / (2 * circle[2]))
    round_ = False
    if circle is not None:
        xc, yc, r = circle
        residual = np.sqrt(np.mean((np.hypot(points[:, 0] - xc, points[:, 1] - yc) - r) ** 2))
        round_ = bool(residual <= max(ROUND_RESIDUAL * r, ROUND_RESIDUAL_PX))
    return _Region(mask=mask, level=level, round=bool(round_), thin=bool(thin), circle=circle)


def _simplify(points: np.ndarray, tolerance_px: float = 0.05) -> np.ndarray:
    """A traced ring with its collinear vertices dropped (shapely, within `tolerance_px`)."""
    from shapely.geometry import Polygon

    polygon = Polygon(points)
    simple = polygon.simplify(tolerance_px, preserve_topology=True)
    if simple.geom_type != "Polygon" or simple.is_empty or not simple.is_valid:
        return points
    return np.asarray(simple.exterior.coords)[:-1]
