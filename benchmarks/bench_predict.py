"""How long a prediction takes a mould, and where the time goes (issue 32, item 2).

    python benchmarks/bench_predict.py results/models/unet.pt [--moulds 32] [--repeats 5]
    python benchmarks/bench_predict.py --random unet      # a preset's network, random weights
    python benchmarks/bench_predict.py ... --precision float32    # the network in float32
    (default: auto, the Predictor's: bfloat16 where the CPU has it natively)

On generated moulds of the checkpoint's scene (with --random: the preset's network at the
default scene, random weights: the time needs the architecture, not trained weights), per
mould (the median over repeats of the whole batch's time divided by its moulds):

- stress: the spring network's stress channels (condor.data.inputs.stress_channels), solved
  afresh, in one thread and in one a CPU (the default: the moulds solve in parallel threads);
- network forward: the network alone on the 8 planar transforms of each mould, as prediction
  runs it ("eval": condor.surrogate.networks.inference_copy, channels_last), at batch 1, the
  Predictor's default (PREDICT_BATCH) and 16;
- network + symmetrisation: condor.surrogate.predict.run_model on inputs prepared: the forward,
  then the outputs moved back, decoded and averaged (the difference is their cost);
- predict, new moulds: Predictor.__call__ end to end on moulds it has not seen (the stress
  solved), at the same batches;
- predict, again: the same moulds once more (their stress channels come from the cache,
  condor.data.inputs.STRESS_CACHE_SIZE).

Wall-clock times on a shared machine are rough: say what else ran (the load is printed).
torch uses 1 thread unless --threads says otherwise (the product uses torch's default: one a
core); the stress solves of a batch run in parallel threads, one a CPU, whatever --threads
says, each solve's BLAS on one thread (condor.data.inputs._one_blas_thread).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch


def _median_per_mould(fn, n_moulds: int, repeats: int) -> float:
    fn()  # warm-up (allocations, oneDNN's kernels)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) / n_moulds)
    return statistics.median(times)


def random_checkpoint(variant: str, path: Path) -> Path:
    """A checkpoint of preset `variant`'s network at the default scene with random weights."""
    from condor.model.scenes import get_scene
    from condor.surrogate.checkpoint import save_checkpoint
    from condor.surrogate.networks import UNetGenerator
    from condor.surrogate.physics import PhysicsHead
    from condor.surrogate.samples import FieldScaling
    from condor.surrogate.variants import preset, train_config

    scene = get_scene("default")
    cfg = train_config(preset(variant), scene.pixels)
    unet, _ = cfg.networks(scene.pixels)
    torch.manual_seed(0)
    model = UNetGenerator(unet)
    scaling = PhysicsHead(np.ones(8), 1.0).to_dict() if cfg.head == "physics" else \
        FieldScaling(-np.ones(8), np.ones(8)).to_dict()
    save_checkpoint({"generator": model.state_dict(), "generator_config": unet.to_dict(),
                     "scaling": scaling, "config": cfg.to_dict(),
                     "data": {"native_size": scene.pixels, "pixel_size": scene.pixel_size,
                              "depth": scene.depth, "sigma": scene.sigma}}, path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", nargs="?")
    parser.add_argument("--random", metavar="PRESET",
                        help="time this preset's network (condor.surrogate.variants.PRESETS) "
                             "with random weights at the default scene, instead of a checkpoint")
    parser.add_argument("--moulds", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=123)
    parser.add_argument("--precision", default="auto", choices=("auto", "float32", "bfloat16"),
                        help="the network's arithmetic (Predictor's precision; default: auto, "
                             "its default)")
    parser.add_argument("--symmetrise", action="store_true",
                        help="symmetrise as the default checkpoint does, whatever this one says")
    args = parser.parse_args()
    if (args.checkpoint is None) == (args.random is None):
        parser.error("give a checkpoint or --random PRESET (one of them)")
    torch.set_num_threads(args.threads)

    import condor.data.inputs as inputs_mod
    from condor.stages.predict import checkpoint_scene
    from condor.moulds.paper import MouldParams
    from condor.moulds.mould import input_channels
    from condor.stages.build import make_mould
    from condor.surrogate.samples import INPUT_VARIABLES, apply_symmetry
    from condor.surrogate.predict import PREDICT_BATCH, Predictor, run_model
    from condor.surrogate.inference import bfloat16_is_native, inference_model, run_network

    with tempfile.TemporaryDirectory() as tmp:
        path = args.checkpoint or random_checkpoint(args.random, Path(tmp) / f"{args.random}.pt")
        predictor = Predictor(path, device="cpu", symmetrise=True if args.symmetrise else None,
                              precision=args.precision)
    scene = checkpoint_scene(predictor)
    moulds = [make_mould(scene, args.seed, i, params=MouldParams()) for i in range(args.moulds)]
    masks = np.stack([input_channels(m, predictor.native) for m in moulds])
    extra = predictor.mould_arguments(moulds)
    what = f"preset {args.random!r}, random weights" if args.random else args.checkpoint
    print(f"{what}: scene {scene.name!r}, {predictor.native} px, inputs "
          f"{predictor.inputs_kind!r}, symmetrise {predictor.symmetrise}, mode {predictor.mode}, "
          f"precision {predictor.precision} (bfloat16 native: {bfloat16_is_native()}); "
          f"{args.moulds} moulds, {args.repeats} repeats, {args.threads} torch thread(s); "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")

    def clear():
        inputs_mod._STRESS_CACHE.clear()

    stress = [m for m in ("stress", "stress_tensor") if m in INPUT_VARIABLES[predictor.inputs_kind]]
    if stress:
        for threads in sorted({1, inputs_mod._cpus()}):
            def solve():
                clear()
                inputs_mod.stress_channels(masks, stress[0] == "stress_tensor", threads=threads)
            print(f"  stress solve, new moulds, {threads} thread(s): "
                  f"{1e3 * _median_per_mould(solve, args.moulds, args.repeats):7.2f} ms a mould")

    # the network alone, on inputs prepared once
    clear()
    by_variable = {"inputs": masks, "lattice": extra.get("lattice")}
    for name in stress:
        by_variable[name] = inputs_mod.stress_channels(masks, name == "stress_tensor")
    network_inputs = np.concatenate([np.asarray(by_variable[n], dtype=np.float32)
                                     for n in INPUT_VARIABLES[predictor.inputs_kind]], axis=1)
    x = torch.from_numpy(network_inputs)
    transforms = range(8) if predictor.symmetrise else range(1)
    network = inference_model(predictor.model, predictor.precision) \
        if predictor.mode == "eval" else predictor.model
    for batch in sorted({1, PREDICT_BATCH, 16}):
        def forward():
            with torch.inference_mode():
                for start in range(0, len(x), batch):
                    part = x[start:start + batch]
                    run_network(network, torch.cat([apply_symmetry(
                        k, inputs=part, input_kind=predictor.inputs_kind)[0] for k in transforms]))

        def symmetrised():
            run_model(predictor.model, predictor.scaling, network_inputs, predictor.mode, batch,
                      predictor.device, predictor.symmetrise, extra.get("n_cells"),
                      predictor.inputs_kind, predictor.precision)
        print(f"  network forward ({len(transforms)} transforms), batch {batch:2d}: "
              f"{1e3 * _median_per_mould(forward, args.moulds, args.repeats):7.2f} ms a mould")
        print(f"  network + symmetrisation, batch {batch:2d}:  "
              f"{1e3 * _median_per_mould(symmetrised, args.moulds, args.repeats):7.2f} ms a mould")

    for batch in sorted({1, PREDICT_BATCH, 16}):
        def fresh():
            clear()
            predictor(masks, batch_size=batch, **extra)

        def again():
            predictor(masks, batch_size=batch, **extra)
        print(f"  predict, new moulds, batch {batch:2d}:      {1e3 * _median_per_mould(fresh, args.moulds, args.repeats):7.2f} ms a mould")
        print(f"  predict, again (cached), batch {batch:2d}:  {1e3 * _median_per_mould(again, args.moulds, args.repeats):7.2f} ms a mould")


if __name__ == "__main__":
    main()
