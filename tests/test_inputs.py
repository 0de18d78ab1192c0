"""The lattice channels (condor.data.inputs): the simulation's own initial cells, counted against
build_lattice, in column units, exact under the box's mirrors; their estimate from masks; the
masks' sub-pixel coverage; and a surrogate that reads them."""

import numpy as np
import pytest
import shapely
from shapely.affinity import scale as shapely_scale
from shapely.geometry import Point, box

from condor.data import inputs
from condor.model.lattice import build_lattice, lattice_sites
from condor.moulds.mould import Mould, input_channels
from condor.moulds.paper import generate_mould
from condor.model.scenes import get_scene
from condor.surrogate.samples import DataError, model_inputs, usable_samples
from condor.surrogate.physics import estimate_n_cells
from condor.surrogate.predict import Predictor, run_model
from condor.surrogate.synthetic import synthetic_dataset
from condor.surrogate.train import TrainConfig, train
from condor.surrogate.networks import UNetConfig

SCENE = get_scene("default")


def _mould(mould_id=4, seed=2026):
    return generate_mould(seed, mould_id, SCENE)


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
    cfg = TrainConfig(network="unet", head="physics", loss="gaussian", inputs=kind,
                      unet=UNetConfig.for_size(32, base=8, upsample="bilinear"), epochs=1,
                      batch_size=4, lr=2e-3)
    path = tmp_path / "lat.pt"
    train(ds, cfg, path, log=lambda _: None)
    predictor = Predictor(path, precision="float32")  # compared with run_model's float32
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
        TrainConfig(network="unet", head="physics", loss="gaussian", inputs="pixels")


# --- the stress channels: a contracting spring network (inputs.spring_stress) -------------

def _masks(mould, tether):
    return np.stack([np.asarray(mould, dtype=np.uint8), np.asarray(tether, dtype=np.uint8)])


def test_a_strip_between_two_posts_carries_uniform_tension_along_it():
    """A one-pixel strip between two post pixels has only axial x bonds; with both ends held,
    no node moves and every bond is stretched by its full contraction |d| = 1: sigma_xx = 1
    (two half-bonds) on the strip's inside, sigma_yy = 0."""
    mould, tether = np.zeros((5, 9)), np.zeros((5, 9))
    mould[2, 1:8] = 1
    tether[2, [1, 7]] = 1
    stress = inputs.spring_stress(_masks(mould, tether))
    assert np.allclose(inputs.spring_displacement(_masks(mould, tether)), 0, atol=1e-7)
    assert np.allclose(stress[0, 2, 2:7], 1.0, atol=1e-7)
    assert np.allclose(stress[0, 2, [1, 7]], 0.5, atol=1e-7)  # one bond at each post
    assert np.allclose(stress[1], 0, atol=1e-7)
    assert np.all(stress[:, mould + tether == 0] == 0)


def test_without_posts_the_network_contracts_freely():
    mould = np.zeros((8, 8))
    mould[1:7, 2:6] = 1
    stress = inputs.spring_stress(_masks(mould, np.zeros((8, 8))))
    assert stress.shape == (2, 8, 8) and np.all(stress == 0)


def _energy(masks, u):
    """Brute force: sum over every bond of k/2 (n . (u_j - u_i) + |d|)^2, by loops."""
    domain = (masks[0] > 0) | (masks[1] > 0)
    total = 0.0
    H, W = domain.shape
    for y in range(H):
        for x in range(W):
            for (dy, dx), k in inputs.SPRING_BONDS:
                if not (0 <= y + dy < H and 0 <= x + dx < W):
                    continue
                if domain[y, x] and domain[y + dy, x + dx]:
                    length = np.hypot(dx, dy)
                    n = np.array([dx, dy]) / length
                    total += 0.5 * k * (n @ (u[y + dy, x + dx] - u[y, x]) + length) ** 2
    return total


def test_the_displacement_minimises_the_bond_energy():
    """The sparse solve is the network's equilibrium: the brute-force energy's gradient
    (central differences) vanishes on every free node and the energy rises along random
    directions that keep the posts fixed."""
    rng = np.random.default_rng(7)
    mould = np.zeros((7, 7))
    mould[1:6, 1:6] = 1
    mould[3, 6] = 1
    tether = np.zeros((7, 7))
    tether[1, 1] = tether[5, 4] = 1
    masks = _masks(mould, tether)
    u = inputs.spring_displacement(masks)
    free = (mould > 0) & (tether == 0)
    assert np.all(u[tether > 0] == 0) and np.abs(u[free]).max() > 0.05
    h = 1e-5
    for y, x in zip(*np.nonzero(free)):
        for a in range(2):
            up, down = u.copy(), u.copy()
            up[y, x, a] += h
            down[y, x, a] -= h
            assert abs(_energy(masks, up) - _energy(masks, down)) / (2 * h) < 1e-6
    e0 = _energy(masks, u)
    for _ in range(5):
        step = rng.normal(size=u.shape) * free[..., None] * 0.01
        assert _energy(masks, u + step) > e0


def _loop_system(masks):
    """The network's equilibrium system, assembled pixel by pixel with loops (independently
    of inputs.spring_displacement): the sparse Hessian K of the bond energy over the free
    pixels' (x, y) plus the 1e-9 ridge, f = -grad at u = 0, and the free pixels (y, x)."""
    import scipy.sparse as sparse

    domain, fixed = (masks[0] > 0) | (masks[1] > 0), masks[1] > 0
    free = domain & ~fixed
    number = {p: n for n, p in enumerate(zip(*np.nonzero(free)))}
    H, W = domain.shape
    entries, f = {}, np.zeros(2 * len(number))
    for y in range(H):
        for x in range(W):
            for (dy, dx), k in inputs.SPRING_BONDS:
                if not (0 <= y + dy < H and 0 <= x + dx < W and domain[y, x]
                        and domain[y + dy, x + dx]):
                    continue
                length = np.hypot(dx, dy)
                n = np.array([dx, dy]) / length
                ends = [number.get((y, x)), number.get((y + dy, x + dx))]
                for e, sign in zip(ends, (1.0, -1.0)):
                    if e is not None:
                        f[2 * e:2 * e + 2] += sign * k * length * n
                for e1, s1 in zip(ends, (1.0, -1.0)):
                    for e2, s2 in zip(ends, (1.0, -1.0)):
                        if e1 is None or e2 is None:
                            continue
                        for a in range(2):
                            for b in range(2):
                                key = (2 * e1 + a, 2 * e2 + b)
                                entries[key] = entries.get(key, 0.0) + s1 * s2 * k * n[a] * n[b]
    rows, cols = zip(*entries)
    K = sparse.csc_matrix((list(entries.values()), (rows, cols)), shape=(len(f), len(f)))
    return K + 1e-9 * sparse.identity(len(f), format="csc"), f, free


def _loop_stress(masks, u):
    """sigma_xx, sigma_yy, sigma_xy of displacements u (H, W, 2), by loops over the bonds."""
    domain = (masks[0] > 0) | (masks[1] > 0)
    H, W = domain.shape
    stress = np.zeros((3, H, W))
    for y in range(H):
        for x in range(W):
            for (dy, dx), k in inputs.SPRING_BONDS:
                if 0 <= y + dy < H and 0 <= x + dx < W and domain[y, x] and \
                        domain[y + dy, x + dx]:
                    length = np.hypot(dx, dy)
                    n = np.array([dx, dy]) / length
                    t = k * (n @ (u[y + dy, x + dx] - u[y, x]) + length)
                    for c, (a, b) in enumerate(((0, 0), (1, 1), (0, 1))):
                        stress[c, y, x] += 0.5 * t * n[a] * n[b] * length
                        stress[c, y + dy, x + dx] += 0.5 * t * n[a] * n[b] * length
    return stress


def test_the_banded_solve_agrees_with_a_dense_solve():
    """spring_displacement (a banded Cholesky over the free pixels numbered along the narrower
    direction) solves the loop-assembled system: against numpy's dense solve on small moulds,
    wide and tall; and the stress channels agree where the displacement is not determined
    by the springs alone: a pixel held by one diagonal bond (free to swing about it) and a
    piece no post holds (it contracts freely, so it carries no stress); the 1e-9 ridge sets
    those motions, which stretch no spring."""
    wide = np.zeros((2, 7, 12), np.uint8)
    wide[0, 1:6, 1:11] = 1
    wide[1, 3, 1] = wide[1, 2, 10] = 1
    hinged = wide.copy()
    hinged[0, 0, 0] = 1  # joined to the mould by one diagonal bond
    floating = np.zeros((2, 9, 9), np.uint8)
    floating[0, 1:4, 1:8] = floating[0, 6:8, 2:6] = 1  # a strip held by posts, an island free
    floating[1, 2, 1] = floating[1, 2, 7] = 1
    for masks in (wide, np.ascontiguousarray(wide.transpose(0, 2, 1)), hinged, floating):
        K, f, free = _loop_system(masks)
        expected = np.zeros(free.shape + (2,))
        expected[free] = np.linalg.solve(K.toarray(), f).reshape(-1, 2)
        u = inputs.spring_displacement(masks)
        assert np.all(u[~free] == 0)
        if masks.shape[1:] in ((7, 12), (12, 7)) and not masks[0, 0, 0]:
            np.testing.assert_allclose(u, expected, rtol=0, atol=1e-10 * np.abs(expected).max())
        reference = _loop_stress(masks, expected)
        np.testing.assert_allclose(inputs.spring_stress(masks, shear=True), reference, rtol=0,
                                   atol=1e-6 * np.abs(reference).max())
    stress = inputs.spring_stress(floating)
    assert np.abs(stress[:, 1:4]).max() > 0.5 and np.abs(stress[:, 6:8]).max() < 1e-6


def test_the_banded_solve_agrees_with_a_sparse_lu_solve_on_a_default_mould():
    """On a default mould (64 px; about 3,200 unknowns) the banded Cholesky solve equals
    SuperLU's solve of the loop-assembled system (what spring_displacement solved before) to
    round-off, and so do the stress channels the network reads (float32)."""
    import scipy.sparse.linalg as sparse_linalg

    for mould_id in (4, 6):
        masks = input_channels(_mould(mould_id), SCENE.pixels)
        K, f, free = _loop_system(masks)
        expected = sparse_linalg.spsolve(K, f).reshape(-1, 2)
        u = inputs.spring_displacement(masks)
        assert free.sum() > 1000
        np.testing.assert_allclose(u[free], expected, rtol=0, atol=1e-10 * np.abs(expected).max())


@pytest.mark.parametrize("k", range(1, 8))
def test_stress_channels_transform_as_the_augmentation_says(k):
    """For every planar symmetry g: the stress of the transformed mould is the transformed
    stress, with the mechanics kind's channel rule (the transpose swaps sigma_xx, sigma_yy);
    without the rule the transpose would be wrong."""
    from condor.surrogate.samples import apply_symmetry

    m = _mould(6)
    masks = input_channels(m, SCENE.pixels)
    lattice = np.zeros((2,) + masks.shape[1:], dtype=np.float32)
    stress = inputs.spring_stress(masks)
    x = np.concatenate([masks.astype(np.float32), lattice, stress])
    gx, _ = apply_symmetry(k, inputs=x, input_kind="mechanics")
    moved = gx[:2].astype(np.uint8)
    assert np.allclose(gx[4:], inputs.spring_stress(moved), atol=1e-4)
    if k & 1:  # a transpose: the plain rule (scalar channels) gets the stress wrong
        plain, _ = apply_symmetry(k, inputs=x, input_kind="both")
        assert not np.allclose(plain[4:], inputs.spring_stress(moved), atol=1e-2)


@pytest.mark.parametrize("k", range(1, 8))
def test_shear_stress_transforms_as_the_augmentation_says(k):
    """sigma_xy of the transformed mould is the transformed sigma_xy with mechanics_shear's
    rule: odd under each mirror, kept by the transpose (which swaps sigma_xx, sigma_yy); the
    mechanics rule alone (no sign) gets a mirror wrong."""
    from condor.surrogate.samples import apply_symmetry

    masks = input_channels(_mould(6), SCENE.pixels)
    lattice = np.zeros((2,) + masks.shape[1:], dtype=np.float32)
    stress = inputs.spring_stress(masks, shear=True)
    assert np.array_equal(stress[:2], inputs.spring_stress(masks))  # the same xx, yy
    assert np.abs(stress[2]).max() > 0.1 * np.abs(stress[:2]).max()  # a shear to get wrong
    x = np.concatenate([masks.astype(np.float32), lattice, stress])
    gx, _ = apply_symmetry(k, inputs=x, input_kind="mechanics_shear")
    moved = gx[:2].astype(np.uint8)
    assert np.allclose(gx[4:], inputs.spring_stress(moved, shear=True), atol=1e-4)
    if bool(k & 2) != bool(k & 4):  # one mirror (two cancel): without the sign, wrong
        unsigned, _ = apply_symmetry(k, inputs=x[:6], input_kind="mechanics")
        flipped = apply_symmetry(k, inputs=x[6:], input_kind="lattice")[0]
        assert not np.allclose(flipped, inputs.spring_stress(moved, shear=True)[2:], atol=1e-2)
        assert np.allclose(unsigned[4:], gx[4:6])


def test_stress_channels_solve_each_mould_once_and_check_shapes():
    masks = input_channels(_mould(6), SCENE.pixels)
    batch = np.stack([masks, masks[:, ::-1].copy(), masks])
    out = inputs.stress_channels(batch)
    assert np.array_equal(out[0], out[2]) and np.allclose(out[1], out[0][:, ::-1], atol=1e-5)
    with pytest.raises(ValueError, match=r"\(S, 2, H, W\)"):
        inputs.stress_channels(masks)
    with pytest.raises(ValueError, match=r"\(2, H, W\)"):
        inputs.spring_displacement(masks[:1])


@pytest.mark.parametrize("kind, channels", [("mechanics", 6), ("mechanics_shear", 7)])
def test_a_mechanics_model_reads_the_stress_of_its_masks(tmp_path, kind, channels):
    ds = synthetic_dataset(8, 32)
    ds.attrs["scene"] = {"box": 15.625, "depth": 2.0}
    cfg = TrainConfig(network="unet", head="physics", loss="gaussian", inputs=kind,
                      unet=UNetConfig.for_size(32, base=8, upsample="bilinear"), epochs=1,
                      batch_size=4, lr=2e-3, augment=True, symmetrise=True)
    path = tmp_path / "mech.pt"
    train(ds, cfg, path, log=lambda _: None)
    predictor = Predictor(path, precision="float32")  # compared with run_model's float32
    assert predictor.needs_lattice and predictor.model.cfg.in_channels == channels
    test = usable_samples(ds, "test")
    masks, lattice = ds["inputs"].values[test], ds["lattice"].values[test]
    prediction = predictor(masks, n_cells=100.0, lattice=lattice)
    assert np.allclose(prediction.raw[:, 0].sum(axis=(1, 2)), 100.0, rtol=1e-4)
    # training reads the masks, the lattice and the stress the masks give
    read = model_inputs(ds, test, kind)
    assert np.array_equal(read[:, :2], masks) and np.array_equal(read[:, 2:4], lattice)
    assert np.array_equal(read[:, 4:], inputs.stress_channels(masks, kind == "mechanics_shear"))
    # and prediction feeds the network those channels: the same as running it on them
    direct, _ = run_model(predictor.model, predictor.scaling, read, symmetrise=True,
                          n_cells=np.full(len(test), 100.0), inputs_kind=kind)
    assert np.allclose(direct, prediction.raw, atol=1e-6)
    # the 8 planar transforms run as one batch ("eval" mode) give what 8 runs give
    import torch

    from condor.surrogate.networks import prediction_mode
    from condor.surrogate.symmetrise import symmetrised, symmetrised_reference

    x = torch.from_numpy(np.ascontiguousarray(read, dtype=np.float32))
    cells = np.full(len(test), 100.0)
    with prediction_mode(predictor.model, "eval"), torch.no_grad():
        apart = symmetrised_reference(predictor.model, predictor.scaling, x, cells, kind)
        together = symmetrised(predictor.model, predictor.scaling, x, cells, kind, batched=True)
    for a, b in zip(apart, together):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)


def test_training_solves_each_split_once_whatever_the_epochs(tmp_path, monkeypatch):
    """The stress solve is not repeated per epoch: training preloads its moulds and the
    validation after every epoch reuses its inputs."""
    from condor.surrogate import samples as data

    calls = []
    solve = data.derived_channels
    monkeypatch.setattr(data, "derived_channels",
                        lambda m, name: calls.append(len(m)) or solve(m, name))
    ds = synthetic_dataset(8, 32)
    ds.attrs["scene"] = {"box": 15.625, "depth": 2.0}
    counts = []
    for epochs in (1, 3):
        calls.clear()
        cfg = TrainConfig(network="unet", head="physics", loss="gaussian", inputs="mechanics",
                          unet=UNetConfig.for_size(32, base=8, upsample="bilinear"),
                          epochs=epochs, batch_size=4, lr=2e-3)
        train(ds, cfg, tmp_path / f"e{epochs}.pt", log=lambda _: None)
        counts.append(list(calls))
    assert counts[0] == counts[1] and len(counts[0]) >= 2  # the training and the val split


def test_a_mould_s_stress_is_solved_once_and_cached(monkeypatch):
    """stress_channels keeps the moulds it solved (STRESS_CACHE_SIZE): a mould seen again is
    not solved again, and gets the same channels; the oldest is dropped first."""
    calls = []
    real = inputs.spring_stress
    monkeypatch.setattr(inputs, "spring_stress",
                        lambda masks, shear=False: calls.append(1) or real(masks, shear))
    monkeypatch.setattr(inputs, "STRESS_CACHE_SIZE", 2)
    monkeypatch.setattr(inputs, "_STRESS_CACHE", type(inputs._STRESS_CACHE)())
    masks = np.zeros((3, 2, 12, 12), np.uint8)
    for k in range(3):
        masks[k, 0, 2:10, 2:10 - k] = 1
        masks[k, 1, 5, 3] = masks[k, 1, 5, 7 - k] = 1
    first = inputs.stress_channels(masks[:2])
    again = inputs.stress_channels(masks[:2])
    assert len(calls) == 2 and np.array_equal(first, again)
    np.testing.assert_array_equal(first[1], real(masks[1]))
    inputs.stress_channels(masks[2:])  # a third mould: the first is dropped
    inputs.stress_channels(masks[:1])
    assert len(calls) == 4


def test_moulds_solved_in_parallel_threads_get_their_own_channels(monkeypatch):
    """stress_channels solves the moulds it has not seen in threads: each mould's channels are
    its own serial solve's, in the caller's order, duplicates solved once; and a call with more
    new moulds than the cache holds still returns every one of them."""
    monkeypatch.setattr(inputs, "_STRESS_CACHE", type(inputs._STRESS_CACHE)())
    monkeypatch.setattr(inputs, "STRESS_CACHE_SIZE", 2)
    moulds = [_mould(i) for i in (4, 6, 7, 9)]
    masks = np.stack([input_channels(m, SCENE.pixels) for m in moulds])
    order = [3, 0, 2, 0, 1, 3]
    out = inputs.stress_channels(masks[order], shear=True, threads=3)
    for s, m in enumerate(order):
        np.testing.assert_array_equal(out[s], inputs.spring_stress(masks[m], shear=True))
    assert len(inputs._STRESS_CACHE) == 2
    assert not np.allclose(out[0], out[1])  # distinct moulds, distinct channels
