"""ALIKED local features, written for our export path.

Zhao et al., "ALIKED: A Lighter Keypoint and Descriptor Extraction Network via Deformable
Transformation", IEEE TIM 2023.

The module layout (attribute names, nesting, channel counts) reproduces the published state dicts
(``aliked-n16.pth``, ``aliked-t16.pth`` in ``shared/models``) so that ``load_state_dict(strict=True)``
works. The network, for an RGB image in [0, 1] whose sides are multiples of 32:

- encoder: ``block1`` (two 3x3 conv + BN + SELU, full resolution) -> 2x2 average pool -> ``block2``
  (residual block, 1/2) -> 4x4 pool -> ``block3`` (residual block of *deformable* 3x3 convs, 1/8)
  -> 4x4 pool -> ``block4`` (deformable residual block, 1/32);
- aggregation: ``conv1``..``conv4`` (1x1, no bias) bring each level to ``dim / 4`` channels, SELU,
  bilinear upsampling (align corners) to full resolution, concatenation: the dense ``dim``-channel
  map ``x1234``;
- ``score_head`` (1x1 -> 3x3 -> 3x3 -> 3x3 convs with SELU between) + sigmoid: the keypoint score map;
  the descriptor map is ``x1234`` L2-normalised over channels;
- keypoints (DKD): local maxima of the score map (NMS radius 2, border of 2 px dropped), the
  strongest ``top_k``, each refined by a soft-argmax (temperature 0.1) over its 5x5 neighbourhood;
- ``desc_head`` (SDDH, sparse deformable descriptor head): per keypoint, a 3x3 conv + SELU + 1x1 conv
  on the 3x3 patch of the descriptor map at the (truncated) keypoint position predicts ``M`` (x, y)
  offsets; the map is sampled bilinearly at keypoint + offset, each sample goes through the 1x1
  ``sf_conv`` + SELU, and the ``M`` samples are aggregated by ``agg_weights`` (M, dim, dim) into one
  descriptor, L2-normalised.

Deformable convolution (as ``torchvision.ops.deform_conv2d`` with offsets but no modulation mask,
stride 1, padding 1): tap ``k = 3 i + j`` of the 3x3 kernel reads the input at
``(y + i - 1 + dy_k, x + j - 1 + dx_k)`` with offset channels ``2k = dy``, ``2k + 1 = dx``, bilinearly,
zero outside the map. Here it is nine ``grid_sample`` calls (align_corners=True, zeros padding, which
is exactly that sampling) and one 1x1 conv over the stacked samples: ops that export to ONNX (opset
>= 16) and run in onnxruntime, with no torchvision. All coordinate grids are derived from the tensors
(cumulative sums), so the exported graph accepts any input size (multiples of 32).

:class:`AlikedDense` is the exported graph: the encoder and the score head, returning the score map
and the four aggregated levels *before* upsampling (the full-resolution ``dim``-channel map is never
materialised: at 1024x768 it would be 400 MB). The score head's first 1x1 conv is applied per level
before upsampling, which is the same linear map (1x1 convs and bilinear upsampling commute). The
sparse steps (DKD, SDDH) run in numpy at run time (:mod:`geoloc.vision.aliked`); the PyTorch versions here
(:meth:`Aliked.detect`, :meth:`Aliked.describe`) are the reference they are tested against.

Only :mod:`geoloc.export.models` (export) and tests import this module.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from geoloc.vision.aliked import NMS_RADIUS, SOFTARGMAX_TEMPERATURE, padding_for


@dataclass(frozen=True)
class AlikedConfig:
    """Channel widths of the four levels, descriptor dimension, SDDH kernel size and sample count."""

    c1: int
    c2: int
    c3: int
    c4: int
    dim: int
    kernel: int
    n_samples: int


ALIKED_CONFIGS: dict[str, AlikedConfig] = {
    "aliked-t16": AlikedConfig(8, 16, 32, 64, 64, 3, 16),
    "aliked-n16": AlikedConfig(16, 32, 64, 128, 128, 3, 16),
}


def _pixel_grids(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, 1, H, W) column and row index maps of ``x``, built from the tensor (no Python ints: ONNX-dynamic)."""
    ones = torch.ones_like(x[:, :1])
    return ones.cumsum(3) - 1.0, ones.cumsum(2) - 1.0


class DeformConv3x3(nn.Module):
    """3x3 deformable convolution (stride 1, padding 1, no modulation), offsets from ``offset_conv``.

    Offsets are clamped to +-max(H, W) / 4 pixels, as in the reference network.
    """

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.offset_conv = nn.Conv2d(c_in, 18, 3, padding=1, bias=True)
        self.regular_conv = nn.Conv2d(c_in, c_out, 3, padding=1, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C_in, H, W) -> (B, C_out, H, W)."""
        offset = self.offset_conv(x)
        xs, ys = _pixel_grids(x)
        x_max, y_max = xs.amax(), ys.amax()  # W - 1, H - 1
        limit = (torch.maximum(x_max, y_max) + 1.0) / 4.0
        offset = torch.maximum(torch.minimum(offset, limit), -limit)
        samples = []
        for k in range(9):
            i, j = divmod(k, 3)
            px = xs + (j - 1) + offset[:, 2 * k + 1 : 2 * k + 2]
            py = ys + (i - 1) + offset[:, 2 * k : 2 * k + 1]
            grid = torch.cat([2.0 * px / x_max - 1.0, 2.0 * py / y_max - 1.0], dim=1).permute(0, 2, 3, 1)
            samples.append(F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=True))
        stacked = torch.cat(samples, dim=1)  # channel k * C + c
        w = self.regular_conv.weight  # (C_out, C, 3, 3) -> (C_out, 9 C) in tap-major order
        return F.conv2d(stacked, w.permute(0, 2, 3, 1).reshape(w.shape[0], -1, 1, 1))


def _conv3x3(c_in: int, c_out: int, deformable: bool) -> nn.Module:
    return DeformConv3x3(c_in, c_out) if deformable else nn.Conv2d(c_in, c_out, 3, padding=1, bias=False)


class ConvBlock(nn.Module):
    """Two 3x3 convs, each followed by BatchNorm and SELU (``block1``)."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C_in, H, W) -> (B, C_out, H, W)."""
        x = F.selu(self.bn1(self.conv1(x)))
        return F.selu(self.bn2(self.conv2(x)))


class ResBlock(nn.Module):
    """Residual block: conv-BN-SELU-conv-BN plus a 1x1 conv shortcut (with bias), then SELU."""

    def __init__(self, c_in: int, c_out: int, deformable: bool) -> None:
        super().__init__()
        self.conv1 = _conv3x3(c_in, c_out, deformable)
        self.bn1 = nn.BatchNorm2d(c_out)
        self.conv2 = _conv3x3(c_out, c_out, deformable)
        self.bn2 = nn.BatchNorm2d(c_out)
        self.downsample = nn.Conv2d(c_in, c_out, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C_in, H, W) -> (B, C_out, H, W)."""
        out = F.selu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return F.selu(out + self.downsample(x))


class SDDH(nn.Module):
    """Sparse deformable descriptor head: parameters only; :meth:`Aliked.describe` applies it."""

    def __init__(self, dim: int, kernel: int, n_samples: int) -> None:
        super().__init__()
        self.kernel = kernel
        self.n_samples = n_samples
        self.offset_conv = nn.Sequential(
            nn.Conv2d(dim, 2 * n_samples, kernel, padding=0, bias=True),
            nn.SELU(),
            nn.Conv2d(2 * n_samples, 2 * n_samples, 1, bias=True),
        )
        self.sf_conv = nn.Conv2d(dim, dim, 1, bias=False)
        self.agg_weights = nn.Parameter(torch.zeros(n_samples, dim, dim))


class Aliked(nn.Module):
    """The ALIKED network of one :class:`AlikedConfig` (see the module docstring)."""

    def __init__(self, config: AlikedConfig) -> None:
        super().__init__()
        c = config
        if c.c4 != c.dim:
            raise ValueError("the published configs have c4 == dim")
        self.config = c
        self.block1 = ConvBlock(3, c.c1)
        self.block2 = ResBlock(c.c1, c.c2, deformable=False)
        self.block3 = ResBlock(c.c2, c.c3, deformable=True)
        self.block4 = ResBlock(c.c3, c.c4, deformable=True)
        quarter = c.dim // 4
        self.conv1 = nn.Conv2d(c.c1, quarter, 1, bias=False)
        self.conv2 = nn.Conv2d(c.c2, quarter, 1, bias=False)
        self.conv3 = nn.Conv2d(c.c3, quarter, 1, bias=False)
        self.conv4 = nn.Conv2d(c.dim, quarter, 1, bias=False)
        self.score_head = nn.Sequential(
            nn.Conv2d(c.dim, 8, 1, bias=False),
            nn.SELU(),
            nn.Conv2d(8, 4, 3, padding=1, bias=False),
            nn.SELU(),
            nn.Conv2d(4, 4, 3, padding=1, bias=False),
            nn.SELU(),
            nn.Conv2d(4, 1, 3, padding=1, bias=False),
        )
        self.desc_head = SDDH(c.dim, c.kernel, c.n_samples)

    # -- dense part -------------------------------------------------------------------------

    def levels(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Compute the aggregated levels (after conv1..4 and SELU) at 1, 1/2, 1/8, 1/32 of a [0, 1] image.

        The image is (B, 3, H, W) RGB.

        H and W must be multiples of 32.
        """
        x1 = self.block1(image)
        x2 = self.block2(F.avg_pool2d(x1, 2))
        x3 = self.block3(F.avg_pool2d(x2, 4))
        x4 = self.block4(F.avg_pool2d(x3, 4))
        return (
            F.selu(self.conv1(x1)),
            F.selu(self.conv2(x2)),
            F.selu(self.conv3(x3)),
            F.selu(self.conv4(x4)),
        )

    def dense(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Score map (B, 1, H, W) in (0, 1) and unit descriptor map (B, dim, H, W) of a [0, 1] RGB image.

        Any size: the image is padded to multiples of 32 (edge replicated, split evenly between the two
        sides, the extra pixel after) and the maps are cropped back.
        """
        h, w = image.shape[-2:]
        (top, bottom), (left, right) = padding_for((h, w))
        padded = F.pad(image, (left, right, top, bottom), mode="replicate")
        f1, f2, f3, f4 = self.levels(padded)
        up = [f1] + [
            F.interpolate(f, scale_factor=s, mode="bilinear", align_corners=True)
            for f, s in ((f2, 2), (f3, 8), (f4, 32))
        ]
        x1234 = torch.cat(up, dim=1)
        score = torch.sigmoid(self.score_head(x1234))
        features = F.normalize(x1234, p=2.0, dim=1)
        return score[..., top : top + h, left : left + w], features[..., top : top + h, left : left + w]

    # -- sparse part (reference for the numpy runtime) ---------------------------------------

    @staticmethod
    def detect(score: torch.Tensor, top_k: int, allowed: torch.Tensor | None = None) -> tuple[torch.Tensor, ...]:
        """Keypoints of one (H, W) score map: (N, 2) sub-pixel (x, y) pixel positions and (N,) scores.

        Local maxima (NMS radius 2, with the two-pass suppression of weaker maxima next to suppressed
        pixels) away from a 2-pixel border and inside ``allowed`` (bool (H, W), optional), the ``top_k``
        largest (positive) ones by score, strongest first; each refined by the soft-argmax of its 5x5
        neighbourhood, its score read bilinearly at the refined position.
        """
        r = NMS_RADIUS
        s = score[None, None]
        nms = _simple_nms(s, r)[0, 0]
        nms[:r, :] = 0
        nms[-r:, :] = 0
        nms[:, :r] = 0
        nms[:, -r:] = 0
        if allowed is not None:
            nms = torch.where(allowed, nms, torch.zeros_like(nms))
        values, flat = torch.topk(nms.reshape(-1), min(top_k, nms.numel()))
        flat = flat[values > 0]
        h, w = score.shape
        base = torch.stack([flat % w, flat // w], dim=1).to(score.dtype)
        patches = F.unfold(s, 2 * r + 1, padding=r)[0].t()[flat]  # (N, 25), row-major over the window
        d = torch.arange(-r, r + 1, dtype=score.dtype)
        grid = torch.stack([d.repeat(2 * r + 1), d.repeat_interleave(2 * r + 1)], dim=1)  # (dx, dy) per cell
        weights = torch.exp((patches - patches.max(dim=1, keepdim=True).values) / SOFTARGMAX_TEMPERATURE)
        xy = base + weights @ grid / weights.sum(dim=1, keepdim=True)
        scores = _sample(s[0], xy)[:, 0]
        return xy, scores

    def describe(self, features: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
        """(N, dim) unit descriptors of keypoints at (N, 2) pixel positions of a (dim, H, W) descriptor map."""
        head = self.desc_head
        c, h, w = features.shape
        n = len(xy)
        k = head.kernel
        ij = xy.long()  # truncated, as the reference (positions are non-negative)
        padded = F.pad(features, (k // 2, k // 2, k // 2, k // 2))
        rows = ij[:, 1, None, None] + torch.arange(k)[None, :, None]
        cols = ij[:, 0, None, None] + torch.arange(k)[None, None, :]
        patches = padded[:, rows, cols].permute(1, 0, 2, 3)  # (N, C, k, k)
        limit = max(h, w) / 4.0
        offsets = head.offset_conv(patches)[:, :, 0, 0].clamp(-limit, limit)  # (N, 2M): x offsets, then y
        offsets = offsets.view(n, 2, head.n_samples).permute(0, 2, 1)
        positions = (xy[:, None, :] + offsets).reshape(-1, 2)
        samples = _sample(features, positions).reshape(n, head.n_samples, c)  # (N, M, C)
        samples = F.selu(samples @ head.sf_conv.weight[:, :, 0, 0].t())
        descriptors = torch.einsum("nmc,mcd->nd", samples, head.agg_weights)
        return F.normalize(descriptors, p=2.0, dim=1)


def _simple_nms(scores: torch.Tensor, radius: int) -> torch.Tensor:
    """Scores kept only at local maxima of a (B, 1, H, W) map; maxima next to stronger ones are dropped."""

    def max_pool(x: torch.Tensor) -> torch.Tensor:
        return F.max_pool2d(x, 2 * radius + 1, stride=1, padding=radius)

    zeros = torch.zeros_like(scores)
    is_max = scores == max_pool(scores)
    for _ in range(2):
        suppressed = max_pool(is_max.float()) > 0
        rest = torch.where(suppressed, zeros, scores)
        is_max = is_max | ((rest == max_pool(rest)) & ~suppressed)
    return torch.where(is_max, scores, zeros)


def _sample(maps: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
    """(N, C) bilinear samples of (C, H, W) maps at (N, 2) pixel positions (zero outside the map)."""
    c, h, w = maps.shape
    scale = torch.tensor([2.0 / (w - 1), 2.0 / (h - 1)], dtype=maps.dtype)
    grid = (xy * scale - 1.0).view(1, 1, -1, 2)
    return F.grid_sample(maps[None], grid, mode="bilinear", padding_mode="zeros", align_corners=True)[0, :, 0].t()


class AlikedDense(nn.Module):
    """The exported graph: RGB image in 0..255 -> score map and the four aggregated levels.

    Input ``image`` (1, 3, H, W) float32 RGB 0..255, H and W multiples of 32 (pad first, see
    :func:`padding_for`). Outputs: ``score`` (1, 1, H, W) in (0, 1); ``level1`` (1, dim/4, H, W),
    ``level2`` (H/2, W/2), ``level3`` (H/8, W/8), ``level4`` (H/32, W/32): what :meth:`Aliked.dense`
    upsamples (bilinear, align corners) and concatenates into the descriptor map before normalising.
    """

    def __init__(self, net: Aliked) -> None:
        super().__init__()
        self.net = net

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """(1, 3, H, W) RGB 0..255 -> (score, level1, level2, level3, level4), see the class docstring."""
        levels = self.net.levels(image * (1.0 / 255.0))
        head = self.net.score_head
        # The head's first conv is 1x1 and linear: apply it per level, then upsample (8 channels, not dim).
        first = head[0]
        assert isinstance(first, nn.Conv2d)
        w0 = first.weight
        quarter = self.net.config.dim // 4
        parts = [F.conv2d(f, w0[:, i * quarter : (i + 1) * quarter]) for i, f in enumerate(levels)]
        s = parts[0]
        for part, factor in zip(parts[1:], (2, 8, 32), strict=True):
            s = s + F.interpolate(part, scale_factor=factor, mode="bilinear", align_corners=True)
        score = torch.sigmoid(head[6](head[5](head[4](head[3](head[2](head[1](s)))))))
        return (score, *levels)


def load_aliked(weights: Path, config: str) -> Aliked:
    """Build the network of ``config`` ("aliked-n16", "aliked-t16") and load its state dict strictly (eval mode)."""
    if config not in ALIKED_CONFIGS:
        raise ValueError(f"unknown ALIKED config {config!r}; known: {sorted(ALIKED_CONFIGS)}")
    net = Aliked(ALIKED_CONFIGS[config])
    state = torch.load(weights, map_location="cpu", weights_only=True)
    net.load_state_dict(state, strict=True)
    return net.eval()
