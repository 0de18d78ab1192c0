"""condor.prediction_page: the page `condor predict --out p.png` draws for a biologist."""

import numpy as np
import pandas as pd
from PIL import Image

from condor import prediction_page as page
from condor.surrogate.predict import Prediction


def test_the_verdict_on_the_page_is_two_short_lines():
    inside = ("inside the training domain on all 5 counts (area / box area 0.4; larger side / "
              "box 0.77; tethers 4; tether radius / box 0.03-0.03; tethers the input grid misses 0)")
    outside = ("OUTSIDE the training domain on 2 of 5 counts: area / box area 0.32 (training: 0.4 "
               "exactly (within +-10% tolerated)); tethers 2 (training: 0 or at least 4). Measured "
               "on moulds drawn outside it (experiments/out_of_domain at 89193f0; ...): ... "
               "Simulate it (condor simulate) to be sure")
    for verdict, words in ((inside, "inside on all 5 counts"),
                           (outside, "OUTSIDE on 2 of 5 counts: area / box area 0.32; tethers 2")):
        lines = page.short_verdict(verdict)
        assert len(lines) == 2 and all(len(line) <= 130 for line in lines)
        assert words in lines[0], lines
    assert "simulate it" in page.short_verdict(outside)[1]
    assert page.short_verdict(None) == []


def test_the_page_has_plain_names_and_units(tmp_path):
    """The fields under plain names with their units; every field's panel drawn from a
    prediction of a square mould with a post."""
    n = 32
    raw = np.zeros((8, n, n))
    raw[0, 8:24, 8:24] = 2.0  # density
    raw[1, 8:24, 8:24] = 0.02  # tension
    raw[2, 8:24, 8:24], raw[3, 8:24, 8:24], raw[4, 8:24, 8:24] = 1.2, 0.4, 0.4
    inputs = np.zeros((2, n, n), np.uint8)
    inputs[0, 8:24, 8:24] = 1
    inputs[1, 14:17, 14:17], inputs[0, 14:17, 14:17] = 1, 0
    prediction = Prediction(raw, raw * n * n / raw[0].sum(), float(raw[0].sum()), raw * 0.1)
    panels = page.page_fields(raw, raw * 0.1, 0.5, 16.0)
    names = [p[0] for p in panels]
    assert names == ["density", "tension", "alignment along x", "alignment at 45°",
                     "out of plane", "density scatter", "tension scatter"]
    density = panels[0][1]
    assert panels[0][2].startswith("cells per mm²")
    assert density[16, 16] == 2.0 / (0.5 * 16 / 1000) ** 2  # cells per mm^2
    assert panels[2][1][16, 16] == (1.2 - 0.4) / 1.6  # (Sx2 - Sy2) / (Sx2 + Sy2)
    assert np.isnan(panels[1][1][0, 0])  # a ratio is blank where there is no tissue
    summary = pd.DataFrame([("alignment", 0.5, 0.1, "0..1"), ("direction", 0.0, 5.0, "deg"),
                            ("mean_tension", 0.01, 0.001, "T units"),
                            ("tissue_area_mm2", 0.02, 0.001, "mm^2")],
                           columns=["statistic", "value", "spread", "unit"])
    path = page.prediction_panels(inputs, prediction, tmp_path / "p.png", summary=summary,
                                   verdict="inside the training domain on all 5 counts (...)",
                                   pixel_size=0.5, l0_um=16.0, scale=0.5)
    with Image.open(path) as image:
        assert image.size[0] > 1000
    line = page.plain_statistics(summary)
    assert "alignment 0.5 ± 0.1 (0: random, 1: all one way) at 0 ± 5° from x" in line
    assert "mm²" in line
    # a mould whose cells point every way: its direction is noise, and the page says so
    isotropic = summary.assign(value=[0.002, 55.0, 0.01, 0.02],
                               spread=[0.029, 111.0, 0.001, 0.001])
    line = page.plain_statistics(isotropic)
    assert "in no clear direction" in line and "55" not in line
