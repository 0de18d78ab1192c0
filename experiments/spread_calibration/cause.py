"""Why the statistics' drawn spreads are off: on the store's test moulds, per field the
replicas' standard deviation (ddof 1) over the map's, RMS over the tissue (median over
moulds), and per statistic the ratio s / spread (RMS over moulds) of the predicted spread
and of an oracle's: the same draws (spread_draws) of the replicas' own standard-deviation map
about their mean, which leaves the noise model (kernel-correlated Gaussian noise) as the only
error.

    python experiments/spread_calibration/cause.py --checkpoint results/models/unet.pt \
        --store results/dataset.zarr
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.data.fields import FIELD_NAMES, normalise  # noqa: E402
from condor.surrogate.answer import SPREAD_STATISTICS, mould_summary, statistics  # noqa: E402
from condor.surrogate.calibration import tissue_pixels  # noqa: E402
from condor.moulds.mould import input_channels  # noqa: E402

from run import OOD, test_moulds  # noqa: E402  (this folder's run.py)


def main(argv=None) -> None:
    from condor.design.search import prediction_spread
    from condor.model.scenes import get_scene

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--store", required=True)
    parser.add_argument("--scene", default="default")
    args = parser.parse_args(argv)
    predictor = OOD.scene_predictor(args.checkpoint, get_scene(args.scene))
    pixel, sigma_px = predictor.pixel_size, predictor.sigma / predictor.pixel_size
    rows = []
    for mould_id, mould, fields, n_cells, _ in test_moulds(args.store):
        inputs = input_channels(mould, predictor.native)
        prediction = predictor(inputs, **predictor.mould_arguments([mould]))
        spread = np.asarray(prediction_spread(prediction)).reshape(prediction.normalised.shape)
        tissue = tissue_pixels(inputs[None])[0]
        simulated = normalise(fields, np.full(len(fields), n_cells))
        sd = simulated.std(axis=0, ddof=1)
        row = {f"map_{name}": np.sqrt((sd[k][tissue] ** 2).mean() / (spread[k][tissue] ** 2).mean())
               for k, name in enumerate(FIELD_NAMES)}
        drawn = mould_summary(prediction.normalised, float(prediction.n_cells), pixel, spread,
                              tissue=tissue, sigma_px=sigma_px).set_index("statistic")
        oracle = mould_summary(simulated.mean(axis=0), n_cells, pixel, sd, tissue=tissue,
                               sigma_px=sigma_px).set_index("statistic")
        for name in SPREAD_STATISTICS:
            values = [statistics(f, n_cells, pixel)[name] for f in simulated]
            s = float(OOD._deviation(name, values, drawn.loc[name, "value"]).std(ddof=1))
            row[f"{name}_predicted"] = (s / drawn.loc[name, "spread"]) ** 2
            row[f"{name}_oracle"] = (s / oracle.loc[name, "spread"]) ** 2
        rows.append(row)
    table = pd.DataFrame(rows)
    print(f"{len(table)} test moulds; replica sd / map, RMS over the tissue (median over moulds):")
    print("  " + ", ".join(f"{n} {table[f'map_{n}'].median():.2f}" for n in FIELD_NAMES))
    print("s / spread, RMS over moulds: predicted map | the replicas' own map (the noise model)")
    for name in SPREAD_STATISTICS:
        print(f"  {name:<13} {np.sqrt(table[f'{name}_predicted'].mean()):.2f} | "
              f"{np.sqrt(table[f'{name}_oracle'].mean()):.2f}")


if __name__ == "__main__":
    main()
