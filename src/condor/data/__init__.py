"""The data: seeds, fields, the lattice and stress inputs, the Zarr store, its check and its
reader (docs/architecture.md). The moulds are the floor below (condor.moulds)."""
