"""The surrogate: pix2pix (the paper's) and right-sized U-Nets from mould inputs to the 8
fields, with training, evaluation, prediction and baselines. See docs/surrogate.md."""

from .baselines import MaskedMeanBaseline, MouldBlurBaseline
from .checkpoint import (CheckpointError, CheckpointMismatchError, CheckpointNotFoundError,
                         load_checkpoint)
from .samples import FieldScaling, compute_scaling, resample_fields, resample_masks, usable_samples
from .evaluate import (combine_summaries, evaluate, evaluate_baselines, evaluate_predictions,
                       pearson_r)
from .models import (PREDICTION_MODES, PatchConfig, PatchDiscriminator, UNetConfig, UNetGenerator,
                     count_parameters_like_paper, paper_discriminator, paper_generator,
                     set_prediction_mode)
from .predict import Prediction, Predictor, predict, read_mould_inputs, write_prediction
from .train import MODEL_KINDS, TrainConfig, train
from .variants import train_config, workflow_variants

__all__ = [
    "MaskedMeanBaseline", "MouldBlurBaseline", "CheckpointError", "CheckpointMismatchError",
    "CheckpointNotFoundError", "load_checkpoint", "FieldScaling", "compute_scaling",
    "resample_fields", "resample_masks", "usable_samples", "evaluate", "evaluate_predictions",
    "pearson_r", "PREDICTION_MODES", "PatchConfig", "PatchDiscriminator", "UNetConfig",
    "UNetGenerator", "count_parameters_like_paper", "paper_discriminator", "paper_generator",
    "set_prediction_mode", "Prediction", "Predictor", "predict",
    "MODEL_KINDS", "TrainConfig", "train", "combine_summaries", "evaluate_baselines",
    "read_mould_inputs", "write_prediction", "train_config", "workflow_variants",
]
