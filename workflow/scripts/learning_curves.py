"""The surrogate's learning curves (measured by benchmarks/bench_surrogate_curves.py) as a figure."""
from condor.stages import start_job
from condor.stages.surrogate import learning_curves_figure

start_job(snakemake)
learning_curves_figure(dict(snakemake.input.items()), snakemake.output[0])
