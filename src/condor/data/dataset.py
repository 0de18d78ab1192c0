"""The dataset as a product, for whoever trains elsewhere: open it, select a split, normalise
it, feed it to PyTorch, and read its card.

    import condor
    ds = condor.open_dataset("results/dataset.zarr")     # xarray.Dataset, validated
    train = condor.dataset.select(ds, "train")           # ok samples, one per mould
    stats = condor.dataset.field_statistics(ds)          # per-field mean/std/min/max (train)
    loader = torch.utils.data.DataLoader(condor.dataset.torch_dataset(ds, "train"), batch_size=8)

Layout (docs/architecture.md, condor.data.store): `inputs` (sample, channel, y, x) 0/1
with channels mould, tether; `lattice` (sample, cell, y, x) float32, the mould's initial mobile
and fixed cells rasterised with the fields' kernel in units of a full FCC column
(condor.data.inputs: what the default surrogate reads); `fields` (sample, field, y, x) float32, the 8 un-normalised fields
P, T, Sx2, Sy2, Sz2, SxSy, SxSz, SySz; per-sample metadata; each mould's geometry, in l0 in the
frame of the x and y coordinates: `outline_x`, `outline_y` (sample, vertex; `outline_vertices` in
use, NaN-padded) and `tether_x`, `tether_y`, `tether_r` (sample, tether; `n_tethers` in use),
read back with `mould_geometry(ds, sample)` as a shapely Polygon and the tethers (n, 3); for
moulds simulated with several seeds, `fields_mean` and `fields_std` (replicated, field, y, x). A
`README.md` dataset card (`write_card`) sits beside the store.
"""

from __future__ import annotations

import datetime
import json
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from condor.version import __version__
from condor.data.fields import FIELD_NAMES, normalise
from condor.data.statistics import MOULD_STATISTICS, STATISTIC_UNITS, mould_summary_statistics
from condor.data.geometry_arrays import outline_polygon
from condor.data.store import FORMAT_VERSION, GEOMETRY_ARRAYS, SPLITS, StoreError, open_store
from condor.data.store_check import check_store

# What torch_dataset yields, per item (documented shapes: the card and the tests use them).
ITEM_SHAPES = "inputs (2, H, W) float32 0/1; fields (8, H, W) float32"


def open_dataset(path) -> xr.Dataset:
    """The dataset store at `path` as a lazily loaded xarray.Dataset (validated first)."""
    return open_store(path)


def usable_samples(ds: xr.Dataset, split: str | None = None, all_replicas: bool = False) -> np.ndarray:
    """Positions (along `sample`) of the ok samples of `split` (all splits when None): replica
    0 of each mould unless `all_replicas` (extra replicas are the test moulds' expected fields,
    not more moulds)."""
    if split is not None and split not in SPLITS:
        raise ValueError(f"split {split!r} is not one of {SPLITS}")
    keep = np.asarray(ds["status"].values).astype(str) == "ok"
    if split is not None:
        keep &= np.asarray(ds["split"].values).astype(str) == split
    if not all_replicas and "replica" in ds:
        keep &= np.asarray(ds["replica"].values) == 0
    return np.flatnonzero(keep)


def select(ds: xr.Dataset, split: str | None = None, all_replicas: bool = False) -> xr.Dataset:
    """The ok samples of `split` as a Dataset (see usable_samples)."""
    return ds.isel(sample=usable_samples(ds, split, all_replicas))


def per_cell(ds: xr.Dataset) -> xr.DataArray:
    """The paper's normalised fields: fields x N_p / N_c (pixels over cells), per sample."""
    n_pixels = ds.sizes["x"] * ds.sizes["y"]
    return ds["fields"] * (n_pixels / ds["n_cells"].astype("float64"))


def field_statistics(ds: xr.Dataset, split: str = "train", chunk: int = 64) -> pd.DataFrame:
    """Per field, over the ok samples of `split` and every pixel: mean, std, min, max (float64,
    read `chunk` samples at a time)."""
    sel = select(ds, split)
    if sel.sizes["sample"] == 0:
        raise ValueError(f"no ok sample in split {split!r}")
    n = 0
    total = np.zeros(len(FIELD_NAMES))
    squares = np.zeros(len(FIELD_NAMES))
    lo = np.full(len(FIELD_NAMES), np.inf)
    hi = np.full(len(FIELD_NAMES), -np.inf)
    for start in range(0, sel.sizes["sample"], chunk):
        f = sel["fields"].isel(sample=slice(start, start + chunk)).values.astype(np.float64)
        n += f.shape[0] * f.shape[2] * f.shape[3]
        total += f.sum(axis=(0, 2, 3))
        squares += (f * f).sum(axis=(0, 2, 3))
        lo = np.minimum(lo, f.min(axis=(0, 2, 3)))
        hi = np.maximum(hi, f.max(axis=(0, 2, 3)))
    mean = total / n
    std = np.sqrt(np.maximum(squares / n - mean ** 2, 0.0))
    return pd.DataFrame({"field": FIELD_NAMES, "mean": mean, "std": std, "min": lo, "max": hi})


def torch_dataset(ds: xr.Dataset, split: str = "train", standardise: pd.DataFrame | None = None,
                  lattice: bool = False, n_cells: bool = False, mould_id: bool = False,
                  expected: bool = False):
    """A torch.utils.data.Dataset over the ok samples of `split` (replica 0 of each mould).

    By default item k is (inputs (2, H, W) float32 0/1, fields (8, H, W) float32), fields
    standardised per field by a `field_statistics` table when given. Any option makes item k a
    dict with "inputs" and "fields" and, per option:

    - lattice: "lattice" (2, H, W) float32, the mould's initial mobile and fixed cells (what
      the default surrogate reads beside the masks; condor.data.inputs);
    - n_cells: "n_cells", a float64 scalar tensor: the mould's cell count N_c (the density's sum);
    - mould_id: "mould", an int64 scalar tensor;
    - expected: "fields_mean" and "fields_std" (8, H, W) float32, the expected fields and one
      simulation's spread about them (standardised like `fields`; the std scaled only), and
      "n_replicas" (int64; 0, and NaN fields, for a mould simulated once: only the test
      moulds have replicas).

    Samples are read lazily, one chunk each, so it serves stores larger than memory (use
    DataLoader workers for speed)."""
    import torch

    sel = select(ds, split)
    mean = std = None
    if standardise is not None:
        mean = standardise["mean"].to_numpy(np.float32)[:, None, None]
        std = np.where(standardise["std"] > 0, standardise["std"], 1.0).astype(np.float32)[:, None, None]
    as_dict = lattice or n_cells or mould_id or expected
    replicated = {}
    if expected and "replicated" in ds.coords:
        replicated = {int(m): i for i, m in enumerate(ds["replicated"].values)}
    shape = (ds.sizes["field"], ds.sizes["y"], ds.sizes["x"])

    class FieldsDataset(torch.utils.data.Dataset):
        def __len__(self):
            return sel.sizes["sample"]

        def __getitem__(self, k):
            item = sel.isel(sample=int(k))
            inputs = item["inputs"].values.astype(np.float32)
            fields = item["fields"].values.astype(np.float32)
            if mean is not None:
                fields = (fields - mean) / std
            if not as_dict:
                return torch.from_numpy(inputs), torch.from_numpy(fields)
            out = {"inputs": torch.from_numpy(inputs), "fields": torch.from_numpy(fields)}
            mould = int(item["mould"].values)
            if lattice:
                out["lattice"] = torch.from_numpy(item["lattice"].values.astype(np.float32))
            if n_cells:
                out["n_cells"] = torch.tensor(float(item["n_cells"].values), dtype=torch.float64)
            if mould_id:
                out["mould"] = torch.tensor(mould, dtype=torch.int64)
            if expected:
                where = replicated.get(mould)
                if where is None:
                    fm = fs = np.full(shape, np.nan, np.float32)
                    count = 0
                else:
                    fm = ds["fields_mean"].isel(replicated=where).values.astype(np.float32)
                    fs = ds["fields_std"].isel(replicated=where).values.astype(np.float32)
                    count = int(ds["n_replicas_ok"].isel(replicated=where).values)
                    if mean is not None:
                        fm, fs = (fm - mean) / std, fs / std
                out.update(fields_mean=torch.from_numpy(fm), fields_std=torch.from_numpy(fs),
                           n_replicas=torch.tensor(count, dtype=torch.int64))
            return out

    return FieldsDataset()


def mould_geometry(ds, index: int):
    """The geometry of sample `index`'s mould as it was simulated and rasterised: (a shapely
    Polygon, its outline with any holes; tethers (n, 3) float64: x, y, radius), in l0 in the
    frame of the x and y coordinates (box coordinates: from the box's left and lower edges).
    Exactly the generator's (condor.moulds.paper.generate_mould: `.polygon`, `.tethers`), to
    the last bit. `ds`: an open dataset or the store's path. Samples 0..n_moulds-1 are
    replica 0 of moulds 0..n_moulds-1, so a mould id is a sample too; every replica holds its
    mould's geometry. The inputs of it: condor.moulds.mould.input_channels(Mould(box=
    ds.attrs["scene"]["box"], polygon=polygon, tethers=tethers), pixels)."""
    if not isinstance(ds, xr.Dataset):
        ds = open_dataset(ds)
    missing = [name for name in GEOMETRY_ARRAYS if name not in ds]
    if missing:
        raise StoreError(f"the dataset holds no mould geometry (no {', '.join(missing)}): "
                         f"store format {ds.attrs.get('format_version')}, the geometry came "
                         f"with format 5; rebuild the store with this code (format "
                         f"{FORMAT_VERSION})")
    n = ds.sizes["sample"]
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < n:
        raise IndexError(f"sample {index!r} is not in the dataset (samples 0..{n - 1})")
    item = ds[[*GEOMETRY_ARRAYS, "n_tethers", "inputs_ready"]].isel(sample=int(index)).load()
    if int(item["inputs_ready"]) != 1 or int(item["outline_vertices"]) < 0:
        raise ValueError(f"sample {index}: its mould is not written yet (inputs_ready "
                         f"{int(item['inputs_ready'])})")
    polygon = outline_polygon(item["outline_x"].values, item["outline_y"].values,
                              int(item["outline_vertices"]))
    count = int(item["n_tethers"])
    tethers = np.column_stack([item[f"tether_{a}"].values[:count] for a in "xyr"]).astype(
        np.float64)
    return polygon, tethers


def replicated_moulds(ds, split: str = "test", min_ok: int = 2):
    """Each mould of `split` with at least `min_ok` ok replicas, in mould order: (mould id, its
    family, its geometry as `mould_geometry` gives it, the ok replicas' raw fields (R, 8, H, W)
    float64, N_c, every replica's status). `ds`: an open dataset or the store's path. A mould
    with fewer ok replicas is left out; the caller sees it by its id missing."""
    if not isinstance(ds, xr.Dataset):
        ds = open_dataset(ds)
    split_of = ds["split"].values.astype(str)
    status = ds["status"].values.astype(str)
    mould = ds["mould"].values
    family = ds["family"].values.astype(str) if "family" in ds else np.full(len(mould), "paper")
    for m in sorted(set(mould[split_of == split].tolist())):
        samples = np.flatnonzero(mould == m)
        ok = samples[status[samples] == "ok"]
        if len(ok) < min_ok:
            continue
        yield (int(m), str(family[samples[0]]), mould_geometry(ds, int(m)),
               ds["fields"].isel(sample=ok).values.astype(np.float64),
               float(ds["n_cells"].values[ok[0]]), list(status[samples]))


# --- the dataset card -----------------------------------------------------------------------

def expected_statistics(ds) -> pd.DataFrame | None:
    """condor's whole-mould statistics (MOULD_STATISTICS) of each replicated mould's expected
    fields (`fields_mean`, normalised by its N_c): per statistic, its unit, the number of
    moulds, and the median, smallest and largest; None when the store holds none."""
    if "fields_mean" not in ds or "replicated" not in ds.coords or not ds.sizes["replicated"]:
        return None
    pixel_size = float(ds.attrs["pixel_size"])
    rows = []
    for k, mould in enumerate(ds["replicated"].values):
        fields = ds["fields_mean"].isel(replicated=k).values.astype(np.float64)
        n_cells = float(ds["n_cells"].isel(sample=int(mould)).values)
        if np.isfinite(fields).all() and n_cells > 0:
            rows.append(mould_summary_statistics(normalise(fields, n_cells), n_cells,
                                                 pixel_size))
    if not rows:
        return None
    table = pd.DataFrame(rows)
    return pd.DataFrame([{"statistic": name, "unit": STATISTIC_UNITS[name], "moulds": len(table),
                          "median": float(table[name].median()), "min": float(table[name].min()),
                          "max": float(table[name].max())} for name in MOULD_STATISTICS])


def card(store, config: dict | None = None) -> str:
    """A dataset card (Markdown) generated from the store: scene and model parameters, counts
    per split and status, generation core-hours and hardware, code version and config,
    per-field statistics, how to load it."""
    ds = open_dataset(store)
    attrs = ds.attrs
    table = check_store(store)
    counts = table.assign(state=table["state"]).groupby(["split", "state"]).size().unstack(
        fill_value=0)
    seconds = ds["solver_seconds"].values.astype(np.float64)
    status = ds["status"].values.astype(str)
    hardware = pd.DataFrame({"hardware": ds["hardware"].values.astype(str),
                             "seconds": np.nan_to_num(seconds)})
    by_machine = hardware[status != ""].groupby("hardware")["seconds"].agg(["size", "sum"])
    stats = field_statistics(ds) if "train" in set(table["split"]) else None
    scene = attrs.get("scene", {})
    lines = [
        f"# condor dataset: scene {scene.get('name')!r}, {attrs['n_moulds']} moulds",
        "",
        f"Written by condor {__version__} on {datetime.date.today().isoformat()} from the store "
        f"`{Path(store).name}` (format {attrs['format_version']}, created by condor "
        f"{attrs.get('code_version')}). Every number below is read from the store.",
        "",
        "## What it is",
        "",
        "Cell-laden hydrogels in tethered moulds, simulated with the CONDOR contractile-network "
        "model (Andrews, Dickinson and Hague) and rasterised into 8 fields per mould: the "
        "input channels (mould, tether; 0/1), the lattice channels `lattice` (the initial "
        "mobile and fixed cells rasterised with the fields' kernel, in units of a full FCC "
        "column) and the fields P (density), T (tension), Sx2, Sy2, Sz2, SxSy, SxSz, SySz "
        "(orientation tensor), un-normalised pixel sums.",
        "",
        "Each mould's geometry, as simulated, in l0 in the frame of the x and y coordinates "
        "(box coordinates: from the box's left and lower edges): `outline_x`, `outline_y` "
        "(sample, vertex), the outline's exterior ring (closed) then each hole's after one NaN, "
        "`outline_vertices` of them in use; `tether_x`, `tether_y`, `tether_r` (sample, tether), "
        "the posts' centres and radii, `n_tethers` in use; NaN after. "
        "`condor.dataset.mould_geometry(ds, sample)` gives a shapely Polygon and the tethers "
        "(n, 3).",
        "",
        "## Scene and model",
        "",
        f"- box {scene.get('box')} l0, depth {scene.get('depth')} l0, {attrs['pixels']} x "
        f"{attrs['pixels']} px of {attrs.get('pixel_size')} l0, kernel sigma {attrs.get('sigma')} l0",
        f"- model: {json.dumps(attrs.get('model'))}",
        f"- solver: {attrs.get('solver')} (budget {attrs.get('solver_budget')}); global seed "
        f"{attrs['seed']}; replicas per mould by split: "
        f"{json.dumps(attrs.get('data_config', {}).get('replicas'))}",
        "",
        "## Moulds and simulations",
        "",
        f"{attrs['n_moulds']} moulds, {len(table)} simulations "
        f"({int((status == 'ok').sum())} ok): a test mould is simulated several times "
        "(replicas, for its expected fields), the others once. Per split:",
        "",
        _markdown(_split_counts(ds, table)),
        "",
        "Simulations per split and state:",
        "",
        _markdown(counts.reset_index()),
        "",
        "A failed simulation keeps its reason in `status` and has no fields.",
        "",
        "## Cost and hardware",
        "",
        f"Generation: {np.nansum(seconds) / 3600:.3f} core-hours of solver CPU time over "
        f"{int((status != '').sum())} simulations (median {np.nanmedian(seconds):.2f} s each).",
        "",
        _markdown(by_machine.reset_index().rename(columns={"size": "simulations",
                                                           "sum": "CPU seconds"})),
        "",
    ]
    if stats is not None:
        lines += ["## Per-field statistics (train split, ok samples, every pixel)", "",
                  _markdown(stats), "",
                  "Also: `condor.dataset.field_statistics(ds)`.", ""]
    expected = expected_statistics(ds)
    if expected is not None:
        lines += ["## Whole-mould statistics of the replicated moulds' expected fields", "",
                  "Under the names `condor predict`, `condor simulate` and `condor.score` use "
                  "(condor.data.statistics.mould_summary_statistics; docs/fields.md defines each):",
                  "", _markdown(expected), ""]
    lines += [
        "## How to load it",
        "",
        "```python",
        "import condor, torch",
        f"ds = condor.open_dataset({str(Path(store).name)!r})  # xarray.Dataset",
        "train = condor.dataset.select(ds, 'train')          # ok samples, replica 0",
        "stats = condor.dataset.field_statistics(ds)",
        "loader = torch.utils.data.DataLoader(",
        "    condor.dataset.torch_dataset(ds, 'train', standardise=stats), batch_size=8)",
        f"# items: {ITEM_SHAPES}",
        "# or dicts with the lattice channels, N_c, the mould id and the expected fields:",
        "# condor.torch_dataset(ds, 'test', lattice=True, n_cells=True, mould_id=True, expected=True)",
        "# score predictions of the test moulds against the noise-corrected expected fields:",
        "# condor.score(raw_fields_of_the_replicated_moulds, ds)['accuracy']",
        "polygon, tethers = condor.dataset.mould_geometry(ds, 0)  # mould 0: outline, (n, 3) posts",
        "```",
        "",
        "Replicas: sample `s` holds replica `replica[s]` of mould `mould[s]`; samples 0..n-1 are "
        "replica 0 of moulds 0..n-1. `fields_mean` / `fields_std` along `replicated` are the "
        "expected fields and their spread. Every chunk carries a CRC32C checksum: "
        "`condor check-store --deep` verifies them.",
        "",
        "## Licence and citation",
        "",
        f"Licence: {LICENCE}",
        "",
        "Cite the model and the task as Andrews, Dickinson and Hague, \"Rapid prediction of "
        "lab-grown tissue properties using deep learning\", and this dataset as: condor "
        f"dataset, scene {scene.get('name')!r}, {attrs['n_moulds']} moulds, global seed "
        f"{attrs['seed']}, built by condor {attrs.get('code_version')} (store format "
        f"{attrs['format_version']}); the same configuration and seed rebuild it bit for bit.",
        "",
        "## Configuration",
        "",
        "```json",
        json.dumps(config if config is not None else attrs.get("data_config"), indent=1),
        "```",
        "",
    ]
    return "\n".join(lines)


# The dataset's licence as the card states it. The project has not chosen one yet (no licence
# in pyproject.toml or the repository): the card says so rather than invent one.
LICENCE = ("none chosen yet: the condor project states no licence for its code or data; ask "
           "its authors before redistributing")


def _split_counts(ds: xr.Dataset, table: pd.DataFrame) -> pd.DataFrame:
    """Per split: moulds, simulations, ok simulations, moulds with replicas."""
    split = np.asarray(ds["split"].values).astype(str)
    mould = np.asarray(ds["mould"].values)
    ok = np.asarray(ds["status"].values).astype(str) == "ok"
    rows = []
    for name in SPLITS:
        here = split == name
        if not here.any():
            continue
        per_mould = np.bincount(mould[here])
        rows.append({"split": name, "moulds": int(len(np.unique(mould[here]))),
                     "simulations": int(here.sum()), "ok simulations": int((here & ok).sum()),
                     "moulds with replicas": int((per_mould > 1).sum())})
    return pd.DataFrame(rows)


def write_card(store, out_md, config: dict | None = None) -> Path:
    out_md = Path(out_md)
    out_md.write_text(card(store, config))
    return out_md


def _markdown(frame: pd.DataFrame) -> str:
    def cell(v):
        return f"{v:.4g}" if isinstance(v, (float, np.floating)) else str(v)

    head = "| " + " | ".join(map(str, frame.columns)) + " |"
    rule = "| " + " | ".join("---" for _ in frame.columns) + " |"
    rows = ["| " + " | ".join(cell(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return "\n".join([head, rule, *rows])
