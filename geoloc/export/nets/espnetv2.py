"""ESPNetv2 semantic segmentation network (Mehta et al., CVPR 2019), written for our export path.

The module layout (attribute names, nesting, channel counts) reproduces the published EdgeNets
``espnetv2_seg`` state dicts so that ``load_state_dict(strict=True)`` works for the Cityscapes
weights in ``shared/models`` (``espnetv2_s_{1.0,2.0}_city_*.pth``). The arithmetic is the same as
the reference; two things are added for ONNX export:

- ``static_ops``: adaptive average pooling with a non-integer size ratio (the pyramid pooling's
  1.5x and 0.1x branches) becomes gathers and a weighted sum with constant indices, which every
  ONNX runtime has. The graph then has a fixed input size.
- ``full_resolution=False``: return the decoder's logits at half the input size and leave the final
  2x upsampling to the caller (it is cheaper to upsample the few merged class maps).

Input: (N, 3, H, W) float32, RGB scaled to [0, 1] then normalised with the ImageNet mean/std
(``IMAGENET_MEAN``/``IMAGENET_STD``); H and W multiples of 16. Output: (N, 20, H, W) logits
(or H/2 x W/2), channels in Cityscapes trainId order, channel 19 = void.

This is the only module in the project that imports torch; only ``geoloc.export.models`` imports it.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

# Output channels per level for each width scale s (levels 1..5; level 5 is unused by segmentation).
CHANNELS: dict[float, tuple[int, ...]] = {
    0.5: (16, 32, 64, 128, 256),
    1.0: (32, 64, 128, 256, 512),
    1.5: (32, 96, 192, 384, 768),
    2.0: (32, 128, 256, 512, 1024),
}
N_BRANCHES = 4  # parallel dilated branches in every EESP unit
REINF_CHANNELS = 3  # channels of the input-image shortcut ("input reinforcement")
PYRAMID_SCALES = (2.0, 1.5, 1.0, 0.5, 0.1)
DILATION_FOR_KERNEL = {3: 1, 5: 2, 7: 3, 9: 4, 11: 5, 13: 6, 15: 7, 17: 8}


# --------------------------------------------------------------------------------------------
# Small conv blocks. Two naming styles exist in the published weights: the encoder's blocks keep
# ``conv``/``bn``/``act`` attributes, the decoder's wrap them in a Sequential (``cbr``/``br``).
# --------------------------------------------------------------------------------------------


class ConvBnAct(nn.Module):
    """Conv (no bias) -> BatchNorm -> PReLU, attributes ``conv``, ``bn``, ``act`` (encoder style)."""

    def __init__(self, c_in: int, c_out: int, k: int, stride: int = 1, groups: int = 1) -> None:
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, k, stride, (k - 1) // 2, bias=False, groups=groups)
        self.bn = nn.BatchNorm2d(c_out)
        self.act = nn.PReLU(c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, c_in, H, W) -> (N, c_out, H / stride, W / stride)."""
        out: torch.Tensor = self.act(self.bn(self.conv(x)))
        return out


class ConvBn(nn.Module):
    """Conv (no bias) -> BatchNorm, attributes ``conv``, ``bn``."""

    def __init__(self, c_in: int, c_out: int, k: int, stride: int = 1, groups: int = 1) -> None:
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, k, stride, (k - 1) // 2, bias=False, groups=groups)
        self.bn = nn.BatchNorm2d(c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, c_in, H, W) -> (N, c_out, H / stride, W / stride)."""
        out: torch.Tensor = self.bn(self.conv(x))
        return out


class BnAct(nn.Module):
    """BatchNorm -> PReLU, attributes ``bn``, ``act``."""

    def __init__(self, c: int) -> None:
        super().__init__()
        self.bn = nn.BatchNorm2d(c)
        self.act = nn.PReLU(c)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, c, H, W) -> same shape."""
        out: torch.Tensor = self.act(self.bn(x))
        return out


class DilatedDW(nn.Module):
    """Depth-wise 3x3 dilated conv (no bias), attribute ``conv``."""

    def __init__(self, c: int, stride: int, dilation: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(c, c, 3, stride, dilation, dilation=dilation, groups=c, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, c, H, W) -> (N, c, H / stride, W / stride)."""
        out: torch.Tensor = self.conv(x)
        return out


class SeqConvBnAct(nn.Module):
    """Conv (no bias) -> BatchNorm -> PReLU held in ``cbr`` (decoder style)."""

    def __init__(self, c_in: int, c_out: int, k: int, groups: int = 1) -> None:
        super().__init__()
        self.cbr = nn.Sequential(
            nn.Conv2d(c_in, c_out, k, 1, (k - 1) // 2, bias=False, groups=groups),
            nn.BatchNorm2d(c_out),
            nn.PReLU(c_out),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, c_in, H, W) -> (N, c_out, H, W)."""
        out: torch.Tensor = self.cbr(x)
        return out


class SeqBnAct(nn.Module):
    """BatchNorm -> PReLU held in ``br`` (decoder style)."""

    def __init__(self, c: int) -> None:
        super().__init__()
        self.br = nn.Sequential(nn.BatchNorm2d(c), nn.PReLU(c))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, c, H, W) -> same shape."""
        out: torch.Tensor = self.br(x)
        return out


class ChannelShuffle(nn.Module):
    """Interleave ``groups`` channel groups: (N, g*c, H, W) -> channel order c-major."""

    def __init__(self, groups: int) -> None:
        super().__init__()
        self.groups = groups

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, g*c, H, W) -> same shape, channels reordered."""
        n, c, h, w = x.shape
        x = x.reshape(n, self.groups, c // self.groups, h, w).transpose(1, 2)
        return x.reshape(n, c, h, w)


# --------------------------------------------------------------------------------------------
# Resampling helpers
# --------------------------------------------------------------------------------------------


def _resize(x: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Bilinear resize with aligned corners (as the reference) to ``size`` = (H, W)."""
    return F.interpolate(x, size=size, mode="bilinear", align_corners=True)


def _adaptive_pool_axis(x: torch.Tensor, out: int, axis: int) -> torch.Tensor:
    """Adaptive average pooling along one axis (2 or 3) with constant gathers, no loops at run time.

    Output bin i covers [floor(i n / out), ceil((i + 1) n / out)) of the n inputs, as PyTorch's
    adaptive pooling; a bin is the weighted sum of K gathered slices (K = longest bin).
    """
    n = x.shape[axis]
    if n == out:
        return x
    starts = [(i * n) // out for i in range(out)]
    ends = [-(-((i + 1) * n) // out) for i in range(out)]
    k_max = max(e - s for s, e in zip(starts, ends, strict=True))
    shape = [1, 1, 1, 1]
    shape[axis] = out
    result = None
    for k in range(k_max):
        index = torch.tensor([min(s + k, n - 1) for s in starts], dtype=torch.long)
        weight = torch.tensor(
            [1.0 / (e - s) if s + k < e else 0.0 for s, e in zip(starts, ends, strict=True)],
            dtype=x.dtype,
        ).reshape(shape)
        term = torch.index_select(x, axis, index) * weight
        result = term if result is None else result + term
    assert result is not None
    return result


def adaptive_avg_pool(x: torch.Tensor, size: tuple[int, int], static: bool) -> torch.Tensor:
    """``F.adaptive_avg_pool2d`` to ``size`` = (H, W); with ``static`` an ONNX-friendly equivalent.

    Integer size ratios become a plain AvgPool; other ratios use constant gathers per axis.
    """
    if not static:
        return F.adaptive_avg_pool2d(x, size)
    h, w = int(x.shape[2]), int(x.shape[3])
    if h % size[0] == 0 and w % size[1] == 0:
        kh, kw = h // size[0], w // size[1]
        return x if kh == kw == 1 else F.avg_pool2d(x, (kh, kw), (kh, kw))
    return _adaptive_pool_axis(_adaptive_pool_axis(x, size[0], 2), size[1], 3)


# --------------------------------------------------------------------------------------------
# Encoder (EESPNet without its level 5 and classifier)
# --------------------------------------------------------------------------------------------


class EESP(nn.Module):
    """Extremely Efficient Spatial Pyramid unit.

    Group 1x1 reduce, K dilated depth-wise branches fused hierarchically, group 1x1 expand; residual
    + PReLU when stride 1.

    With ``stride=2`` it returns the expanded map without residual/activation (the down-sampler
    merges it with an average-pooled copy of its input).
    """

    def __init__(self, c_in: int, c_out: int, stride: int, branches: int, r_lim: int) -> None:
        super().__init__()
        self.stride = stride
        n = c_out // branches
        if n * branches != c_out:
            raise ValueError(f"c_out={c_out} must be divisible by branches={branches}")
        self.proj_1x1 = ConvBnAct(c_in, n, 1, groups=branches)
        k_sizes = sorted(3 + 2 * i if 3 + 2 * i <= r_lim else 3 for i in range(branches))
        self.spp_dw = nn.ModuleList(DilatedDW(n, stride, DILATION_FOR_KERNEL[k]) for k in k_sizes)
        self.conv_1x1_exp = ConvBn(c_out, c_out, 1, groups=branches)
        self.br_after_cat = BnAct(c_out)
        self.module_act = nn.PReLU(c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, c_in, H, W) -> (N, c_out, H / stride, W / stride)."""
        reduced = self.proj_1x1(x)
        outs = [self.spp_dw[0](reduced)]
        for branch in list(self.spp_dw)[1:]:
            outs.append(branch(reduced) + outs[-1])
        expanded: torch.Tensor = self.conv_1x1_exp(self.br_after_cat(torch.cat(outs, 1)))
        if self.stride == 2:
            return expanded
        if expanded.shape == x.shape:
            expanded = expanded + x
        activated: torch.Tensor = self.module_act(expanded)
        return activated


class DownSampler(nn.Module):
    """Halve the resolution: [avg-pool(x), strided EESP(x)] concatenated.

    Plus a projection of the input image pooled to the same size (input reinforcement), then PReLU.
    """

    def __init__(self, c_in: int, c_out: int, branches: int, r_lim: int) -> None:
        super().__init__()
        self.eesp = EESP(c_in, c_out - c_in, 2, branches, r_lim)
        self.inp_reinf = nn.Sequential(ConvBnAct(REINF_CHANNELS, REINF_CHANNELS, 3), ConvBn(REINF_CHANNELS, c_out, 1))
        self.act = nn.PReLU(c_out)

    def forward(self, x: torch.Tensor, image_pooled: torch.Tensor) -> torch.Tensor:
        """``image_pooled``: the input image average-pooled (3x3, stride 2) to this output size."""
        out = torch.cat([F.avg_pool2d(x, 3, 2, 1), self.eesp(x)], 1)
        activated: torch.Tensor = self.act(out + self.inp_reinf(image_pooled))
        return activated


class EESPNetBase(nn.Module):
    """ESPNetv2 encoder, levels 1-4 (strides 2, 4, 8, 16)."""

    def __init__(self, s: float) -> None:
        super().__init__()
        ch = CHANNELS[s]
        self.config = ch
        self.level1 = ConvBnAct(3, ch[0], 3, stride=2)
        self.level2_0 = DownSampler(ch[0], ch[1], N_BRANCHES, 13)
        self.level3_0 = DownSampler(ch[1], ch[2], N_BRANCHES, 11)
        self.level3 = nn.ModuleList(EESP(ch[2], ch[2], 1, N_BRANCHES, 9) for _ in range(3))
        self.level4_0 = DownSampler(ch[2], ch[3], N_BRANCHES, 9)
        self.level4 = nn.ModuleList(EESP(ch[3], ch[3], 1, N_BRANCHES, 7) for _ in range(7))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(N, 3, H, W) -> features at strides 2, 4, 8, 16."""
        l1 = self.level1(x)
        img = F.avg_pool2d(F.avg_pool2d(x, 3, 2, 1), 3, 2, 1)  # stride 4
        l2 = self.level2_0(l1, img)
        img = F.avg_pool2d(img, 3, 2, 1)  # stride 8
        l3 = self.level3_0(l2, img)
        for layer in self.level3:
            l3 = layer(l3)
        img = F.avg_pool2d(img, 3, 2, 1)  # stride 16
        l4 = self.level4_0(l3, img)
        for layer in self.level4:
            l4 = layer(l4)
        return l1, l2, l3, l4


# --------------------------------------------------------------------------------------------
# Decoder
# --------------------------------------------------------------------------------------------


class EfficientPyrPool(nn.Module):
    """Pyramid pooling.

    Project to few channels, depth-wise 3x3 at 5 scales (2, 1.5, 1, 0.5, 0.1 of the map size; at
    least 5 px), shuffle, group conv, 1x1 to ``c_out`` (+ BN/PReLU).
    """

    def __init__(self, c_in: int, c_proj: int, c_out: int, last_layer_br: bool = True) -> None:
        super().__init__()
        self.scales = PYRAMID_SCALES
        self.static_ops = False
        self.projection_layer = SeqConvBnAct(c_in, c_proj, 1)
        self.stages = nn.ModuleList(nn.Conv2d(c_proj, c_proj, 3, 1, 1, bias=False, groups=c_proj) for _ in self.scales)
        n = len(self.scales)
        self.merge_layer = nn.Sequential(
            SeqBnAct(c_proj * n),
            ChannelShuffle(n),
            SeqConvBnAct(c_proj * n, c_proj, 3, groups=c_proj),
            nn.Conv2d(c_proj, c_out, 1, bias=not last_layer_br),
        )
        self.last_layer_br = last_layer_br
        if last_layer_br:
            self.br = SeqBnAct(c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, c_in, H, W) -> (N, c_out, H, W)."""
        x = self.projection_layer(x)
        h, w = int(x.shape[2]), int(x.shape[3])
        branches = []
        for scale, stage in zip(self.scales, self.stages, strict=True):
            hs, ws = max(math.ceil(h * scale), 5), max(math.ceil(w * scale), 5)
            if scale < 1.0:
                y = _resize(stage(adaptive_avg_pool(x, (hs, ws), self.static_ops)), (h, w))
            elif scale > 1.0:
                y = adaptive_avg_pool(stage(_resize(x, (hs, ws))), (h, w), self.static_ops)
            else:
                y = stage(x)
            branches.append(y)
        out: torch.Tensor = self.merge_layer(torch.cat(branches, 1))
        if self.last_layer_br:
            out = self.br(out)
        return out


class EfficientPWConv(nn.Module):
    """Skip-connection projection: group 3x3 CBR gated by a per-channel sigmoid of the global mean."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.wt_layer = nn.Sequential(nn.AdaptiveAvgPool2d(1), nn.Conv2d(c_in, c_out, 1, bias=False), nn.Sigmoid())
        self.expansion_layer = SeqConvBnAct(c_in, c_out, 3, groups=math.gcd(c_in, c_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, c_in, H, W) -> (N, c_out, H, W)."""
        out: torch.Tensor = self.expansion_layer(x) * self.wt_layer(x)
        return out


class ESPNetv2Segmentation(nn.Module):
    """ESPNetv2 encoder + pyramid-pooling decoder (EdgeNets ``espnetv2_seg``, ``dataset='city'``).

    Parameters
    ----------
    s
        Width scale (0.5, 1.0, 1.5, 2.0).
    classes
        Output channels (20 for the Cityscapes weights).
    """

    def __init__(self, s: float = 2.0, classes: int = 20) -> None:
        super().__init__()
        self.base_net = EESPNetBase(s)
        ch = self.base_net.config
        base_dec = 16
        dec = (4 * base_dec, 3 * base_dec, 2 * base_dec, classes)
        proj = min(classes // 2, base_dec)
        self.bu_dec_l1 = EfficientPyrPool(ch[3], proj, dec[0])
        self.bu_dec_l2 = EfficientPyrPool(dec[0], proj, dec[1])
        self.bu_dec_l3 = EfficientPyrPool(dec[1], proj, dec[2])
        self.bu_dec_l4 = EfficientPyrPool(dec[2], proj, dec[3], last_layer_br=False)
        self.merge_enc_dec_l2 = EfficientPWConv(ch[2], dec[0])
        self.merge_enc_dec_l3 = EfficientPWConv(ch[1], dec[1])
        self.merge_enc_dec_l4 = EfficientPWConv(ch[0], dec[2])
        self.bu_br_l2 = nn.Sequential(nn.BatchNorm2d(dec[0]), nn.PReLU(dec[0]))
        self.bu_br_l3 = nn.Sequential(nn.BatchNorm2d(dec[1]), nn.PReLU(dec[1]))
        self.bu_br_l4 = nn.Sequential(nn.BatchNorm2d(dec[2]), nn.PReLU(dec[2]))
        self.full_resolution = True

    def set_static_ops(self, static: bool) -> None:
        """Use ONNX-friendly fixed-size pooling (see module docstring)."""
        for m in self.modules():
            if isinstance(m, EfficientPyrPool):
                m.static_ops = static

    @staticmethod
    def _up2(x: torch.Tensor) -> torch.Tensor:
        return _resize(x, (2 * int(x.shape[2]), 2 * int(x.shape[3])))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3, H, W) normalised RGB -> (N, classes, H, W) logits (H/2 x W/2 unless full_resolution)."""
        size = (int(x.shape[2]), int(x.shape[3]))
        l1, l2, l3, l4 = self.base_net(x)
        y = self.bu_dec_l1(l4)
        y = self.bu_dec_l2(self.bu_br_l2(self._up2(y) + self.merge_enc_dec_l2(l3)))
        y = self.bu_dec_l3(self.bu_br_l3(self._up2(y) + self.merge_enc_dec_l3(l2)))
        y = self.bu_dec_l4(self.bu_br_l4(self._up2(y) + self.merge_enc_dec_l4(l1)))
        return _resize(y, size) if self.full_resolution else y


class NormalizedSegmenter(nn.Module):
    """Wrapper for export: (N, 3, H, W) float RGB in 0..255 -> ImageNet normalisation -> network."""

    mean: torch.Tensor
    inv_std: torch.Tensor

    def __init__(self, net: ESPNetv2Segmentation) -> None:
        super().__init__()
        self.net = net
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).reshape(1, 3, 1, 1) * 255.0)
        self.register_buffer("inv_std", 1.0 / (torch.tensor(IMAGENET_STD).reshape(1, 3, 1, 1) * 255.0))

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """(N, 3, H, W) float RGB in 0..255 -> the network's logits."""
        logits: torch.Tensor = self.net((image - self.mean) * self.inv_std)
        return logits


def load_espnetv2(weights: Path, s: float = 2.0, classes: int = 20) -> ESPNetv2Segmentation:
    """Build the network and load a published state dict strictly; returns it in eval mode."""
    net = ESPNetv2Segmentation(s=s, classes=classes)
    state = torch.load(weights, map_location="cpu", weights_only=True)
    net.load_state_dict(state, strict=True)
    return net.eval()
