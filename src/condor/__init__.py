"""condor: dataset factory and surrogate for cell-laden hydrogels in tethered moulds.

The library is pure: it never imports Snakemake. docs/architecture.md shows the floors and
what each module owns. For the dataset: `condor.open_dataset(path)` (`condor.dataset`, the
module condor.data.reader).
"""

from condor.version import __version__

__all__ = ["__version__", "dataset", "open_dataset"]


def __getattr__(name):
    # `condor.open_dataset` and `condor.dataset` without importing zarr/xarray on `import condor`.
    if name in ("open_dataset", "dataset"):
        import condor.data.reader as dataset

        return dataset if name == "dataset" else dataset.open_dataset
    raise AttributeError(f"module 'condor' has no attribute {name!r}")
