"""Scene presets: the simulation box, layer depth and grid that a dataset is built on.

Lengths are in units of l0 (the nearest-neighbour rest length). The kernel width sigma is
fixed in l0 (3 px at the paper's 256 px over 62.5 l0), so it is the same at every resolution.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

PAPER_BOX = 62.5
PAPER_PIXELS = 256
SIGMA_L0 = 3.0 * PAPER_BOX / PAPER_PIXELS  # 0.732421875 l0
# Two box sides or pixel sizes (l0) closer than this, relative, are the same grid's: what a
# checkpoint, a result or a mould records (float products of what a scene states) against a
# scene. The one home of the same-grid check.
GRID_RTOL = 1e-9


def same_length(a: float, b: float) -> bool:
    """Whether two box sides or pixel sizes (l0) are the same grid's (GRID_RTOL)."""
    return math.isclose(float(a), float(b), rel_tol=GRID_RTOL)


@dataclass(frozen=True)
class Scene:
    name: str
    box: float  # side of the square simulation box, l0
    depth: float  # depth of the extruded mould, l0
    pixels: int  # grid side in pixels
    area_fraction: float = 0.40  # mould area / box area (paper: exactly 40%)
    max_extent: float = 0.90  # largest mould width or height / box (paper: 0.9)
    sigma: float = SIGMA_L0  # kernel width, l0

    @property
    def pixel_size(self) -> float:
        """Side of one pixel, l0."""
        return self.box / self.pixels

    @property
    def sigma_px(self) -> float:
        return self.sigma / self.pixel_size

    def to_dict(self) -> dict:
        return asdict(self)


PRESETS: dict[str, Scene] = {
    # The paper's scene: about 8,800 cells, 256 px.
    "paper": Scene("paper", box=PAPER_BOX, depth=4.0, pixels=PAPER_PIXELS),
    # The embedded default: half the box side (a quarter of the cells), same pixel size
    # as 128 px at paper scale; builds a few hundred samples on a 2-core laptop.
    "default": Scene("default", box=PAPER_BOX / 2, depth=4.0, pixels=64),
    # For tests: a few hundred cells.
    "tiny": Scene("tiny", box=PAPER_BOX / 4, depth=2.0, pixels=32),
}


def get_scene(name: str, **overrides) -> Scene:
    """Return the preset `name`, with any fields in `overrides` replaced."""
    if name not in PRESETS:
        raise ValueError(f"unknown scene {name!r}; choose one of {sorted(PRESETS)}")
    scene = PRESETS[name]
    unknown = set(overrides) - set(Scene.__dataclass_fields__)
    if unknown:
        raise ValueError(f"unknown scene field(s) {sorted(unknown)} for scene {name!r}")
    return replace(scene, **overrides) if overrides else scene
