"""condor: dataset factory and surrogate for cell-laden hydrogels in tethered moulds.

The library is pure: it never imports Snakemake. docs/architecture.md shows the floors and
what each module owns. For the dataset: `condor.open_dataset(path)`, `condor.torch_dataset(ds, split)` and
`condor.score(predictions, ds)` (condor.dataset, condor.studies.accuracy).
"""

__version__ = "0.1.0"


# What `import condor` offers (loaded on first use, so that `import condor` stays light).
_LAZY = {"open_dataset": "condor.dataset", "torch_dataset": "condor.dataset",
         "score": "condor.studies.accuracy", "dataset": None}


def __getattr__(name):
    # `condor.open_dataset` and `condor.dataset` without importing zarr/xarray on `import condor`.
    if name in _LAZY:
        import importlib

        if name == "dataset":
            return importlib.import_module("condor.dataset")
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'condor' has no attribute {name!r}")


def __dir__():
    return sorted(["__version__", *_LAZY])
