"""The paper's 256 px pix2pix against a right-sized U-Net, trained side by side on the same
data for an equal, modest budget; prints inference time per mould and test MAE, and their
ratios.

Budget: pix2pix trains `--paper-epochs` epochs on `--n-train` moulds (the paper's settings:
batch 1, Adam 2e-4, lambda 1000; the 64 px inputs and fields resampled to 256 px). The
right-sized variant (the embedded default config's first workflow variant) then trains,
epoch by epoch, until it has used the same process CPU seconds (CPU time, not wall time,
so that other jobs on a shared machine do not skew the budget; both run on --threads
threads). Its result after the same number of epochs is printed too.

Test moulds: the store's "test" split when it has at least --min-test usable ones, else the
last --min-test usable moulds not used for training (the benchmark says which).

    python experiments/surrogate/compare.py --store results/dataset.zarr \\
        [--n-train 48] [--paper-epochs 1] [--threads 2] [--repeats 9]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from condor.config import Config
from condor.data.dataset import open_dataset
from condor.surrogate.samples import usable_samples
from condor.surrogate.predict import Predictor
from condor.surrogate.train import TrainConfig, train
from condor.surrogate.variants import train_config, workflow_variants

REPO = Path(__file__).resolve().parents[2]


def benchmark_split(ds, n_train: int, min_test: int):
    """A copy of ds whose "train" split is the first n_train usable training moulds, and a
    test split of at least min_test moulds; other samples are left out ("unused")."""
    train_pos = usable_samples(ds, "train")
    test_pos = usable_samples(ds, "test")
    source = "store test split"
    if len(test_pos) < min_test:
        test_pos = train_pos[-min_test:]
        train_pos = train_pos[:-min_test]
        source = "held-back training moulds"
    train_pos = train_pos[:n_train]
    split = np.full(ds.sizes["sample"], "unused", dtype="<U8")
    split[train_pos], split[test_pos] = "train", "test"
    val = usable_samples(ds, "val")[:4]
    split[val] = "val"
    return ds.assign(split=("sample", split)), len(train_pos), len(test_pos), source


def cpu_seconds() -> float:
    return time.process_time()


def train_timed(ds, cfg: TrainConfig, path: Path, stop_after=None) -> tuple[float, float, list]:
    """Train (or continue) to cfg.epochs, or to `stop_after` of them; CPU and wall seconds of
    this call."""
    c0, w0 = cpu_seconds(), time.perf_counter()
    history = train(ds, cfg, path, log=lambda line: print("   ", line, flush=True),
                    stop_after=stop_after)
    return cpu_seconds() - c0, time.perf_counter() - w0, history


def predictor(path: Path) -> Predictor:
    """The checkpoint on the CPU in eval mode, one network run per mould (no test-time
    symmetrisation). A physics head takes each mould's cell count N_c (the store's n_cells)."""
    return Predictor(path, device="cpu", mode="eval", symmetrise=False)


def test_mae(path: Path, ds) -> float:
    pos = usable_samples(ds, "test")
    inputs = ds["inputs"].values[pos].astype(np.float32)
    pred = predictor(path)(inputs, n_cells=ds["n_cells"].values[pos]).raw
    return float(np.abs(pred.astype(np.float64) - ds["fields"].values[pos]).mean())


def seconds_per_mould(path: Path, inputs: np.ndarray, n_cells: np.ndarray,
                      repeats: int) -> tuple[float, float]:
    """Median wall and CPU seconds to predict one mould (batch 1, eval mode, resampling
    included)."""
    model = predictor(path)
    model(inputs[:1], n_cells=n_cells[:1])  # warm-up
    wall, cpu = [], []
    for r in range(repeats):
        k = r % len(inputs)
        c0, t0 = cpu_seconds(), time.perf_counter()
        model(inputs[k:k + 1], n_cells=n_cells[k:k + 1])
        wall.append(time.perf_counter() - t0)
        cpu.append(cpu_seconds() - c0)
    return statistics.median(wall), statistics.median(cpu)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--store", default="results/dataset.zarr")
    parser.add_argument("--n-train", type=int, default=48)
    parser.add_argument("--min-test", type=int, default=8)
    parser.add_argument("--paper-epochs", type=int, default=1)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--max-variant-epochs", type=int, default=400)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    ds, n_train, n_test, source = benchmark_split(open_dataset(args.store).load(), args.n_train,
                                                  args.min_test)
    native = int(ds.sizes["x"])
    config = Config.load(REPO / "config" / "config.yaml")
    name, settings = next(iter(workflow_variants(config).items()))
    print(f"store {args.store}: {native} px, {n_train} training moulds, {n_test} test moulds "
          f"({source}); torch {torch.__version__}, {args.threads} threads")
    work = Path(tempfile.mkdtemp(prefix="bench_compare_"))

    paper_cfg = TrainConfig(network="pix2pix", epochs=args.paper_epochs, num_threads=args.threads,
                            val_every=10 ** 6)
    print(f"pix2pix (paper, 256 px): {args.paper_epochs} epoch(s)")
    paper_cpu, paper_wall, _ = train_timed(ds, paper_cfg, work / "paper.pt")

    base_cfg = train_config({**settings, "num_threads": args.threads, "val_every": 10 ** 6}, native)
    print(f"{name} ({settings}): epochs until {paper_cpu:.0f} CPU s")
    variant_cpu = variant_wall = 0.0
    same_epochs_mae = None
    epochs = 0
    while variant_cpu < paper_cpu and epochs < args.max_variant_epochs:
        epochs += 1
        cfg = TrainConfig.from_dict({**base_cfg.to_dict(), "epochs": args.max_variant_epochs,
                                     "unet": base_cfg.unet})  # one run, continued epoch by epoch
        cpu, wall, _ = train_timed(ds, cfg, work / "variant.pt", stop_after=epochs)
        variant_cpu, variant_wall = variant_cpu + cpu, variant_wall + wall
        if epochs == args.paper_epochs:
            same_epochs_mae = test_mae(work / "variant.pt", ds)

    test = usable_samples(ds, "test")
    inputs = ds["inputs"].values[test].astype(np.float32)
    n_cells = ds["n_cells"].values[test]
    paper_mae, variant_mae = test_mae(work / "paper.pt", ds), test_mae(work / "variant.pt", ds)
    paper_s = seconds_per_mould(work / "paper.pt", inputs, n_cells, args.repeats)
    variant_s = seconds_per_mould(work / "variant.pt", inputs, n_cells, args.repeats)
    print(f"\n{'model':28s} {'epochs':>6s} {'train CPU s':>11s} {'train wall s':>12s} "
          f"{'test MAE':>9s} {'s/mould':>9s} {'CPU s/mould':>11s}")
    rows = (("pix2pix 256px (paper)", args.paper_epochs, paper_cpu, paper_wall, paper_mae, paper_s),
            (f"{name} {native}px", epochs, variant_cpu, variant_wall, variant_mae, variant_s))
    for label, n_epochs, cpu, wall, mae, (s_wall, s_cpu) in rows:
        print(f"{label:28s} {n_epochs:6d} {cpu:11.1f} {wall:12.1f} {mae:9.4f} {s_wall:9.4f} "
              f"{s_cpu:11.4f}")
    if same_epochs_mae is not None:
        print(f"{name} after {args.paper_epochs} epoch(s) (same samples seen): test MAE "
              f"{same_epochs_mae:.4f}")
    print(f"\ninference speed ratio (pix2pix / {name}, per mould): wall {paper_s[0] / variant_s[0]:.1f}x, "
          f"CPU {paper_s[1] / variant_s[1]:.1f}x")
    print(f"test MAE ratio at equal CPU budget (pix2pix / {name}): {paper_mae / variant_mae:.2f}")

if __name__ == "__main__":
    main()
