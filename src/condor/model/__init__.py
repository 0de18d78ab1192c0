"""The model: scenes, the FCC lattice and walls, the CONDOR energy, its solvers, one simulation (docs/architecture.md)."""
