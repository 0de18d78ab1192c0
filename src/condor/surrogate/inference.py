"""How the network runs at prediction: the device, the arithmetic (float32, or bfloat16 where
the CPU has it), the inference copy of a model (BatchNorm folded, channels_last), one run of
the network (`run_network`) and the one decoder of its output into physical fields and their
spread (`decode`)."""

from __future__ import annotations

import weakref

import numpy as np
import torch

from .modes import AUTO_PRECISION, PRECISIONS
from .networks import UNetGenerator, inference_copy


def default_device(device=None) -> torch.device:
    """`device` if given, else CUDA when present, else CPU. ValueError, one line, when
    `device` is not a torch device or this machine lacks it (a CUDA device without a GPU): torch
    would fail later with an AssertionError."""
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        chosen = torch.device(device)
    except (RuntimeError, TypeError) as err:
        raise ValueError(f"device {device!r} is not a torch device ({err})") from None
    if chosen.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r} asked for, but this machine has no CUDA device "
                         "(torch sees none): leave --device out, or pass --device cpu")
    if chosen.type == "cuda" and chosen.index is not None and \
            chosen.index >= torch.cuda.device_count():
        raise ValueError(f"device {device!r} asked for, but this machine has "
                         f"{torch.cuda.device_count()} CUDA device(s)")
    if chosen.type == "mps" and not torch.backends.mps.is_available():
        raise ValueError(f"device {device!r} asked for, but this machine has no MPS device")
    return chosen


# "eval" prediction's copies of the models it ran (inference_copy), each with the identity and
# version of every tensor of the model's state it was made from: a model trained or loaded
# since gets a new copy.
_INFERENCE_COPIES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def bfloat16_is_native() -> bool:
    """True when this CPU has bfloat16 arithmetic (oneDNN's check: AVX512-BF16 or AMX)."""
    try:
        return bool(torch.backends.mkldnn.is_available()
                    and torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def resolve_precision(precision: str) -> str:
    """`precision` as the network will run it: one of PRECISIONS ("auto": bfloat16 where
    bfloat16_is_native, else float32); anything else is refused by name."""
    if precision == AUTO_PRECISION:
        return "bfloat16" if bfloat16_is_native() else "float32"
    if precision not in PRECISIONS:
        raise ValueError(f"precision {precision!r} is not one of {(AUTO_PRECISION,) + PRECISIONS}")
    return precision


def inference_model(model: UNetGenerator, precision: str = "float32") -> UNetGenerator:
    """`model`'s inference_copy (BatchNorm folded, channels_last) in `precision`, made once per
    state of the model's weights."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision {precision!r} is not one of {PRECISIONS}")
    state = tuple((t.data_ptr(), t._version) for t in model.state_dict().values())
    held = _INFERENCE_COPIES.setdefault(model, {})
    if precision not in held or held[precision][0] != state:
        copy = inference_copy(model)
        held[precision] = (state, copy if precision == "float32" else copy.to(torch.bfloat16))
    return held[precision][1]


def run_network(model, x: torch.Tensor) -> torch.Tensor:
    """One run of the network on x (float32), in the memory order and the precision of its
    weights; float32 out."""
    first = next(model.parameters())
    x = x.to(first.dtype)
    if first.dim() == 4 and first.is_contiguous(memory_format=torch.channels_last) and \
            not first.is_contiguous():
        out = model(x.contiguous(memory_format=torch.channels_last))
    else:
        out = model(x.contiguous())
    return out if out.dtype == torch.float32 else out.float()


def decode(scaling, out: torch.Tensor, n_cells) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Physical fields and spread (None for a tanh head) of the network's output `out` (B, C,
    H, W), in out's dtype and on its device. `scaling`: the checkpoint's output map, a
    physics.PhysicsHead (`n_cells`: N_c per sample) or a samples.FieldScaling. The map is the
    same at every pixel but for the physics head's softmax over the grid, which does not depend
    on the pixels' order: an output may be decoded before or after its pixels move."""
    if getattr(scaling, "kind", None) == "physics":
        return scaling.decode(out, torch.tensor(np.asarray(n_cells), dtype=out.dtype,
                                                device=out.device))
    return scaling.unscale(out), None
