"""condor: dataset factory and surrogate for cell-laden hydrogels in tethered moulds.

The library is pure: it never imports Snakemake. Modules, one per concept:
scenes (scene presets), moulds (mould generator), lattice/energy/anneal/minimise/simulate
(the CONDOR simulator), fields (rasterisation), store (the Zarr dataset), surrogate (PyTorch).
"""

__version__ = "0.1.0"
