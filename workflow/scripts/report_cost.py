"""Cost per mould against error for every method on the same test moulds and reference
(condor.costchart): simulations from the sweep tables, surrogates and baselines here."""
import logging

import numpy as np
import pandas as pd

from condor import costchart
from condor.config import scene_of
from condor.moulds import input_channels
from condor.pipeline import load_moulds, setup_logging, store_path
from condor.store import open_dataset

setup_logging(snakemake.log[0])
scene = scene_of(snakemake.config)
sweep = pd.concat([pd.read_csv(p) for p in snakemake.input.tables], ignore_index=True)
refs = [np.load(p) for p in snakemake.input.references]
ids = [int(r["mould"]) for r in refs]
reference = np.stack([r["fields"] for r in refs])
moulds = {m.mould_id: m for path in snakemake.input.moulds for m in load_moulds(path)}
inputs = np.stack([input_channels(moulds[i], scene.pixels) for i in ids]).astype(np.float32)

rows = costchart.simulation_rows(sweep)
rows += costchart.surrogate_rows(dict(zip(snakemake.params.variants, snakemake.input.checkpoints)),
                                 inputs, reference, ids)
rows += costchart.baseline_rows(open_dataset(store_path(snakemake.config)), inputs, reference, ids)
pd.DataFrame(rows).to_csv(snakemake.output.per_mould, index=False)
table = costchart.cost_table(rows)
table.to_csv(snakemake.output.table, index=False)
costchart.chart(table, snakemake.output.chart,
                title=f"cost per mould against error, scene {scene.name!r}, {len(ids)} test moulds")
logging.getLogger("condor").info("\n" + table.to_string(index=False))
