"""The lab families' gallery (docs/moulds.md, "Lab families"): five moulds a family drawn in a
grid (docs/figures/lab_families.png), and the first of each written as an SVG drawing in mm at
l0 = 16 um through condor's own writer (docs/figures/lab/<family>.svg); `--dxf` writes the DXF
drawings too (65-77 KB each, so not kept in git).

  python experiments/generalisation/gallery.py
"""

from __future__ import annotations

from pathlib import Path

from condor import plots
from condor.model.scenes import get_scene
from condor.moulds.lab import FAMILY_NAMES, lab_mould
from condor.moulds.write import write_dxf, write_svg

DOCS = Path(__file__).resolve().parents[2] / "docs" / "figures"
SEED, L0_UM, PER_FAMILY = 2026, 16.0, 5


def main() -> None:
    import sys

    dxf = "--dxf" in sys.argv[1:]
    scene = get_scene("default")
    moulds = [lab_mould(SEED, i, family, scene) for family in FAMILY_NAMES
              for i in range(PER_FAMILY)]
    plots.mould_gallery(moulds, DOCS / "lab_families.png", ncols=PER_FAMILY, dpi=45)
    (DOCS / "lab").mkdir(parents=True, exist_ok=True)
    for family in FAMILY_NAMES:
        first = moulds[FAMILY_NAMES.index(family) * PER_FAMILY]
        write_svg(first, DOCS / "lab" / f"{family}.svg", l0_um=L0_UM)
        if dxf:
            write_dxf(first, DOCS / "lab" / f"{family}.dxf", l0_um=L0_UM)


if __name__ == "__main__":
    main()
