"""Inference time per mould: the paper's generator against right-sized U-Nets.

Prints, for each network and device (CPU; CUDA when present), the median seconds per mould at
batch 1 and in batches of --batch, and the speed-up over the paper's generator at batch 1.
Networks are untrained (timing does not depend on the weights); prediction mode "eval".

    python benchmarks/bench_surrogate.py [--repeats 5] [--batch 16] [--threads N]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from condor.surrogate.networks import UNetConfig, UNetGenerator, count_parameters_like_paper

VARIANTS = {
    "paper pix2pix 256px": UNetConfig.paper(),
    "unet 128px base32": UNetConfig.for_size(128, base=32),
    "unet 64px base32 (default scene)": UNetConfig.for_size(64, base=32),
    "unet 64px base16": UNetConfig.for_size(64, base=16),
    "unet 32px base16 (tiny scene)": UNetConfig.for_size(32, base=16),
}


def seconds_per_mould(model, size: int, batch: int, repeats: int, device) -> float:
    x = torch.rand(batch, 2, size, size, device=device).round()
    with torch.no_grad():
        model(x)  # warm-up (allocations, cuDNN autotuning)
        times = []
        for _ in range(repeats):
            if device.type == "cuda":
                torch.cuda.synchronize()
            t0 = time.perf_counter()
            model(x)
            if device.type == "cuda":
                torch.cuda.synchronize()
            times.append((time.perf_counter() - t0) / batch)
    return statistics.median(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    devices = [torch.device("cpu")] + ([torch.device("cuda")] if torch.cuda.is_available() else [])
    print(f"torch {torch.__version__}, CPU threads {torch.get_num_threads()}, "
          f"repeats {args.repeats} (medians)")
    for device in devices:
        print(f"\n== {device} ==")
        print(f"{'network':34s} {'params':>11s} {'s/mould b=1':>12s} {f's/mould b={args.batch}':>13s}"
              f" {'speed-up b=1':>13s}")
        reference = None
        for name, cfg in VARIANTS.items():
            model = UNetGenerator(cfg).to(device).eval()
            one = seconds_per_mould(model, cfg.size, 1, args.repeats, device)
            many = seconds_per_mould(model, cfg.size, args.batch, max(1, args.repeats // 2), device)
            reference = reference or one
            print(f"{name:34s} {count_parameters_like_paper(model):11,d} {one:12.5f} {many:13.5f}"
                  f" {reference / one:12.1f}x")


if __name__ == "__main__":
    main()
