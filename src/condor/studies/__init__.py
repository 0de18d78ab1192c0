"""Studies: tables that measure the simulator and the surrogate (no drawing, no files).

`recipes` holds the recipes every study shares (the long anneal, the reference ensemble);
`paper_reference` holds the paper's CONDOR as data (the shipped long anneals, in
src/condor/paper_reference/) and `fidelity` a method's distance to it; `sweep` runs
simulation methods on a mould; `accuracy` scores every method against the expected fields;
`convergence` measures what the scene's reductions change; `ladder` asks whether the fast
solver samples the paper's ensemble. The stages draw and write them.
"""
