"""Throughput of the design search: designs per minute, and where the time goes.

For the scene of the checkpoint (or --scene without one), prints medians over --repeats runs of
  * geometry: decoding a vector into a valid mould and rasterising it (ms per design);
  * a search with the analytic stand-in predictor (condor.design.analytic): the search's own
    cost without a network (designs per minute);
  * with --checkpoint: a search scored by the real surrogate, with and without test-time
    symmetrisation (the checkpoint's setting is what `condor design` uses), at the torch
    thread counts in --threads (designs per minute, and the predictor's share of the time);
  * with --simulate N: seconds per confirmation simulation of N designs (the simulator's
    default solver, condor.model.simulate.DEFAULT_SOLVER, as design confirmation uses).

    python benchmarks/bench_design.py --checkpoint model.pt --budget 600 --threads 1 2
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from condor.design import default_space, parse_objective, search_designs
from condor.design.analytic import AnalyticPredictor
from condor.moulds.mould import input_channels
from condor.model.scenes import PRESETS, get_scene


class TimedPredictor:
    """Wraps a predictor and sums the seconds spent in it."""

    def __init__(self, predictor):
        self.predictor, self.seconds = predictor, 0.0
        self.native, self.box = predictor.native, getattr(predictor, "box", None)

    def __call__(self, inputs):
        start = time.perf_counter()
        out = self.predictor(inputs)
        self.seconds += time.perf_counter() - start
        return out


def scene_for(predictor_box, pixels, name):
    if predictor_box is None:
        return get_scene(name)
    for scene in PRESETS.values():
        if abs(scene.box - predictor_box) < 1e-6 and scene.pixels == pixels:
            return scene
    raise SystemExit(f"no scene preset has a {predictor_box} l0 box at {pixels} px")


def time_search(objective, space, predictor, budget, repeats):
    """Medians of designs per wall minute, per CPU minute, and the predictor's share of the
    wall time."""
    rates, cpu_rates, shares = [], [], []
    for seed in range(repeats):
        timed = TimedPredictor(predictor)
        result = search_designs(objective, space, timed, budget=budget, seed=seed, progress=False)
        rates.append(result.designs_per_minute)
        cpu_rates.append(result.designs_per_cpu_minute)
        shares.append(timed.seconds / result.seconds)
    return statistics.median(rates), statistics.median(cpu_rates), statistics.median(shares)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default=None)
    parser.add_argument("--scene", default="default", help="without a checkpoint")
    parser.add_argument("--objective", default="alignment:x")
    parser.add_argument("--budget", type=int, default=600)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, nargs="+", default=[1])
    parser.add_argument("--simulate", type=int, default=0)
    args = parser.parse_args()

    predictor = None
    if args.checkpoint:
        from condor.surrogate.predict import Predictor

        predictor = Predictor(args.checkpoint)
    scene = scene_for(predictor.box if predictor else None,
                      predictor.native if predictor else None, args.scene)
    objective = parse_objective(args.objective, pixels=scene.pixels, max_extent=scene.max_extent)
    space = default_space(scene, objective)
    print(f"scene {scene.name} ({scene.box} l0, {scene.pixels} px), objective {objective.label}, "
          f"space {space.symmetry} dim {space.dim}, budget {args.budget}, medians of "
          f"{args.repeats}")

    rng = np.random.default_rng(0)
    vectors = space.random_vectors(rng, 300)
    start, cpu = time.perf_counter(), time.process_time()
    for x in vectors:
        input_channels(space.mould(x), scene.pixels)
    print(f"geometry (decode + validate + rasterise): "
          f"{(time.perf_counter() - start) / len(vectors) * 1e3:.2f} ms wall, "
          f"{(time.process_time() - cpu) / len(vectors) * 1e3:.2f} ms CPU per design")

    rate, cpu_rate, _ = time_search(objective, space, AnalyticPredictor(scene.pixels, scene.box),
                                    args.budget, args.repeats)
    print(f"search, analytic predictor: {rate:,.0f} designs/min wall, {cpu_rate:,.0f} per CPU min")

    if predictor is not None:
        import torch

        settings = sorted({bool(predictor.symmetrise), False}, reverse=True)
        for threads in args.threads:
            torch.set_num_threads(threads)
            for symmetrise in settings:
                predictor.symmetrise = symmetrise
                rate, cpu_rate, share = time_search(objective, space, predictor, args.budget,
                                                    args.repeats)
                print(f"search, surrogate (threads {threads}, symmetrise {symmetrise}): "
                      f"{rate:,.0f} designs/min wall, {cpu_rate:,.0f} per CPU min, "
                      f"{100 * share:.0f}% of the wall time in the predictor")

    if args.simulate:
        from condor.model.simulate import DEFAULT_SOLVER, simulate, warm_up

        warm_up()
        seconds, cpu = [], []
        for x in vectors[: args.simulate]:
            mould = space.mould(x)
            start, cpu_start = time.perf_counter(), time.process_time()
            simulate(mould.polygon, mould.tethers, scene.depth, seed=0)
            seconds.append(time.perf_counter() - start)
            cpu.append(time.process_time() - cpu_start)
        print(f"confirmation simulation ({DEFAULT_SOLVER}): "
              f"{statistics.median(seconds):.2f} s wall, "
              f"{statistics.median(cpu):.2f} s CPU per replica (median of {len(seconds)})")


if __name__ == "__main__":
    main()
