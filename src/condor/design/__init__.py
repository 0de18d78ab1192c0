"""Mould design: objectives on the fields, a parametric mould family, a CMA-ES search scored by
the surrogate, and confirmation by simulation. See docs/design.md.

    objective = parse_objective("alignment:x", pixels=predictor.native)
    space = default_space(scene, objective)
    result = search_designs(objective, space, predictor, budget, seed=0)
    confirmation = confirm_designs(result, scene, n_top, n_random, replicas, baseline=...)

The numbers (budget, n_top, ...) have one home: the workflow config's `design:` defaults
(the packaged schema), which the workflow and the CLI pass.
"""

from .confirm import (Confirmation, SimulatedDesigns, agreement, baseline_objectives,
                      confirm_designs, confirmation_table, dataset_baseline, design_summary,
                      design_table, replica_ceiling, replica_seeds, select_for_confirmation,
                      simulate_designs, spearman)
from .objectives import (EmptyRegionError, InfeasibleConstraintError, Objective, ObjectiveError,
                         ObjectiveRegion, Quantity, UnknownObjectiveError, parse_objective)
from .search import (DesignPrediction, DesignSearchError, SearchResult, objective_spread,
                     predict_designs, prediction_spread, search_designs)
from .space import DesignSpace, constrained_space, default_space, symmetry_group

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
