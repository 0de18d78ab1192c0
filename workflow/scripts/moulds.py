"""Generate one batch of moulds: geometry JSON + input channels in the store."""
from condor.pipeline import make_moulds, setup_logging, store_path

setup_logging(snakemake.log[0])
make_moulds(snakemake.config, snakemake.params.ids, snakemake.output[0], store=store_path(snakemake.config))
