"""Learned depth from transformers' depth-estimation models stored in a LOCAL directory
(ZoeDepth, Depth Anything, DPT...). Nothing is downloaded.

Metric models (ZoeDepth; Depth Anything with ``depth_estimation_type: metric``) give
depth in metres, used as z-depth. Relative models (DPT, Depth Anything relative) give an
affine-invariant *disparity* d (inverse depth up to scale and shift). It is converted
here, before anything else sees it (the footprint alignment must never be fed
disparity):

* with a ground-plane description: fit ``1 / depth_proxy ~ a * d + b`` by robust
  least squares over the floor pixels of the proxy, then ``depth = 1 / (a d + b)``;
* otherwise: shift 0 and the scale that puts the median depth at ``median_depth_m``
  (default 3 m): ``depth = median_depth_m * median(d) / d``.

Pixels whose fitted inverse depth is not positive are invalid (depth 0).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError, WeightsError

log = logging.getLogger(__name__)

DEFAULT_MEDIAN_DEPTH_M = 3.0
WEIGHT_FILES = ("model.safetensors", "pytorch_model.bin", "model.safetensors.index.json",
                "pytorch_model.bin.index.json")
PROCESSOR_FILES = ("preprocessor_config.json",)


@dataclass
class LearnedDepth:
    depth: np.ndarray  # (H, W) float32 z-depth, metres, 0 = invalid
    raw: np.ndarray  # (H, W) float32 the model's output resized to the image
    kind: str  # "metric" | "disparity"
    alignment: str  # how raw became depth


def check_model_dir(model_dir) -> Path:
    """Raise WeightsError naming every file looked for unless ``model_dir`` holds a
    transformers depth model (config.json, weights, preprocessor_config.json)."""
    d = Path(model_dir).expanduser()
    missing = []
    if not (d / "config.json").is_file():
        missing.append("config.json")
    if not any((d / f).is_file() for f in WEIGHT_FILES):
        missing.append(" or ".join(WEIGHT_FILES))
    if not any((d / f).is_file() for f in PROCESSOR_FILES):
        missing.append("preprocessor_config.json")
    if missing:
        raise WeightsError(
            f"depth model directory {str(d)!r} lacks {', '.join(missing)}. Save a transformers "
            "depth-estimation model there (e.g. on a connected machine: "
            "AutoModelForDepthEstimation.from_pretrained('Intel/zoedepth-nyu-kitti')"
            ".save_pretrained(dir) and AutoImageProcessor...save_pretrained(dir)) and copy it over."
        )
    return d


def load_depth_model(model_dir):
    """(model, image_processor) from a local directory, eval mode, CPU/GPU as available."""
    d = check_model_dir(model_dir)
    try:
        from transformers import AutoImageProcessor, AutoModelForDepthEstimation

        processor = AutoImageProcessor.from_pretrained(str(d), local_files_only=True)
        model = AutoModelForDepthEstimation.from_pretrained(str(d), local_files_only=True)
    except (OSError, ValueError, KeyError) as exc:
        raise WeightsError(f"cannot load the depth model in {str(d)!r}: {exc}") from exc
    model.eval()
    return model, processor


def output_kind(config) -> str:
    """'metric' or 'disparity' for a transformers depth model config."""
    if getattr(config, "model_type", "") == "zoedepth":
        return "metric"
    if getattr(config, "depth_estimation_type", "relative") == "metric":
        return "metric"
    return "disparity"


def predict_raw(model, processor, image_lin) -> np.ndarray:
    """Run the model on a linear image (sRGB-encoded for the model, as it was trained)
    and return its (H, W) output resized (bilinear) to the image size, float32."""
    import torch
    import torch.nn.functional as F
    from PIL import Image

    from zcomp_cli.conventions import linear_to_srgb

    img = np.asarray(image_lin, np.float32)
    h, w = img.shape[:2]
    pil = Image.fromarray((linear_to_srgb(img) * 255 + 0.5).astype(np.uint8))
    inputs = processor(images=pil, return_tensors="pt")
    dev = next(model.parameters()).device
    inputs = {k: v.to(dev) for k, v in inputs.items()}
    with torch.no_grad():
        out = model(**inputs).predicted_depth
    if out.ndim == 3:
        out = out[:, None]
    out = F.interpolate(out.float(), size=(h, w), mode="bilinear", align_corners=False)
    raw = out[0, 0].cpu().numpy().astype(np.float32)
    if not np.isfinite(raw).all():
        from zcomp_cli.errors import NumericalError

        raise NumericalError("the depth model produced non-finite values")
    return raw


def _robust_affine(x: np.ndarray, y: np.ndarray, iters: int = 10) -> tuple[float, float]:
    """y ~ a x + b, robust to a minority of outliers (objects on the floor): least
    squares, then refits on the inliers within 3 robust sigmas (MAD) of the last fit."""
    keep = np.ones(x.shape, bool)
    a = b = 0.0
    for _ in range(iters):
        A = np.stack([x[keep], np.ones(int(keep.sum()))], -1)
        sol, *_ = np.linalg.lstsq(A, y[keep], rcond=None)
        a, b = float(sol[0]), float(sol[1])
        r = np.abs(a * x + b - y)
        s = 1.4826 * float(np.median(r)) + 1e-12 * (np.abs(y).max() + 1e-30)
        new = r <= 3.0 * s
        if new.sum() < 8 or np.array_equal(new, keep):
            break
        keep = new
    return a, b


def disparity_to_depth(disp, *, proxy_depth=None, proxy_mask=None,
                       median_depth_m: float = DEFAULT_MEDIAN_DEPTH_M) -> tuple[np.ndarray, str]:
    """Convert an affine-invariant disparity map to metric z-depth (see module doc).

    Args:
        disp: (H, W) disparity (larger = nearer), any affine scale.
        proxy_depth, proxy_mask: optional (H, W) reference depth (metres) and the bool
            pixels to fit over (e.g. the ground-plane floor).
        median_depth_m: used when no proxy is given.
    Returns:
        (depth (H, W) float32, 0 where invalid; a one-line description of the fit).
    """
    d = np.asarray(disp, np.float64)
    if d.ndim != 2:
        raise InputError(f"disparity must be (H, W), got {d.shape}")
    finite = np.isfinite(d)
    if proxy_depth is not None:
        pd = np.asarray(proxy_depth, np.float64)
        m = finite & np.isfinite(pd) & (pd > 0)
        if proxy_mask is not None:
            m &= np.asarray(proxy_mask, bool)
        if m.sum() >= 16 and np.ptp(d[m]) > 1e-9:
            a, b = _robust_affine(d[m], 1.0 / pd[m])
            if a > 0:
                inv = a * d + b
                with np.errstate(divide="ignore"):
                    depth = np.where(finite & (inv > 1e-6), 1.0 / inv, 0.0)
                return depth.astype(np.float32), f"1/depth = {a:.4g} * disparity + {b:.4g} (fit to ground plane, {int(m.sum())} px)"
        log.warning("disparity fit to the ground plane failed; using the median depth")
    if not (np.isfinite(median_depth_m) and median_depth_m > 0):
        raise InputError(f"median_depth must be positive, got {median_depth_m!r}")
    pos = finite & (d > 0)
    if not pos.any():
        raise InputError("the disparity map has no positive value")
    med = float(np.median(d[pos]))
    with np.errstate(divide="ignore"):
        depth = np.where(pos, median_depth_m * med / np.where(pos, d, 1.0), 0.0)
    return depth.astype(np.float32), f"depth = {median_depth_m:g} m * median(disparity) / disparity"


def learned_depth(image_lin, camera: Camera, model_dir, *, output: str | None = None,
                  proxy_depth=None, proxy_mask=None,
                  median_depth_m: float = DEFAULT_MEDIAN_DEPTH_M, model=None) -> LearnedDepth:
    """Metric z-depth of a linear (H, W, 3) image from a local transformers model.

    ``output`` overrides the detected kind ('metric' or 'disparity'). ``model`` may be a
    preloaded ``(model, processor)`` pair.
    """
    img = np.asarray(image_lin)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[:2] != (camera.height, camera.width):
        raise InputError(f"learned_depth: image {img.shape} does not match the camera "
                         f"{camera.height}x{camera.width}x3")
    mdl, proc = model if model is not None else load_depth_model(model_dir)
    kind = output or output_kind(mdl.config)
    if kind not in ("metric", "disparity"):
        raise InputError(f"depth model output must be 'metric' or 'disparity', got {kind!r}")
    raw = predict_raw(mdl, proc, np.nan_to_num(img, nan=0.0, posinf=1.0, neginf=0.0))
    if kind == "metric":
        depth = np.where(raw > 0, raw, 0.0).astype(np.float32)
        return LearnedDepth(depth, raw, kind, "metric output used as z-depth")
    depth, how = disparity_to_depth(raw, proxy_depth=proxy_depth, proxy_mask=proxy_mask,
                                    median_depth_m=median_depth_m)
    return LearnedDepth(depth, raw, kind, how)
