"""The quality bars every verdict is read against, each written once: the studies' tables
(convergence, fidelity), the report's verdicts and the figures that draw them."""

# Two ensembles sample the same states, and a reduction of the scene is justified, when
# their distance (its upper bound, where an interval is known) is at most this fraction of
# one simulation's scatter (the replica noise).
SAME_STATES = 0.5
# A whole-mould statistic's bias (median of predicted / simulated - 1) worth naming.
MAX_BIAS = 0.01
# A whole-mould statistic's r that needs no comment: at least MIN_R, or within
# R_CEILING_SLACK of its ceiling (a perfect predictor's r against one simulation).
MIN_R = 0.98
R_CEILING_SLACK = 0.01
# The spread map's 90% intervals are calibrated when they hold between these shares of the
# replicas' pixels (the report's headline verdict).
CALIBRATED_90 = (0.85, 0.95)
