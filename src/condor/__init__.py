"""condor: dataset factory and surrogate for cell-laden hydrogels in tethered moulds.

The library is pure: it never imports Snakemake. docs/architecture.md shows the floors and
what each module owns. For the dataset: `condor.open_dataset(path)`,
`condor.torch_dataset(ds, split)` and `condor.score(predictions, ds)` (`condor.dataset`, the
module condor.data.dataset; condor.studies.accuracy).
"""

from condor.openmp import choose_wait
from condor.version import __version__

# How OpenMP's threads (torch's and numba's) wait for work: they spin briefly where the machine
# is idle and sleep where other processes want its cores (condor.openmp, docs/scale.md). It must
# be set before the OpenMP runtime loads, i.e. before torch or a parallel numba function:
# `import condor` first, or set OMP_WAIT_POLICY or GOMP_SPINCOUNT in the environment (kept).
choose_wait()

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
