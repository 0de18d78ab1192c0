"""condor.moulds.read_picture: pictures of moulds (clean, photo-like, condor's own), made in the
tests, read back as outlines, holes and posts; the rules of polarity and posts, any resolution,
the scale, and the one-line errors."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from PIL import Image
from shapely.geometry import Polygon

from condor import plots
from condor.model.scenes import get_scene
from condor.moulds.lab import lab_mould
from condor.moulds.mould import DrawingError, Mould, input_channels
from condor.moulds.paper import generate_mould
from condor.moulds.read import load_placement
from condor.moulds.read_picture import PictureOptions

DEFAULT = get_scene("default")


def picture(mould: Mould, pixels: int, background=0.95, mould_shade=0.1, posts=0.55,
            noise=0.0, lighting=0.0, seed=0) -> np.ndarray:
    """A grey picture (uint8, row 0 at the top) of `mould` spanning its box: each pixel the
    area-weighted shade of background, mould and posts (4 x 4 subpixels), then lighting
    falling by `lighting` across it and Gaussian noise."""
    cover = input_channels(mould, pixels, supersample=4)
    image = (background * (1 - cover[0] - cover[1]) + mould_shade * cover[0]
             + posts * cover[1])[::-1]
    yy, xx = np.mgrid[0:pixels, 0:pixels] / pixels
    image = image * (1 - lighting * (0.7 * xx + 0.3 * yy))
    image = image + noise * np.random.default_rng(seed).standard_normal(image.shape)
    return (np.clip(image, 0, 1) * 255).astype(np.uint8)


def save(image: np.ndarray, path, **kwargs):
    Image.fromarray(image).save(path, **kwargs)
    return path


def dogbone() -> Mould:
    return lab_mould(7, 1, "dogbone", DEFAULT)


def same_geometry(true: Mould, read: Mould, area=0.003, radius=0.02, holes=None):
    """The read mould has the true one's area (relative `area`), as many posts of the same
    radii (relative `radius`) and holes; the outline's symmetric difference is small."""
    assert read.polygon.area == pytest.approx(true.polygon.area, rel=area)
    assert len(read.polygon.interiors) == (len(true.polygon.interiors) if holes is None else holes)
    assert read.n_tethers == true.n_tethers
    np.testing.assert_allclose(np.sort(read.tethers[:, 2]), np.sort(true.tethers[:, 2]),
                               rtol=radius)
    # placed as a drawing: the bounding box centred, as the true mould is (the generator's rule)
    assert true.polygon.symmetric_difference(read.polygon).area < 5 * area * true.polygon.area


def test_condor_s_own_picture_is_read_back_at_its_scale(tmp_path):
    """`condor mould --png`'s picture (plots.mould_picture) states its box in the PNG: a
    generated mould and a lab frame (holes, posts) read back to their geometry."""
    for mould in (generate_mould(7, 3, DEFAULT), lab_mould(7, 2, "frame", DEFAULT)):
        path = plots.mould_picture(mould, tmp_path / f"{mould.family}.png")
        placement = load_placement(path, DEFAULT)
        same_geometry(mould, placement.mould, area=0.002, radius=0.01)
        assert "condor's own picture" in placement.describe()
        # a box that the placement does not move: at its drawn size, centred as drawn
        np.testing.assert_allclose(placement.mould.polygon.bounds, mould.polygon.bounds, atol=0.08)


def test_a_photo_like_picture_with_noise_and_uneven_lighting(tmp_path):
    """Noise of 0.1, lighting falling by half across it, JPEG: the dog-bone's outline and both
    posts come back."""
    mould = dogbone()
    path = save(picture(mould, 400, noise=0.1, lighting=0.5), tmp_path / "photo.jpg",
                quality=80)
    placement = load_placement(path, DEFAULT)
    same_geometry(mould, placement.mould, area=0.01, radius=0.05)
    assert "mould darker" in placement.describe() and "posts a third shade" in placement.describe()


def test_polarity_is_found_not_assumed(tmp_path):
    """A light mould on a dark background (TIFF, uneven lighting) reads as the dark mould on a
    light one (PNG): the background is the shade at the picture's edge."""
    mould = dogbone()
    dark = load_placement(save(picture(mould, 300), tmp_path / "a.png"), DEFAULT).mould
    light = load_placement(save(picture(mould, 300, background=0.08, mould_shade=0.9, posts=0.45,
                                        lighting=0.4), tmp_path / "b.tif"), DEFAULT).mould
    for read in (dark, light):
        same_geometry(mould, read, area=0.005, radius=0.03)


@pytest.mark.parametrize("pixels", [64, 256, 1000])
def test_any_resolution(tmp_path, pixels):
    """64 px (posts two pixels across), 256 px, 1000 px: the picture spans the box."""
    mould = dogbone()
    read = load_placement(save(picture(mould, pixels), tmp_path / "m.png"), DEFAULT).mould
    coarse = pixels < 100
    same_geometry(mould, read, area=0.02 if coarse else 0.004, radius=0.12 if coarse else 0.03)


def square_with_round_regions(tmp_path, name, shade, radius=8, centres=((60, 100), (140, 100))):
    """A dark 140 x 120 px rectangle on a light 200 px picture with round regions of `shade`
    (edges antialiased: 4 x 4 subpixels)."""
    yy, xx = (np.mgrid[0:800, 0:800] + 0.5) / 4
    image = np.full((800, 800), 0.95)
    image[160:640, 120:680] = 0.05
    for cx, cy in centres:
        image[(xx - cx) ** 2 + (yy - cy) ** 2 < radius ** 2] = shade
    image = image.reshape(200, 4, 200, 4).mean(axis=(1, 3))
    return save((image * 255).round().astype(np.uint8), tmp_path / name)


def test_the_posts_rule_and_its_overrides(tmp_path):
    """Round holes of the background's shade: posts when there is no third shade (auto), holes
    with --posts none; a third shade: posts, and --posts light / dark choose by shade; a
    large round hole (a ring's) stays a hole."""
    holes = square_with_round_regions(tmp_path, "holes.png", 0.95)
    auto = load_placement(holes, DEFAULT).mould
    assert auto.n_tethers == 2 and not auto.polygon.interiors
    none = load_placement(holes, DEFAULT, picture=PictureOptions(posts="none")).mould
    assert none.n_tethers == 0 and len(none.polygon.interiors) == 2
    grey = square_with_round_regions(tmp_path, "grey.png", 0.5)
    assert load_placement(grey, DEFAULT).mould.n_tethers == 2
    assert load_placement(grey, DEFAULT, picture=PictureOptions(posts="light")).mould.n_tethers == 2
    assert load_placement(grey, DEFAULT, picture=PictureOptions(posts="dark")).mould.n_tethers == 0
    # post radius: 8 px of 200 spanning the 31.25 l0 box, within a tenth of a pixel
    np.testing.assert_allclose(auto.tethers[:, 2], 8 * DEFAULT.box / 200, atol=0.05 * DEFAULT.box / 200)
    yy, xx = np.mgrid[0:200, 0:200]
    r = np.hypot(xx - 100, yy - 100)
    ring = save((np.where((r < 80) & (r >= 40), 0.05, 0.95) * 255).astype(np.uint8),
                tmp_path / "ring.png")
    read = load_placement(ring, DEFAULT).mould
    assert read.n_tethers == 0 and len(read.polygon.interiors) == 1
    expected = np.pi * (80 ** 2 - 40 ** 2) * (DEFAULT.box / 200) ** 2
    assert read.polygon.area == pytest.approx(expected, rel=0.01)


def test_the_pixel_size_gives_the_drawn_size(tmp_path):
    """--pixel-um 5 with --l0-um 16: a 120 px wide mould is 0.6 mm = 37.5 l0 wide, and --fit
    scales it like a drawing."""
    path = square_with_round_regions(tmp_path, "m.png", 0.5)
    options = PictureOptions(pixel_um=5.0)
    placement = load_placement(path, DEFAULT, l0_um=16, picture=options, fit="extent")
    assert placement.drawn_l0[1] == pytest.approx(120 * 5 / 16, rel=0.01)
    assert placement.scale == pytest.approx(0.9 * DEFAULT.box / (140 * 5 / 16), rel=0.01)
    with pytest.raises(DrawingError, match="--l0-um"):
        load_placement(path, DEFAULT, picture=options)


@pytest.mark.parametrize("case, words", [
    ("touching", ["touch.png", "not round", "--posts none"]),
    ("edge", ["edge.png", "no closed outline", "touches the picture's edge", "--invert"]),
    ("blank", ["blank.png", "no closed outline", "one shade"]),
    ("line", ["line.png", "drawn as a line", "SVG or DXF"]),
])
def test_a_picture_without_a_mould_is_one_line_naming_the_file_and_the_flag(tmp_path, case, words):
    yy, xx = np.mgrid[0:200, 0:200]
    image = np.full((200, 200), 0.95)
    if case == "touching":
        image[40:160, 30:170] = 0.05
        for cx in (90, 106):
            image[(xx - cx) ** 2 + (yy - 100) ** 2 < 100] = 0.5
    elif case == "edge":
        image[0:160, 30:170] = 0.05
    elif case == "line":
        image[40:160, 30:170] = 0.0
        image[42:158, 32:168] = 0.95
    name = {"touching": "touch", "edge": "edge", "blank": "blank", "line": "line"}[case]
    path = save((image * 255).astype(np.uint8), tmp_path / f"{name}.png")
    with pytest.raises(DrawingError) as error:
        load_placement(path, DEFAULT)
    message = str(error.value)
    assert "\n" not in message
    for word in words:
        assert word in message, (word, message)


def test_invert_reads_a_mould_inside_a_frame_of_its_shade(tmp_path):
    """A dark mould inside a dark frame line at the picture's edge: the edge's shade is not the
    background; --invert takes the mould to be of the edge's shade."""
    image = np.full((200, 200), 0.95)
    image[:3, :], image[-3:, :], image[:, :3], image[:, -3:] = 0.05, 0.05, 0.05, 0.05
    image[50:150, 40:160] = 0.05
    path = save((image * 255).astype(np.uint8), tmp_path / "framed.png")
    read = load_placement(path, DEFAULT, picture=PictureOptions(invert=True)).mould
    assert read.polygon.area == pytest.approx(100 * 120 * (DEFAULT.box / 200) ** 2, rel=0.01)


def test_what_was_read_is_said_in_one_line(tmp_path):
    mould = dogbone()
    line = load_placement(save(picture(mould, 300), tmp_path / "d.png"), DEFAULT,
                          l0_um=16).describe()
    assert line.startswith("read 1 outline, 0 holes, 2 posts (radius 0.8")
    read = [float(word) for word in line.split("(radius ")[1].split(")")[0].split()
            if word.replace(".", "").isdigit()][::2]  # "0.8298 l0 = 0.01328 mm, 1.483 l0 ..."
    np.testing.assert_allclose(read, sorted(mould.tethers[:, 2]), rtol=0.01)
    assert "a picture of 300 x 300 px" in line and "\n" not in line


def test_condor_s_own_picture_of_a_ring_round_a_large_post(tmp_path):
    """A light mould round one large dark post (condor's own picture: three shades, evenly
    lit): the outline and the post come back, not the post as the mould. Fitting the lighting
    to such a picture bent its background round the mould, and 5 of the default run's 100 test
    moulds (rings, and moulds of 4-12 posts) read as one of their posts."""
    for k in range(4):
        mould = lab_mould(2026, k, "ring", DEFAULT)
        path = plots.mould_picture(mould, tmp_path / f"ring{k}.png")
        same_geometry(mould, load_placement(path, DEFAULT).mould, area=0.002, radius=0.01)
