"""The lattice channels (condor.inputs): the simulation's own initial cells, counted against
build_lattice, in column units, exact under the box's mirrors; their estimate from masks; the
masks' sub-pixel coverage; and a surrogate that reads them."""

import numpy as np
import pytest
import shapely
from shapely.affinity import scale as shapely_scale
from shapely.geometry import Point, box

from condor import inputs
from condor.lattice import build_lattice, lattice_sites
from condor.moulds import Mould, generate_mould, input_channels
from condor.scenes import get_scene
from condor.surrogate.data import DataError, usable_samples
from condor.surrogate.physics import estimate_n_cells
from condor.surrogate.predict import Predictor
from condor.surrogate.synthetic import synthetic_dataset
from condor.surrogate.train import TrainConfig, train
from condor.surrogate.models import UNetConfig

SCENE = get_scene("default")


def _mould(mould_id=4, seed=2026):
    return generate_mould(seed, mould_id, box=SCENE.box)


def test_lattice_sites_are_build_lattices_cells():
    m = _mould()
    lat = build_lattice(m.polygon, m.tethers, SCENE.depth)
    positions, fixed = lattice_sites(m.polygon, m.tethers, SCENE.depth)
    np.testing.assert_array_equal(positions, lat.positions)
    np.testing.assert_array_equal(fixed, lat.fixed)


@pytest.mark.parametrize("mould_id", [0, 4, 9])
def test_channels_count_every_mobile_and_fixed_cell(mould_id):
    m = _mould(mould_id)
    lat = build_lattice(m.polygon, m.tethers, SCENE.depth)
    channels = inputs.of_mould(m, SCENE)
    assert channels.shape == (2, SCENE.pixels, SCENE.pixels) and channels.dtype == np.float32
    unit = inputs.column_cells(SCENE.depth, SCENE.pixel_size)
    # every cell lands on the grid (but for the kernel's tail past the box edge)
    sums = channels.sum(axis=(1, 2), dtype=np.float64) * unit
    assert sums[0] == pytest.approx(np.count_nonzero(~lat.fixed), rel=1e-4)
    assert sums[1] == pytest.approx(np.count_nonzero(lat.fixed), rel=1e-4)
    assert np.count_nonzero(lat.fixed) > 0


def test_a_full_column_reads_one():
    """Deep inside a large slab the channel is the FCC column density: 1 in column units."""
    square = Mould(box=SCENE.box, polygon=box(4, 4, SCENE.box - 4, SCENE.box - 4),
                   tethers=np.zeros((0, 3)), seed=0, mould_id=0, symmetry="none", order=1,
                   removal="no_tethers")
    channels = inputs.of_mould(square, SCENE)
    inner = channels[0, 20:44, 20:44]
    assert inner.mean() == pytest.approx(1.0, rel=0.01)
    assert np.abs(inner - 1).max() < 0.1
    assert channels[1].max() == 0


@pytest.mark.parametrize("axis", ["x", "y", "transpose"])
def test_channels_mirror_with_the_mould(axis):
    """The box's mirrors and transpose map a mould's lattice onto its image's (the
    surrogate's augmentation relies on it)."""
    m = _mould(7)
    c = SCENE.box / 2
    if axis == "transpose":
        polygon = shapely.transform(m.polygon, lambda xy: xy[:, ::-1])
        tethers = m.tethers[:, [1, 0, 2]]
        expect = lambda a: a.transpose(0, 2, 1)
    else:
        fx, fy = (-1, 1) if axis == "x" else (1, -1)
        polygon = shapely_scale(m.polygon, fx, fy, origin=(c, c))
        tethers = m.tethers.copy()
        k = 0 if axis == "x" else 1
        tethers[:, k] = 2 * c - tethers[:, k]
        expect = (lambda a: a[:, :, ::-1]) if axis == "x" else (lambda a: a[:, ::-1, :])
    a = inputs.lattice_channels(m.polygon, m.tethers, SCENE.depth, SCENE.box, SCENE.pixels,
                                SCENE.sigma)
    b = inputs.lattice_channels(polygon, tethers, SCENE.depth, SCENE.box, SCENE.pixels,
                                SCENE.sigma)
    np.testing.assert_allclose(b, expect(a), atol=1e-5)


def test_estimate_from_masks_counts_what_estimate_n_cells_counts():
    m = _mould(3)
    masks = input_channels(m, SCENE.pixels)
    estimate = inputs.estimate_lattice_channels(masks, SCENE.pixel_size, SCENE.depth, SCENE.sigma)
    unit = inputs.column_cells(SCENE.depth, SCENE.pixel_size)
    assert estimate.sum() * unit == pytest.approx(
        estimate_n_cells(masks, SCENE.pixel_size, SCENE.depth), rel=1e-5)
    exact = inputs.of_mould(m, SCENE)
    # close to the exact channels in bulk, not equal (the outline is pixelated)
    assert np.sqrt(np.mean((estimate - exact) ** 2)) < 0.1
    assert not np.allclose(estimate, exact, atol=1e-3)
    with pytest.raises(ValueError, match="masks must be"):
        inputs.estimate_lattice_channels(masks[0], SCENE.pixel_size, SCENE.depth, SCENE.sigma)


def test_supersampled_masks_measure_coverage():
    disk = Mould(box=10.0, polygon=Point(5.0, 5.0).buffer(3.0, 256), tethers=np.array([[5.0, 5.0, 0.7]]),
                 seed=0, mould_id=0, symmetry="none", order=1, removal="none")
    binary = input_channels(disk, 20)
    assert binary.dtype == np.uint8 and set(np.unique(binary)) <= {0, 1}
    np.testing.assert_array_equal(input_channels(disk, 20, 1), binary)
    coverage = input_channels(disk, 20, 16)
    pixel_area = (10.0 / 20) ** 2
    assert coverage[1].sum() * pixel_area == pytest.approx(np.pi * 0.7 ** 2, rel=0.02)
    assert coverage[0].sum() * pixel_area == pytest.approx(disk.polygon.area - np.pi * 0.7 ** 2,
                                                           rel=0.01)
    with pytest.raises(ValueError, match="supersample"):
        input_channels(disk, 20, 0)


@pytest.mark.parametrize("kind", ["lattice", "both"])
def test_a_lattice_model_reads_the_lattice_variable(tmp_path, kind):
    ds = synthetic_dataset(8, 32)
    ds.attrs["scene"] = {"box": 15.625, "depth": 2.0}
    cfg = TrainConfig(model="unet", head="physics", loss="gaussian", inputs=kind,
                      unet=UNetConfig.for_size(32, base=8, upsample="bilinear"), epochs=1,
                      batch_size=4, lr=2e-3)
    path = tmp_path / "lat.pt"
    train(ds, cfg, path, log=lambda _: None)
    predictor = Predictor(path)
    assert predictor.needs_lattice
    assert predictor.model.cfg.in_channels == (2 if kind == "lattice" else 4)
    test = usable_samples(ds, "test")
    masks = ds["inputs"].values[test]
    lattice = ds["lattice"].values[test]
    exact = predictor(masks, n_cells=100.0, lattice=lattice)
    # the network reads the lattice: other lattice channels give another prediction
    other = predictor(masks, n_cells=100.0, lattice=lattice * 0.5)
    assert not np.allclose(exact.raw, other.raw)
    with pytest.warns(UserWarning, match="estimating them from the mask pixels"):
        predictor(masks, n_cells=100.0)
    with pytest.raises(DataError, match="no 'lattice' variable"):
        train(ds.drop_vars("lattice"), cfg, tmp_path / "none.pt", log=lambda _: None)
    with pytest.raises(ValueError, match="inputs 'pixels' is not one of"):
        TrainConfig(model="unet", head="physics", loss="gaussian", inputs="pixels")
