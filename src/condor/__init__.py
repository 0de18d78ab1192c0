"""condor: dataset factory and surrogate for cell-laden hydrogels in tethered moulds.

The library is pure: it never imports Snakemake. docs/architecture.md shows the floors and
what each module owns. For the dataset: `condor.open_dataset(path)`,
`condor.torch_dataset(ds, split)` and `condor.score(predictions, ds)` (`condor.dataset`, the
module condor.data.dataset; condor.studies.accuracy).
"""

from condor.version import __version__

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
