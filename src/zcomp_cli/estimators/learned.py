"""Learned depth from transformers' depth-estimation models stored in a LOCAL directory
(ZoeDepth, Depth Anything, DPT...). Nothing is downloaded.

Metric models (ZoeDepth; Depth Anything with ``depth_estimation_type: metric``) give
depth in metres, used as z-depth. Relative models (DPT, Depth Anything relative) give an
affine-invariant *disparity* (inverse depth up to scale and shift), turned into metric
z-depth by ``estimators.depth_alignment`` before anything else sees it (the footprint
alignment must never be fed disparity): fitted to a ground plane when one is described,
else scaled to a median depth with the shift fitted to learned normals or taken as 0.
The diffusers depth pipelines (Marigold) live in ``estimators.diffusion``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError, WeightsError
from zcomp_cli.estimators.depth_alignment import DEFAULT_MEDIAN_DEPTH_M, disparity_to_depth
from zcomp_cli.estimators.model_outputs import clean_nonfinite

log = logging.getLogger(__name__)

__all__ = ["LearnedDepth", "check_model_dir", "load_depth_model", "output_kind", "predict_raw",
           "learned_depth", "disparity_to_depth", "DEFAULT_MEDIAN_DEPTH_M"]
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
    if not missing:
        from zcomp_cli.estimators.weights import check_folder_safety

        check_folder_safety(d, "depth model")
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
        import transformers
        from transformers import AutoImageProcessor, AutoModelForDepthEstimation

        from zcomp_cli.estimators.weights import quiet_loading

        # trust_remote_code=False: never the folder's own code, and never a question on stdin;
        # no "Loading weights" bar (it showed under -q)
        with quiet_loading(transformers.utils.logging):
            processor = AutoImageProcessor.from_pretrained(str(d), local_files_only=True, trust_remote_code=False)
            model, info = AutoModelForDepthEstimation.from_pretrained(
                str(d), local_files_only=True, trust_remote_code=False, output_loading_info=True)
    except Exception as exc:  # noqa: BLE001 - a damaged folder fails its scene's jobs, not the batch
        raise WeightsError(f"cannot load the depth model in {str(d)!r}: {type(exc).__name__}: "
                           f"{str(exc)[:500]}") from exc
    # transformers loads weights that lack tensors the config needs by initialising them
    # at random (a load report, no error): a depth map from such a model is noise.
    # Refused (found by the fuzzer). Mismatched shapes it refuses itself; kept here too.
    bad = {k: sorted(map(str, info.get(k) or ()))[:3] for k in ("missing_keys", "mismatched_keys")
           if info.get(k)}
    if bad:
        said = "; ".join(f"{len(info[k])} {k.replace('_', ' ')} (e.g. {', '.join(v)})" for k, v in bad.items())
        raise WeightsError(f"the depth model in {str(d)!r} does not match its config.json: {said}; transformers "
                           "would fill them with random values. Save the model and its config together")
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
    # Non-finite values are kept: the caller cleans or refuses them (model_outputs).
    return out[0, 0].float().cpu().numpy().astype(np.float32)


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
    raw, _ = clean_nonfinite(raw, "depth model output")
    if kind == "metric":
        depth = np.where(raw > 0, raw, 0.0).astype(np.float32)
        return LearnedDepth(depth, raw, kind, "metric output used as z-depth")
    depth, how = disparity_to_depth(raw, proxy_depth=proxy_depth, proxy_mask=proxy_mask,
                                    median_depth_m=median_depth_m)
    return LearnedDepth(depth, raw, kind, how)
