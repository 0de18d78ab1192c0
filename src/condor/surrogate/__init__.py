"""The surrogate: pix2pix (the paper's) and right-sized U-Nets from mould inputs to the 8
fields (`networks`), their training (`train`, `variants`, `checkpoint`), prediction
(`predict`, `inference`, `symmetrise`, `pictures`, `prediction_zarr`), evaluation
(`evaluate`, `baselines`, `calibration`) and the answer to a user's mould (`answer`). Import
the modules themselves; the package re-exports nothing. See docs/surrogate.md."""
