"""The mould gallery figure and the regime/removal frequency table."""
from condor.moulds import gallery, regime_table
from condor.pipeline import load_moulds, setup_logging

setup_logging(snakemake.log[0])
moulds = [m for path in snakemake.input for m in load_moulds(path)]
gallery(moulds[: snakemake.params.n], snakemake.output[0])
regime_table(moulds).to_csv(snakemake.output[1])
