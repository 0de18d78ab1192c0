"""Mould design: objectives on the fields, a parametric mould family, a CMA-ES search scored by
the surrogate, and confirmation by simulation. See docs/design.md.

    objective = parse_objective("alignment:x", pixels=predictor.native)
    space = default_space(scene, objective)
    result = search_designs(objective, space, predictor, budget, seed=0)
    confirmation = confirm_designs(result, scene, n_top, n_random, replicas, baseline=...)

The numbers (budget, n_top, ...) have one home: the workflow config's `design:` defaults
(the packaged schema), which the workflow and the CLI pass.
"""

# Each name from its module, imported on first use (PEP 562): `condor.design.objectives` alone
# (what a config check reads at every `snakemake` start) then costs no torch, cma or matplotlib.
_HOMES = {
    "Confirmation": "confirm",
    "SimulatedDesigns": "confirm",
    "agreement": "confirm",
    "baseline_objectives": "confirm",
    "confirm_designs": "confirm",
    "confirmation_table": "confirm",
    "dataset_baseline": "confirm",
    "design_summary": "confirm",
    "design_table": "confirm",
    "replica_ceiling": "confirm",
    "replica_seeds": "confirm",
    "select_for_confirmation": "confirm",
    "simulate_designs": "confirm",
    "spearman": "confirm",
    "EmptyRegionError": "objectives",
    "InfeasibleConstraintError": "objectives",
    "Objective": "objectives",
    "ObjectiveError": "objectives",
    "ObjectiveRegion": "objectives",
    "Quantity": "objectives",
    "UnknownObjectiveError": "objectives",
    "parse_objective": "objectives",
    "DesignPrediction": "search",
    "DesignSearchError": "search",
    "SearchResult": "search",
    "objective_spread": "search",
    "predict_designs": "search",
    "prediction_spread": "search",
    "search_designs": "search",
    "DesignSpace": "space",
    "constrained_space": "space",
    "default_space": "space",
    "symmetry_group": "space",
}


def __getattr__(name: str):
    if name in _HOMES:
        import importlib

        value = getattr(importlib.import_module(f"{__name__}.{_HOMES[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_HOMES))


__all__ = [
    "Confirmation", "SimulatedDesigns", "agreement", "baseline_objectives", "confirm_designs",
    "confirmation_table", "dataset_baseline", "design_summary", "design_table",
    "replica_ceiling",
    "replica_seeds", "select_for_confirmation", "simulate_designs", "spearman",
    "EmptyRegionError", "InfeasibleConstraintError", "Objective", "ObjectiveError", "Quantity",
    "ObjectiveRegion", "UnknownObjectiveError", "parse_objective", "DesignPrediction",
    "DesignSearchError", "SearchResult", "objective_spread", "predict_designs",
    "prediction_spread", "search_designs", "DesignSpace", "constrained_space", "default_space", "symmetry_group",
]
