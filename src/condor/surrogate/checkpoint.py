"""The training checkpoint: one dict (networks, optimisers, epoch, config, scaling, history),
written atomically, and the errors that name a missing or mismatched file."""

from __future__ import annotations

import io
from pathlib import Path

import torch

from condor.files import write_bytes

from .samples import FieldScaling
from .networks import PatchConfig, PatchDiscriminator, UNetConfig, UNetGenerator

FORMAT = "condor-surrogate/1"
# Training settings (TrainConfig) renamed since a checkpoint may have been written: the old
# key -> the name now. load_checkpoint reads an old checkpoint under the new names.
RENAMED_SETTINGS = {"model": "network"}


class CheckpointError(ValueError):
    """A checkpoint that cannot be used; the message names the file and the problem."""


class CheckpointNotFoundError(CheckpointError, FileNotFoundError):
    pass


class CheckpointMismatchError(CheckpointError):
    pass


def save_checkpoint(state: dict, path) -> None:
    """Write `state` to `path` whole or not at all (condor.files.write_bytes: a temporary file
    and a rename), so a reader (or a run killed mid-write) sees either the previous checkpoint
    or the new one. It is serialised in memory first: torch's file writer names neither the
    file nor, plainly, the cause of a failed write (disk full, a file-size limit), and Python's
    does (condor.files.WriteError)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    torch.save({"format": FORMAT, **state}, buffer)
    write_bytes(path, buffer.getbuffer())


def weights_sha256(state: dict) -> str:
    """sha256 (hex) of a loaded checkpoint's generator weights (names, dtypes, shapes, bytes):
    what identifies a trained network. The file's own bytes do not: its history records each
    epoch's wall-clock seconds, so two bit-identical trainings write different files."""
    import hashlib

    digest = hashlib.sha256()
    for name, tensor in sorted(state["generator"].items()):
        array = tensor.detach().cpu().contiguous().numpy()
        digest.update(f"{name}|{array.dtype}|{array.shape}|".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


# What a checkpoint's recipe leaves out: a machine's setting, and the data's bytes, which differ
# between machines that simulate the same moulds (their last bits), so two trainings of one
# recipe on two machines differ in weights but not in recipe.
NOT_RECIPE = {"config": ("num_threads",), "data": ("fingerprint",)}


def recipe_sha256(state: dict) -> str | None:
    """sha256 (hex) of what a checkpoint was trained to be: its training settings (but the
    thread count), its network's shape and its data's description (sizes, fields, inputs, the
    number of training samples; not the data's bytes). Two trainings of the default run on two
    machines share it and differ in weights_sha256. Another dataset of the same description
    shares it too: it names a recipe, not a dataset. None for a state that lacks one of the
    three (load_checkpoint refuses such a file; a network built in code has none)."""
    import hashlib
    import json

    if any(key not in state for key in ("config", "generator_config", "data")):
        return None

    described = {key: {k: v for k, v in dict(state[key]).items() if k not in NOT_RECIPE.get(key, ())}
                 for key in ("config", "generator_config", "data")}
    text = json.dumps(described, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def load_checkpoint(path, map_location="cpu") -> dict:
    """Read a checkpoint; CheckpointNotFoundError when absent, CheckpointError when it is not
    a condor surrogate checkpoint."""
    path = Path(path)
    if path.is_dir():
        found = sorted(p.name for p in path.glob("*.pt"))[:3]
        raise CheckpointNotFoundError(
            f"surrogate checkpoint {str(path)!r} is a folder, not a checkpoint file (.pt)"
            + (f": it holds {', '.join(found)}" if found else ""))
    if not path.is_file():
        raise CheckpointNotFoundError(f"surrogate checkpoint {str(path)!r} does not exist "
                                      "(train a model first)")
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as err:  # torch raises several types, with pages of advice, for any file
        if isinstance(err, OSError):  # unreadable (permissions), not foreign
            raise CheckpointError(f"cannot read surrogate checkpoint {str(path)!r}: "
                                  f"{err.strerror or err}") from err
        raise CheckpointError(f"{str(path)!r} is not a surrogate checkpoint written by `condor "
                              f"train` (or it is truncated): torch cannot load it "
                              f"({type(err).__name__})") from err
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise CheckpointError(f"{str(path)!r} is not a {FORMAT} checkpoint")
    missing = {"generator", "generator_config", "scaling", "data", "config"} - set(state)
    if missing:
        raise CheckpointError(f"checkpoint {str(path)!r} lacks {sorted(missing)}")
    for old, new in RENAMED_SETTINGS.items():
        if old in state["config"] and new not in state["config"]:
            state["config"][new] = state["config"].pop(old)
    return state


def _load_state(model: torch.nn.Module, state: dict, what: str, path) -> None:
    try:
        model.load_state_dict(state)
    except RuntimeError as err:
        raise CheckpointMismatchError(
            f"checkpoint {str(path)!r}: {what} weights do not match its config: {err}") from err


def generator_from_checkpoint(state: dict, path="<checkpoint>") -> UNetGenerator:
    """The generator described by a checkpoint's config, with its weights loaded."""
    try:
        cfg = UNetConfig(**state["generator_config"])
    except (TypeError, ValueError) as err:
        raise CheckpointMismatchError(f"checkpoint {str(path)!r}: bad generator config: {err}") from err
    model = UNetGenerator(cfg)
    _load_state(model, state["generator"], "generator", path)
    return model


def discriminator_from_checkpoint(state: dict, path="<checkpoint>") -> PatchDiscriminator | None:
    if state.get("discriminator") is None:
        return None
    model = PatchDiscriminator(PatchConfig(**state["patch_config"]))
    _load_state(model, state["discriminator"], "discriminator", path)
    return model


def scaling_from_checkpoint(state: dict, path="<checkpoint>"):
    """The checkpoint's output map: a FieldScaling (tanh head) or a physics.PhysicsHead."""
    from .physics import PhysicsHead

    d = state["scaling"]
    try:
        if isinstance(d, dict) and d.get("kind") == PhysicsHead.kind:
            return PhysicsHead.from_dict(d)
        return FieldScaling.from_dict(d)
    except (KeyError, TypeError, ValueError) as err:
        raise CheckpointMismatchError(f"checkpoint {str(path)!r}: bad output scaling: {err}") from err
