"""The data: moulds (generated and drawn), seeds, fields, inputs, the Zarr store and its reader (docs/architecture.md)."""
