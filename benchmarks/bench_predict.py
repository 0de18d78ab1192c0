"""How long a prediction takes a mould, and where the time goes (issue 32, item 2).

    python benchmarks/bench_predict.py results/models/unet.pt [--moulds 32] [--repeats 3]

On generated moulds of the checkpoint's scene, per mould (the median over repeats of the
whole batch's time divided by its moulds, and of each mould alone):

- stress: the spring network's stress channels (condor.data.inputs.spring_stress), solved afresh;
- network: the model with its test-time symmetrisation (8 planar transforms, run as one batch
  in "eval" mode), inputs prepared; with a symmetrising checkpoint (or --symmetrise), the
  symmetrisation of one mould as 8 network runs against one batch of 8;
- predict, new moulds: Predictor.__call__ end to end on moulds it has not seen (the stress
  solved), at batch 1 and at batch 16;
- predict, again: the same moulds once more (their stress channels come from the cache,
  condor.data.inputs.STRESS_CACHE_SIZE).

Wall-clock times on a shared machine are rough: say what else ran. torch uses 1 thread unless
--threads says otherwise.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch


def _median_per_mould(fn, n_moulds: int, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) / n_moulds)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--moulds", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=123)
    parser.add_argument("--symmetrise", action="store_true",
                        help="symmetrise as the default checkpoint does, whatever this one says")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    import condor.data.inputs as inputs_mod
    from condor.cli import _checkpoint_scene
    from condor.data.moulds import MouldParams, input_channels
    from condor.stages.dataset import make_mould
    from condor.surrogate.samples import INPUT_VARIABLES
    from condor.surrogate.predict import Predictor, run_model

    predictor = Predictor(args.checkpoint, device="cpu", symmetrise=True if args.symmetrise else None)
    scene = _checkpoint_scene(predictor)
    moulds = [make_mould(scene, args.seed, i, MouldParams()) for i in range(args.moulds)]
    masks = np.stack([input_channels(m, predictor.native) for m in moulds])
    extra = predictor.mould_arguments(moulds)
    print(f"{args.checkpoint}: scene {scene.name!r}, {predictor.native} px, inputs "
          f"{predictor.inputs_kind!r}, symmetrise {predictor.symmetrise}, mode {predictor.mode}; "
          f"{args.moulds} moulds, {args.repeats} repeats, {args.threads} torch thread(s)")

    def clear():
        inputs_mod._STRESS_CACHE.clear()

    stress = [m for m in ("stress", "stress_tensor") if m in INPUT_VARIABLES[predictor.inputs_kind]]
    if stress:
        def solve():
            clear()
            inputs_mod.stress_channels(masks, stress[0] == "stress_tensor")
        print(f"  stress solve, new moulds:        {1e3 * _median_per_mould(solve, args.moulds, args.repeats):7.2f} ms a mould")

    # the network alone, on inputs prepared once
    clear()
    by_variable = {"inputs": masks, "lattice": extra.get("lattice")}
    for name in stress:
        by_variable[name] = inputs_mod.stress_channels(masks, name == "stress_tensor")
    network_inputs = np.concatenate([np.asarray(by_variable[n], dtype=np.float32)
                                     for n in INPUT_VARIABLES[predictor.inputs_kind]], axis=1)
    for batch in (1, 16):
        def network():
            run_model(predictor.model, predictor.scaling, network_inputs, predictor.mode, batch,
                      predictor.device, predictor.symmetrise, extra.get("n_cells"),
                      predictor.inputs_kind)
        print(f"  network, batch {batch:2d}:               {1e3 * _median_per_mould(network, args.moulds, args.repeats):7.2f} ms a mould")

    if predictor.symmetrise and predictor.mode == "eval":
        from condor.surrogate.models import prediction_mode
        from condor.surrogate.predict import _symmetrised

        x = torch.from_numpy(np.ascontiguousarray(network_inputs, dtype=np.float32))
        for batched in (False, True):
            def symmetries():
                with prediction_mode(predictor.model, "eval"), torch.no_grad():
                    for k in range(len(x)):
                        _symmetrised(predictor.model, predictor.scaling, x[k:k + 1],
                                     extra.get("n_cells", np.ones(len(x)))[k:k + 1],
                                     predictor.inputs_kind, batched=batched)
            how = "one batch of 8" if batched else "8 runs of 1   "
            print(f"  symmetrisation, {how}:  {1e3 * _median_per_mould(symmetries, args.moulds, args.repeats):7.2f} ms a mould")

    for batch in (1, 16):
        def fresh():
            clear()
            predictor(masks, batch_size=batch, **extra)

        def again():
            predictor(masks, batch_size=batch, **extra)
        print(f"  predict, new moulds, batch {batch:2d}:   {1e3 * _median_per_mould(fresh, args.moulds, args.repeats):7.2f} ms a mould")
        predictor(masks, batch_size=batch, **extra)  # fills the cache
        print(f"  predict, again (cached), batch {batch:2d}: {1e3 * _median_per_mould(again, args.moulds, args.repeats):7.2f} ms a mould")


if __name__ == "__main__":
    main()
