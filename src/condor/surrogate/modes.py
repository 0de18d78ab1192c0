"""How a prediction may run, as a caller names it (torch is not imported here, so that the
command line's parser can offer the choices): the BatchNorm/dropout modes
(condor.surrogate.networks.set_prediction_mode) and the network's arithmetic
(condor.surrogate.inference.resolve_precision)."""

PREDICTION_MODES = ("eval", "batch_stats", "train")
# The arithmetic of "eval" prediction's network: float32 (the model's own), or bfloat16 (the
# inference copy's weights and activations; CPUs with native bfloat16 arithmetic, such as
# AVX512-BF16 or AMX, run it about twice as fast; measured on the default run's test moulds:
# docs/surrogate.md, "Prediction time").
PRECISIONS = ("float32", "bfloat16")
# Predictor's default: bfloat16 where the CPU has it natively (bfloat16_is_native), else
# float32. "auto" is resolved once, when the Predictor is made (Predictor.precision).
AUTO_PRECISION = "auto"
DEFAULT_PRECISION = AUTO_PRECISION
