"""Image-to-image networks: the paper's pix2pix (U-Net generator + 70x70 PatchGAN) and a
configurable U-Net family for smaller scenes.

The paper's tables are TensorFlow's pix2pix tutorial model, layer for layer, so this module
follows TensorFlow where PyTorch defaults differ:
- convolutions: kernel 4, stride 2, 'same' padding, no bias except the last layer of each
  network; weights ~ N(0, 0.02);
- BatchNorm: eps 1e-3, running averages with decay 0.99, biased batch variance, and it accepts
  a single value per channel (the generator's 1x1 bottleneck at batch size 1, where PyTorch's
  own BatchNorm2d refuses to train);
- LeakyReLU slope 0.3 (Keras' default, which the tutorial uses; the pix2pix paper uses 0.2);
- three dropout layers (rate 0.5) in the decoder, after BatchNorm, before ReLU.

Prediction mode (BatchNorm and dropout at inference): reference pix2pix implementations call
the generator in training mode at test time (batch statistics, dropout on). Here it is a
parameter, `set_prediction_mode(model, mode)`, with three modes:
- "eval" (our default): running statistics, no dropout; deterministic, independent of batch;
- "batch_stats": BatchNorm uses the statistics of the batch, no dropout;
- "train": batch statistics and dropout, as the reference implementations predict.
"""

from __future__ import annotations

from contextlib import contextmanager

import torch
from torch import nn
from torch.nn import functional as F

from .modes import PREDICTION_MODES
# The networks' shapes (torch-free, condor.surrogate.settings), exported here too, as before
from .settings import (OUTPUT_ACTIVATIONS, PAPER_SIZE, UPSAMPLE_MODES,  # noqa: F401
                       PatchConfig, UNetConfig)

INIT_STD = 0.02


class TFBatchNorm2d(nn.BatchNorm2d):
    """BatchNorm as TensorFlow computes it: biased variance for the running estimate, and a
    batch of one value per channel normalises to beta instead of raising."""

    def __init__(self, channels: int, eps: float = 1e-3, decay: float = 0.99):
        super().__init__(channels, eps=eps, momentum=1.0 - decay)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training:
            return F.batch_norm(x, self.running_mean, self.running_var, self.weight, self.bias,
                                False, 0.0, self.eps)
        mean = x.mean(dim=(0, 2, 3))
        var = x.var(dim=(0, 2, 3), unbiased=False)
        with torch.no_grad():
            self.running_mean.lerp_(mean.detach(), self.momentum)
            self.running_var.lerp_(var.detach(), self.momentum)
            self.num_batches_tracked += 1
        scale = self.weight * torch.rsqrt(var + self.eps)
        shift = self.bias - mean * scale
        return x * scale[None, :, None, None] + shift[None, :, None, None]


def _down(c_in: int, c_out: int, norm: bool, slope: float) -> nn.Sequential:
    layers = [nn.Conv2d(c_in, c_out, 4, stride=2, padding=1, bias=False)]
    if norm:
        layers.append(TFBatchNorm2d(c_out))
    layers.append(nn.LeakyReLU(slope))
    return nn.Sequential(*layers)


def _upconv(c_in: int, c_out: int, mode: str, bias: bool) -> nn.Module:
    """2x upsampling convolution (see UNetConfig.upsample)."""
    if mode == "transpose":
        return nn.ConvTranspose2d(c_in, c_out, 4, stride=2, padding=1, bias=bias)
    conv = nn.Conv2d(c_in, c_out, 3, padding=1, bias=bias)
    if mode == "resize":
        return nn.Sequential(nn.Upsample(scale_factor=2, mode="nearest"), conv)
    # Linear maps commute with the (linear) resize, so convolving at the coarse level first
    # costs a quarter of the arithmetic of resize-then-convolve for the same kind of map.
    return nn.Sequential(conv, nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False))


def _up(c_in: int, c_out: int, dropout: float, mode: str = "transpose") -> nn.Sequential:
    layers = [_upconv(c_in, c_out, mode, bias=False), TFBatchNorm2d(c_out)]
    if dropout > 0:
        layers.append(nn.Dropout(dropout))
    layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class _Residual(nn.Module):
    """x + activation(BN(conv3x3(x))): depth within a level at its own resolution."""

    def __init__(self, channels: int, activation: nn.Module):
        super().__init__()
        self.body = nn.Sequential(nn.Conv2d(channels, channels, 3, padding=1, bias=False),
                                  TFBatchNorm2d(channels), activation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


def _with_blocks(block: nn.Sequential, channels: int, n: int, activation) -> nn.Sequential:
    return nn.Sequential(*block, *(_Residual(channels, activation()) for _ in range(n))) if n \
        else block


def _init_weights(model: nn.Module, generator: torch.Generator | None) -> None:
    """TensorFlow tutorial initialisation: kernels ~ N(0, 0.02), biases 0, BN gamma 1."""
    for m in model.modules():
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
            with torch.no_grad():
                m.weight.normal_(0.0, INIT_STD, generator=generator)
                if m.bias is not None:
                    m.bias.zero_()


class UNetGenerator(nn.Module):
    """U-Net generator: (B, in_channels, size, size) in [-1, 1] -> (B, out_channels, size,
    size), in (-1, 1) (output "tanh") or unbounded (output "linear")."""

    def __init__(self, cfg: UNetConfig = UNetConfig(), generator: torch.Generator | None = None):
        super().__init__()
        self.cfg = cfg
        widths = cfg.widths()
        leaky = lambda: nn.LeakyReLU(cfg.leaky_slope)  # noqa: E731
        self.down = nn.ModuleList(
            _with_blocks(_down(c_in, c_out, norm=i > 0, slope=cfg.leaky_slope), c_out,
                         cfg.blocks, leaky)
            for i, (c_in, c_out) in enumerate(zip([cfg.in_channels] + widths[:-1], widths)))
        # Decoder: from the bottleneck up to level 0; after the first block the input is the
        # previous output concatenated with the encoder skip of the same resolution.
        ups = []
        for k, level in enumerate(range(cfg.depth - 2, -1, -1)):
            c_in = widths[level + 1] * (1 if k == 0 else 2)
            ups.append(_with_blocks(_up(c_in, widths[level], cfg.dropout if k < cfg.n_dropout
                                        else 0.0, cfg.upsample), widths[level], cfg.blocks,
                                    nn.ReLU))
        self.up = nn.ModuleList(ups)
        last_in = widths[0] * (2 if cfg.depth > 1 else 1)
        self.last = _upconv(last_in, cfg.out_channels, cfg.upsample, bias=True)
        _init_weights(self, generator)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for block in self.down:
            x = block(x)
            skips.append(x)
        skips = skips[-2::-1]  # encoder outputs below the bottleneck, deepest first
        for block, skip in zip(self.up, skips):
            x = torch.cat([block(x), skip], dim=1)
        k = self.cfg.out_channels - self.cfg.detached_outputs
        if k < self.cfg.out_channels and torch.is_grad_enabled():
            x = torch.cat([self.last(x)[:, :k], self.last(x.detach())[:, k:]], dim=1)
        else:
            x = self.last(x)
        return torch.tanh(x) if self.cfg.output == "tanh" else x


class PatchDiscriminator(nn.Module):
    """PatchGAN: (inputs (B, c_in, S, S), image (B, c_img, S, S)) -> logits (B, 1, S', S')."""

    def __init__(self, cfg: PatchConfig = PatchConfig(), generator: torch.Generator | None = None):
        super().__init__()
        self.cfg = cfg
        widths = [min(cfg.base * 2 ** i, cfg.max_width) for i in range(cfg.n_down + 1)]
        self.down = nn.Sequential(*(
            _down(c_in, c_out, norm=i > 0, slope=cfg.leaky_slope)
            for i, (c_in, c_out) in enumerate(zip([cfg.in_channels] + widths[:-2], widths[:-1]))))
        self.head = nn.Sequential(
            nn.ZeroPad2d(1), nn.Conv2d(widths[-2], widths[-1], 4, stride=1, bias=False),
            TFBatchNorm2d(widths[-1]), nn.LeakyReLU(cfg.leaky_slope),
            nn.ZeroPad2d(1), nn.Conv2d(widths[-1], 1, 4, stride=1))
        _init_weights(self, generator)

    def forward(self, inputs: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
        return self.head(self.down(torch.cat([inputs, image], dim=1)))


def paper_generator(generator: torch.Generator | None = None) -> UNetGenerator:
    return UNetGenerator(UNetConfig.paper(), generator)


def paper_discriminator(generator: torch.Generator | None = None) -> PatchDiscriminator:
    return PatchDiscriminator(PatchConfig(), generator)


def count_parameters_like_paper(model: nn.Module) -> int:
    """Trainable parameters plus BatchNorm running mean and variance, as the paper's tables
    (Keras' summary) count them; the batch counter is not counted."""
    n = sum(p.numel() for p in model.parameters() if p.requires_grad)
    for m in model.modules():
        if isinstance(m, nn.modules.batchnorm._BatchNorm) and m.track_running_stats:
            n += m.running_mean.numel() + m.running_var.numel()
    return n


def set_prediction_mode(model: nn.Module, mode: str) -> nn.Module:
    """Put `model` in one of PREDICTION_MODES (see the module docstring); returns it."""
    if mode not in PREDICTION_MODES:
        raise ValueError(f"prediction mode {mode!r} is not one of {PREDICTION_MODES}")
    model.eval()
    if mode in ("batch_stats", "train"):
        for m in model.modules():
            if isinstance(m, nn.modules.batchnorm._BatchNorm):
                m.train()
    if mode == "train":
        for m in model.modules():
            if isinstance(m, nn.Dropout):
                m.train()
    return model


@contextmanager
def prediction_mode(model: nn.Module, mode: str):
    """Run `model` in `mode` for the block, then restore its training flags and its BatchNorm
    running statistics (which "batch_stats" and "train" would otherwise update)."""
    flags = {m: m.training for m in model.modules()}
    buffers = {k: v.clone() for k, v in model.named_buffers()}
    try:
        yield set_prediction_mode(model, mode)
    finally:
        for m, flag in flags.items():
            m.training = flag
        with torch.no_grad():
            for k, v in model.named_buffers():
                v.copy_(buffers[k])


def _fold_into(conv: nn.Module, bn: "TFBatchNorm2d") -> None:
    """conv's weights and bias times bn's eval-mode affine map (per output channel)."""
    scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
    shift = bn.bias - bn.running_mean * scale
    axis = 1 if isinstance(conv, nn.ConvTranspose2d) else 0  # the output channels' axis
    shape = [1] * conv.weight.dim()
    shape[axis] = -1
    conv.weight.mul_(scale.reshape(shape))
    bias = shift if conv.bias is None else conv.bias * scale + shift
    conv.bias = nn.Parameter(bias)


def _folded(seq: nn.Sequential) -> nn.Sequential:
    """seq with each TFBatchNorm2d that follows a convolution (alone, or in a resize step:
    Upsample then conv, or conv then a bilinear Upsample, which commutes with a per-channel
    affine map as its weights sum to 1) folded into it; other modules kept."""
    out = []
    for module in seq:
        previous = out[-1] if out else None
        if isinstance(module, TFBatchNorm2d) and previous is not None:
            convs = [m for m in (previous if isinstance(previous, nn.Sequential) else [previous])
                     if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d))]
            others = [m for m in (previous if isinstance(previous, nn.Sequential) else [])
                      if not isinstance(m, (nn.Conv2d, nn.ConvTranspose2d, nn.Upsample))]
            if len(convs) == 1 and not others:
                _fold_into(convs[0], module)
                continue
        if isinstance(module, nn.Sequential):
            module = _folded(module)
        elif isinstance(module, _Residual):
            module.body = _folded(module.body)
        out.append(module)
    return nn.Sequential(*out)


@torch.no_grad()
def inference_copy(model: UNetGenerator) -> UNetGenerator:
    """A copy of `model` for "eval" prediction on a CPU: every BatchNorm folded into the
    convolution before it (its running statistics and affine map scale that convolution's
    output channels and set its bias: the same map, rounded differently), dropout removed,
    weights in channels_last memory order (a channels_last input then runs oneDNN's
    convolutions and the bilinear resizes without layout copies). Same outputs as `model` in
    "eval" mode to float32 round-off (tested); never trained (no gradients)."""
    import copy

    folded = copy.deepcopy(model).eval()
    for blocks in (folded.down, folded.up):
        for k in range(len(blocks)):
            blocks[k] = _folded(nn.Sequential(*(m for m in blocks[k]
                                                if not isinstance(m, nn.Dropout))))
    for param in folded.parameters():
        param.requires_grad_(False)
    return folded.to(memory_format=torch.channels_last)


# --- losses, as the paper's Appendix writes them -------------------------------------------

def l1_loss(generated: torch.Tensor, label: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference over pixels and channels (the paper's L_L1)."""
    return (generated - label).abs().mean()


def sigmoid_cross_entropy(logits: torch.Tensor, target: float) -> torch.Tensor:
    """Per-pixel L_LSXE(X, Y) = (Y-1) log(1-sigmoid X) - Y log(sigmoid X), unreduced."""
    return F.binary_cross_entropy_with_logits(logits, torch.full_like(logits, target),
                                              reduction="none")


def discriminator_loss(real_logits: torch.Tensor, generated_logits: torch.Tensor) -> torch.Tensor:
    """L_disc = sum over patch pixels of LSXE(D^L, 1) + LSXE(D^G, 0), averaged over the batch
    (the paper's sum; with Adam its scale does not change the updates)."""
    per_pixel = sigmoid_cross_entropy(real_logits, 1.0) + sigmoid_cross_entropy(generated_logits, 0.0)
    return per_pixel.flatten(1).sum(1).mean()


def generator_loss(generated_logits: torch.Tensor, generated: torch.Tensor, label: torch.Tensor,
                   lam: float = 1000.0, adversarial_target: float = 1.0):
    """L_gen = lam * L_L1 + mean over patch pixels of LSXE(D^G, target).

    The paper writes the target as 0, which would reward the generator for looking fake; the
    TensorFlow pix2pix code the paper follows (and the pix2pix paper) uses 1, our default.
    Returns (total, l1, adversarial)."""
    l1 = l1_loss(generated, label)
    adversarial = sigmoid_cross_entropy(generated_logits, adversarial_target).mean()
    return lam * l1 + adversarial, l1, adversarial
