"""condor: dataset factory and surrogate for cell-laden hydrogels in tethered moulds.

The library is pure: it never imports Snakemake. docs/architecture.md shows the floors and
what each module owns. For the dataset: `condor.open_dataset(path)`,
`condor.torch_dataset(ds, split)` and `condor.score(predictions, ds)` (`condor.dataset`, the
module condor.data.dataset; condor.studies.accuracy).
"""

import os

from condor.version import __version__

# OpenMP's threads (torch's and numba's) sleep while they wait for work instead of spinning, so
# that training, predicting and rasterising keep their speed beside other work: with one
# spinning competitor on 2 cores, a training step with 2 spinning threads took several times
# longer (benchmarks/bench_busy.py, docs/scale.md). It must be set before the OpenMP runtime
# loads, i.e. before torch or a parallel numba function: `import condor` first, or set it in
# the environment (a value there is kept).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__all__ = ["__version__", "dataset", "open_dataset", "torch_dataset", "score"]


# What `import condor` offers (loaded on first use, so that `import condor` stays light).
_LAZY = {"open_dataset": "condor.data.dataset", "torch_dataset": "condor.data.dataset",
         "score": "condor.studies.accuracy", "dataset": "condor.data.dataset"}


def __getattr__(name):
    # `condor.open_dataset` and `condor.dataset` without importing zarr/xarray on `import condor`.
    if name in _LAZY:
        import importlib

        module = importlib.import_module(_LAZY[name])
        return module if name == "dataset" else getattr(module, name)
    raise AttributeError(f"module 'condor' has no attribute {name!r}")


def __dir__():
    return sorted(["__version__", *_LAZY])
