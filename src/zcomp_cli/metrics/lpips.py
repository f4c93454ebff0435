"""LPIPS (Zhang et al. 2018, v0.1, AlexNet) without torchvision.

torchvision cannot be installed beside the project's CPU torch, so the AlexNet feature
extractor lives here with torchvision's layer layout (``features.0`` ... ``features.12``)
so that torchvision's AlexNet state dict (``alexnet-owt-7be5be79.pth``) loads into it.
The linear heads use the lpips package's layout (``lin0.model.1.weight`` ...).

Inputs: sRGB-encoded images in [0, 1], H x W x 3; they are resized to 256 x 256 (as in
the paper's evaluation) and mapped to [-1, 1].
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zcomp_cli.errors import InputError, WeightsError

from zcomp_cli.metrics.lpips_weights import BACKBONE, LINEAR, resolve

BACKBONE_FILE = BACKBONE.name
LIN_FILE = LINEAR.name
ENV_BACKBONE = BACKBONE.env
ENV_WEIGHTS = LINEAR.env
LPIPS_SIZE = 256
# Channel counts of the 5 AlexNet ReLU outputs LPIPS compares.
ALEX_CHANNELS = (64, 192, 384, 256, 256)
# Indices into ``features`` that end each LPIPS slice (relu1 .. relu5), as in lpips.
_SLICE_ENDS = (2, 5, 8, 10, 12)


def torch_home() -> Path:
    """torch's cache root: $TORCH_HOME, else $XDG_CACHE_HOME/torch, else ~/.cache/torch."""
    if os.environ.get("TORCH_HOME"):
        return Path(os.environ["TORCH_HOME"]).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join("~", ".cache")
    return Path(xdg).expanduser() / "torch"


def backbone_candidates() -> list[Path]:
    """Copies of the AlexNet backbone that may be on the machine (torch hub's cache)."""
    return [torch_home() / "hub" / "checkpoints" / BACKBONE_FILE]


def lin_candidates() -> list[Path]:
    """Copies of the LPIPS v0.1 linear layers that may be on the machine: torch hub's
    cache, an installed lpips package's ``weights/v0.1/alex.pth``."""
    out = [torch_home() / "hub" / "checkpoints" / "lpips_v0.1_alex.pth"]
    installed = installed_lpips_weights()
    return out + ([installed] if installed is not None else [])


def installed_lpips_weights() -> Path | None:
    """An installed lpips package's ``weights/v0.1/alex.pth``, located without importing
    lpips (its import pulls in torchvision)."""
    import importlib.util

    spec = importlib.util.find_spec("lpips")
    return Path(spec.origin).parent / "weights" / "v0.1" / LIN_FILE if spec is not None and spec.origin else None


def lpips_files(backbone_path=None, weights_path=None, *, cache_root=None):
    """(backbone path, linear weights path, notes): found, given or fetched on first use
    (``lpips_weights``); ``WeightsError`` when one cannot be had."""
    b = resolve(BACKBONE, backbone_path, backbone_candidates(), cache_root=cache_root)
    lin = resolve(LINEAR, weights_path, lin_candidates(), cache_root=cache_root)
    return b.path, lin.path, [n for n in (b.note, lin.note) if n]


def _build_modules():
    import torch.nn as nn

    class AlexNetFeatures(nn.Module):
        """torchvision's ``alexnet().features`` layer for layer (same names/shapes)."""

        def __init__(self):
            super().__init__()
            self.features = nn.Sequential(
                nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2),
                nn.ReLU(inplace=True),
                nn.MaxPool2d(kernel_size=3, stride=2),
                nn.Conv2d(64, 192, kernel_size=5, padding=2),
                nn.ReLU(inplace=True),
                nn.MaxPool2d(kernel_size=3, stride=2),
                nn.Conv2d(192, 384, kernel_size=3, padding=1),
                nn.ReLU(inplace=True),
                nn.Conv2d(384, 256, kernel_size=3, padding=1),
                nn.ReLU(inplace=True),
                nn.Conv2d(256, 256, kernel_size=3, padding=1),
                nn.ReLU(inplace=True),
                nn.MaxPool2d(kernel_size=3, stride=2),
            )

        def forward(self, x):
            """x: N x 3 x H x W (already shifted/scaled). Returns the 5 ReLU outputs."""
            outs, start = [], 0
            for end in _SLICE_ENDS:
                for i in range(start, end):
                    x = self.features[i](x)
                outs.append(x)
                start = end
            return outs

    class LinHead(nn.Module):
        """1x1 conv without bias behind a dropout (index 1 = conv, as in lpips)."""

        def __init__(self, chn_in):
            super().__init__()
            self.model = nn.Sequential(nn.Dropout(), nn.Conv2d(chn_in, 1, 1, bias=False))

        def forward(self, x):
            return self.model(x)

    return AlexNetFeatures, LinHead


def make_alexnet_features():
    """A randomly initialised AlexNet feature extractor (torchvision layout)."""
    AlexNetFeatures, _ = _build_modules()
    return AlexNetFeatures()


def make_lpips_model():
    """A randomly initialised LPIPS-Alex module in eval mode (weights not loaded)."""
    import torch
    import torch.nn as nn

    AlexNetFeatures, LinHead = _build_modules()

    class LPIPSAlex(nn.Module):
        def __init__(self):
            super().__init__()
            # lpips' ScalingLayer: ImageNet statistics expressed on [-1, 1] inputs.
            self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
            self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))
            self.net = AlexNetFeatures()
            for k, c in enumerate(ALEX_CHANNELS):
                self.add_module(f"lin{k}", LinHead(c))

        def layer_maps(self, x0, x1):
            """x0, x1: N x 3 x H x W in [-1, 1]. Returns the 5 per-layer N x 1 x h x w maps."""
            f0 = self.net((x0 - self.shift) / self.scale)
            f1 = self.net((x1 - self.shift) / self.scale)
            maps = []
            for k, (a, b) in enumerate(zip(f0, f1)):
                # Unit-normalise along channels; eps as in lpips, after the sqrt.
                a = a / (torch.sqrt((a**2).sum(dim=1, keepdim=True)) + 1e-10)
                b = b / (torch.sqrt((b**2).sum(dim=1, keepdim=True)) + 1e-10)
                maps.append(getattr(self, f"lin{k}")((a - b) ** 2))
            return maps

        def forward(self, x0, x1):
            """Distance per batch item, N, from inputs in [-1, 1]."""
            return sum(m.mean(dim=(2, 3)) for m in self.layer_maps(x0, x1))[:, 0]

    return LPIPSAlex().eval()


def _load_state(path: Path, what: str) -> dict:
    import torch

    try:
        sd = torch.load(str(path), map_location="cpu", weights_only=True)
    except Exception as exc:  # corrupt file, pickle, wrong format
        raise WeightsError(f"cannot read LPIPS {what}: {exc}", where=str(path)) from exc
    if isinstance(sd, dict) and "state_dict" in sd and isinstance(sd["state_dict"], dict):
        sd = sd["state_dict"]
    if not isinstance(sd, dict):
        raise WeightsError(f"LPIPS {what} is not a state dict", where=str(path))
    return sd


def load_lpips(backbone_path=None, weights_path=None, *, device: str = "cpu", cache_root=None):
    """Build LPIPS-Alex and load its weights.

    Args:
        backbone_path: torchvision AlexNet state dict (full model or ``features.*``
            only); default $ZCOMP_LPIPS_BACKBONE, else a published copy on the machine
            (zcomp's cache, ``$TORCH_HOME/hub/checkpoints/alexnet-owt-7be5be79.pth``),
            else fetched into zcomp's cache (``lpips_weights``).
        weights_path: lpips ``weights/v0.1/alex.pth`` (keys ``lin{k}.model.1.weight``);
            default $ZCOMP_LPIPS_WEIGHTS, else the same places or an installed lpips.
        cache_root: zcomp's cache root (``--cache-dir``; default ``zcomp_cli.cache``'s).
    Returns:
        The module in eval mode on ``device``; ``zcomp_notes``: why a given file's
        scores may not be the paper's.
    Raises:
        WeightsError: a file cannot be had (naming every path looked at and why the
        download failed) or does not match.
    """
    bpath, lpath, notes = lpips_files(backbone_path, weights_path, cache_root=cache_root)
    model = make_lpips_model()
    model.zcomp_notes = notes
    bsd = _load_state(bpath, "backbone")
    feats = {k: v for k, v in bsd.items() if k.startswith("features.")}
    want = set(model.net.state_dict())
    if set(feats) != want:
        missing = sorted(want - set(feats))
        raise WeightsError(f"not a torchvision AlexNet state dict (missing {missing[:4]})", where=str(bpath))
    lsd = _load_state(lpath, "linear weights")
    lins = {k: v for k, v in lsd.items() if k.startswith("lin")}
    want_l = {f"lin{k}.model.1.weight" for k in range(5)}
    if set(lins) != want_l:
        raise WeightsError(f"expected keys {sorted(want_l)}, found {sorted(lins)[:6]}", where=str(lpath))
    try:
        model.net.load_state_dict(feats, strict=True)
        model.load_state_dict(lins, strict=False)
    except RuntimeError as exc:  # shape mismatch
        raise WeightsError(f"weights do not fit LPIPS-Alex: {exc}") from exc
    return model.to(device)


def to_lpips_tensor(img_srgb, *, size: int | None = LPIPS_SIZE, device: str = "cpu"):
    """H x W x 3 sRGB [0, 1] numpy -> 1 x 3 x size x size torch tensor in [-1, 1].

    Resizing is bilinear with antialiasing (as torchvision's tensor Resize); ``size``
    None keeps the resolution.
    """
    import torch
    import torch.nn.functional as F

    a = np.asarray(img_srgb, dtype=np.float32)
    if a.ndim != 3 or a.shape[-1] != 3:
        raise InputError(f"LPIPS needs an H x W x 3 image, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise InputError("LPIPS input has non-finite values")
    t = torch.from_numpy(np.ascontiguousarray(np.clip(a, 0.0, 1.0))).permute(2, 0, 1)[None].to(device)
    if size is not None and tuple(t.shape[-2:]) != (size, size):
        t = F.interpolate(t, size=(size, size), mode="bilinear", align_corners=False, antialias=True)
    return t * 2.0 - 1.0


def lpips_distance(model, pred_srgb, ref_srgb, mask=None, *, size: int | None = LPIPS_SIZE) -> float:
    """LPIPS distance (0 for identical images; lower is better).

    Args:
        model: from ``load_lpips`` (or ``make_lpips_model`` in tests).
        pred_srgb, ref_srgb: H x W x 3 sRGB-encoded in [0, 1].
        mask: optional H x W; the per-layer maps are upsampled to the (resized) image
            and averaged over the (resized) mask instead of over the whole image.
    """
    import torch
    import torch.nn.functional as F

    if np.shape(pred_srgb) != np.shape(ref_srgb):
        raise InputError(f"size mismatch: pred {np.shape(pred_srgb)}, ref {np.shape(ref_srgb)}")
    device = next(model.parameters()).device
    x0 = to_lpips_tensor(pred_srgb, size=size, device=device)
    x1 = to_lpips_tensor(ref_srgb, size=size, device=device)
    with torch.no_grad():
        if mask is None:
            return float(model(x0, x1)[0])
        hw = x0.shape[-2:]
        m = torch.from_numpy(np.asarray(mask, dtype=np.float32).reshape(np.shape(pred_srgb)[:2]))
        m = F.interpolate(m[None, None].to(device), size=hw, mode="bilinear", align_corners=False)
        m = (m > 0.5).float()
        if float(m.sum()) == 0:
            raise InputError("mask selects no pixel at the LPIPS resolution", where="mask")
        total = sum(
            F.interpolate(lm, size=hw, mode="bilinear", align_corners=False)
            for lm in model.layer_maps(x0, x1)
        )
        return float((total * m).sum() / m.sum())


@dataclass
class LPIPSStatus:
    """The outcome of trying to load LPIPS for a run: a model, or why not."""

    model: object | None
    reason: str | None = None


def try_load_lpips(backbone_path=None, weights_path=None, *, cache_root=None) -> LPIPSStatus:
    """``load_lpips`` that reports a missing/bad file instead of raising."""
    try:
        return LPIPSStatus(load_lpips(backbone_path, weights_path, cache_root=cache_root))
    except WeightsError as exc:
        return LPIPSStatus(None, str(exc))
