"""Model-backed estimators of a scene's maps: ``{model: DIR}`` for depth, normals and
albedo. Each runs its model once per image content and settings (the raw prediction is
cached), then converts the prediction to zcomp's conventions at the edge.

* depth: a transformers depth model (``config.json``) or a diffusers depth pipeline
  (``model_index.json``): the raw prediction and its kind (metric, disparity, affine);
  the alignment to metric depth happens in ``estimate_scene_maps``, which knows whether
  a ground plane or learned normals can fix it;
* normals: a diffusers normals pipeline, converted from the model's frame and range;
* albedo: a diffusers intrinsics pipeline; its albedo target decoded to linear, and the
  appearance model's material target split into roughness and metallic.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from zcomp_cli.errors import InputError, WeightsError
from zcomp_cli.estimators.cache import EstimateCache, content_key
from zcomp_cli.estimators.model_outputs import clean_nonfinite, to_camera_normals, to_linear
from zcomp_cli.estimators.weights import fingerprint, folder_kind

# Marigold's target_properties name the space of each target; its "srgb" is the trainer's
# x ** (1 / 2.2) encoding, decoded here with x ** 2.2 ("gamma").
MARIGOLD_SPACES = {"srgb": "gamma", "linear": "linear"}
# The appearance model's material stack is encoded like its albedo: the trainer applies
# x ** (1 / 2.2) to InteriorVerse's linear material EXR and decodes the prediction with
# x ** 2.2 before evaluating it (targets_to_eval_in_linear_space: [material]), whatever
# the sub-targets' "linear" display hint says.
STACK_SPACE = "gamma"
MATERIAL_NAMES = {"roughness": "roughness", "metallicity": "metallic", "metallic": "metallic"}


@dataclass
class LearnedMap:
    """One estimated map (or a few from the same run) in zcomp's conventions."""

    maps: dict[str, np.ndarray]
    source: str
    notes: list = field(default_factory=list)
    run: dict = field(default_factory=dict)  # device, dtype, steps, seconds... or {"cached": True}
    kind: str | None = None  # depth only: metric | disparity | affine


def _hint(run: dict) -> str:
    dt = run.get("dtype", "?")
    return (f"the model ran in {dt} on {run.get('device', '?')}; " +
            ("fp16 overflows easily: try dtype: bf16 or fp32" if dt == "fp16" else "check the weights"))


def _diffusion_maps(image, spec: dict, *, task: str, what: str, cache: EstimateCache, img_key: str,
                    channels: dict[str, int]):
    """Run (or read from the cache) a diffusers pipeline: (PipelineInfo, raw maps, run info)."""
    from zcomp_cli.estimators.diffusion import (PipelineSettings, pipeline_info, resolve_device_dtype,
                                                run_pipeline)

    settings = PipelineSettings.from_spec(spec)
    info = pipeline_info(spec["model"], what=what, variant=settings.variant, pipeline=spec.get("pipeline"))
    if info.task != task:
        raise InputError(f"{what}: {info.folder.path} holds a {info.folder.class_name or info.runner} "
                         f"({info.task}), not a {task} model")
    device, dtype, note = resolve_device_dtype(settings.device, settings.dtype)
    key = content_key(img_key, "diffusers", task, fingerprint(info.folder.path),
                      settings.cache_fields(device, dtype), info.runner)
    names = channels if task != "intrinsics" else {t: 3 for t in info.target_names}
    cached = {n: cache.get(f"{task}_{n}" if task == "intrinsics" else n, key, c) for n, c in names.items()}
    if names and all(v is not None for v in cached.values()):
        run = {"cached": True, "device": device, "dtype": dtype}
        return info, cached, run
    pred = run_pipeline(info, image, settings)
    for n, arr in pred.maps.items():  # refuse before caching: a refused output is never stored
        clean_nonfinite(arr, f"{what} ({n})", hint=_hint(pred.info))
        cache.put(f"{task}_{n}" if task == "intrinsics" else n, key, arr)
    if note:
        pred.info["note"] = note
    return info, pred.maps, pred.info


def learned_normals(image, spec: dict, *, cache: EstimateCache, img_key: str) -> LearnedMap:
    """Camera-frame normals from a normals pipeline (``spec``: the manifest's mapping)."""
    from zcomp_cli.estimators.model_outputs import NORMAL_FRAMES, parse_normal_frame

    what = "normals model"
    if folder_kind(spec["model"]) == "transformers":
        raise WeightsError(f"{what}: {spec['model']} holds a transformers model (config.json); normals need a "
                           "diffusers normals pipeline (model_index.json), e.g. a saved MarigoldNormalsPipeline")
    info, raw, run = _diffusion_maps(image, spec, task="normals", what=what, cache=cache, img_key=img_key,
                                     channels={"normals": 3})
    frame = parse_normal_frame(spec.get("frame", "opengl"))
    notes = []
    arr, note = clean_nonfinite(raw["normals"], what, hint=_hint(run))
    if note:
        notes.append(note)
    n = to_camera_normals(arr, frame, encoded=bool(spec.get("encoded", False)))
    zero = int((np.linalg.norm(n, axis=-1) == 0).sum())
    if zero:
        notes.append(f"{what}: {zero} pixels without a direction (0 normal)")
    fname = next((k for k, v in NORMAL_FRAMES.items() if v == frame), str(spec.get("frame")))
    run = dict(run, frame=fname)
    return LearnedMap({"normals": n}, f"learned:{info.folder.path}", notes, run)


def _space(info, target: str, override: str | None) -> str:
    if override not in (None, "auto"):
        return override
    props = info.target_properties.get(target) or {}
    return MARIGOLD_SPACES.get(props.get("prediction_space", "srgb"), "gamma")


def learned_albedo(image, spec: dict, *, cache: EstimateCache, img_key: str) -> LearnedMap:
    """Linear albedo (and roughness/metallic when the model predicts a material stack)
    from an intrinsics pipeline."""
    from zcomp_cli.estimators.albedo import scale_albedo

    what = "albedo model"
    if folder_kind(spec["model"]) == "transformers":
        raise WeightsError(f"{what}: {spec['model']} holds a transformers model (config.json); albedo needs a "
                           "diffusers intrinsics pipeline (model_index.json), e.g. a saved MarigoldIntrinsicsPipeline")
    info, raw, run = _diffusion_maps(image, spec, task="intrinsics", what=what, cache=cache, img_key=img_key,
                                     channels={})
    target = spec.get("target", "albedo")
    if target not in raw:
        raise WeightsError(f"{what}: {info.folder.path} predicts {', '.join(raw) or 'nothing'}, no {target!r} "
                           "(set target: NAME)")
    notes = []
    arr, note = clean_nonfinite(raw[target], f"{what} ({target})", hint=_hint(run))
    if note:
        notes.append(note)
    space = _space(info, target, spec.get("space"))
    albedo = to_linear(arr, space)
    props = info.target_properties.get(target) or {}
    if props.get("up_to_scale"):
        albedo, s = scale_albedo(albedo)
        notes.append(f"{what}: albedo predicted up to scale; scaled by {s:.3g} (95th percentile luminance 0.8)")
    maps = {"albedo": albedo}
    run = dict(run, space=space, target=target)
    if spec.get("materials", True):
        for name, props in info.target_properties.items():
            if not isinstance(props, dict) or props.get("prediction_space") != "stack" or name not in raw:
                continue
            stack, note = clean_nonfinite(raw[name], f"{what} ({name})", hint=_hint(run))
            if note:
                notes.append(note)
            stack = to_linear(stack, STACK_SPACE)
            for i, sub in enumerate(props.get("sub_target_names") or []):
                if sub in MATERIAL_NAMES and i < 3:
                    maps[MATERIAL_NAMES[sub]] = stack[..., i].copy()
    return LearnedMap(maps, f"learned:{info.folder.path}", notes, run)


def marigold_depth_kind(info, override: str | None) -> str:
    """metric | disparity | affine for a diffusers depth pipeline's prediction."""
    if override:
        return override
    cfg = info.config
    if not cfg.get("scale_invariant", True) and not cfg.get("shift_invariant", True):
        return "metric"
    return "disparity" if cfg.get("prediction_type") == "disparity" else "affine"


def learned_depth_raw(image, spec: dict, *, cache: EstimateCache, img_key: str) -> LearnedMap:
    """The raw prediction of a depth model (transformers or diffusers) at the image's size,
    finite, with its kind; the alignment to metric depth is the caller's."""
    model = spec["model"]
    kind_of_folder = folder_kind(model)
    override = spec.get("output")
    notes: list[str] = []
    if kind_of_folder is None:
        from pathlib import Path

        d = Path(model).expanduser()
        raise WeightsError(f"depth model: {d} holds neither a diffusers depth pipeline (looked for "
                           f"{d / 'model_index.json'}) nor a transformers depth model (looked for "
                           f"{d / 'config.json'}, its weights and {d / 'preprocessor_config.json'})")
    if kind_of_folder == "diffusers":
        info, raw, run = _diffusion_maps(image, spec, task="depth", what="depth model", cache=cache,
                                         img_key=img_key, channels={"depth": 1})
        kind = marigold_depth_kind(info, override)
        src = f"learned:{info.folder.path}"
        arr = raw["depth"]
    else:
        from zcomp_cli.estimators.learned import check_model_dir, load_depth_model, output_kind, predict_raw

        if override == "affine":
            raise InputError("depth model: output: affine is for diffusers depth pipelines; a transformers "
                             "model outputs metric depth or disparity")
        d = check_model_dir(model)
        key = content_key(img_key, "transformers-depth", fingerprint(d))
        arr = cache.get("depth", key, 1)
        run = {"cached": True}
        if arr is None:
            mdl, proc = load_depth_model(d)
            kind_auto = output_kind(mdl.config)
            arr = predict_raw(mdl, proc, np.nan_to_num(np.asarray(image, np.float32), nan=0.0, posinf=1.0,
                                                       neginf=0.0))
            clean_nonfinite(arr, "depth model", hint="check the weights")
            cache.put("depth", key, arr)
            run = {"kind": kind_auto}
        else:
            import json

            from types import SimpleNamespace

            try:  # the kind, from the config alone: the model is not loaded on a cache hit
                cfg = json.loads((d / "config.json").read_text())
            except (OSError, ValueError) as exc:
                raise WeightsError(f"cannot read {d / 'config.json'}: {exc}") from exc
            kind_auto = output_kind(SimpleNamespace(**cfg) if isinstance(cfg, dict) else None)
        kind = override or kind_auto
        src = f"learned:{model}"
    arr, note = clean_nonfinite(arr, "depth model", hint=_hint(run))
    if note:
        notes.append(note)
    return LearnedMap({"depth": arr}, src, notes, run, kind)
