"""Dense prediction with diffusers pipelines saved in a LOCAL folder: Marigold depth,
normals and intrinsic image decomposition (albedo; roughness and metallic for the
appearance model), and any folder saved in the same format (a fine-tune, an LCM
distillation). Nothing is downloaded: every load is ``local_files_only`` and the folder
is checked first (``estimators.weights``), naming each missing file.

The pipelines return their outputs in their own conventions (Marigold's image
processor: normals in [-1, 1], x right, y up, z toward the viewer; depth in [0, 1],
affine-invariant; intrinsic targets in [0, 1] in each target's prediction space). The
conversion to zcomp's conventions happens in ``estimators.model_outputs`` and
``estimators.depth_alignment``, not here.

Steps of ``predict``:

1. check the folder and what its ``model_index.json`` says (class, task);
2. resolve the device and dtype (bf16 on a GPU that has it, else fp16; fp32 on the CPU);
3. load the pipeline (kept in memory for the next scene) and run it on the sRGB image
   with the settings (steps, ensemble size, processing resolution, seed);
4. return the raw maps and what is needed to interpret them.
"""

from __future__ import annotations

import logging
import time
import warnings
from collections import OrderedDict
from dataclasses import asdict, dataclass, field

import numpy as np

from zcomp_cli.conventions import DEFAULT_SEED, linear_to_srgb
from zcomp_cli.errors import InputError, NumericalError, WeightsError
from zcomp_cli.estimators.weights import PipelineFolder, read_pipeline_folder

log = logging.getLogger(__name__)

# The diffusers class that runs each task, and the names folders are saved under
# (the Marigold repository's own classes save the same components).
RUNNERS = {"depth": "MarigoldDepthPipeline", "normals": "MarigoldNormalsPipeline",
           "intrinsics": "MarigoldIntrinsicsPipeline"}
CLASS_TASKS = {
    "MarigoldDepthPipeline": "depth",
    "MarigoldPipeline": "depth",  # prs-eth/marigold-v1-0 (depth), saved by the original code
    "MarigoldNormalsPipeline": "normals",
    "MarigoldIntrinsicsPipeline": "intrinsics",
    "MarigoldIIDPipeline": "intrinsics",  # the Marigold repository's name for the same pipeline
}
# Pipelines with their own code (custom classes, ControlNets, extra priors): zcomp does
# not execute code shipped with weights, so these are refused with the reason.
FOREIGN = {"YOSONormalsPipeline": "StableNormal-turbo (YOSO)", "StableNormalPipeline": "StableNormal"}
DTYPES = ("auto", "fp32", "fp16", "bf16")
MAX_LOADED_CPU, MAX_LOADED_GPU = 1, 3  # pipelines kept loaded between scenes
_LOADED: "OrderedDict[tuple, object]" = OrderedDict()


@dataclass(frozen=True)
class PipelineSettings:
    """How a pipeline is run. ``None`` takes the model's own default (from its
    ``model_index.json``: ``default_denoising_steps``, ``default_processing_resolution``)."""

    steps: int | None = None
    ensemble_size: int = 1
    processing_resolution: int | None = None  # longest side; 0 = the image's own size
    seed: int = DEFAULT_SEED
    dtype: str = "auto"  # auto | fp32 | fp16 | bf16
    device: str = "auto"  # auto | cpu | cuda | cuda:N
    variant: str | None = None  # weight files to load ("fp16"); None = picked from the folder
    batch_size: int = 1

    KEYS = ("steps", "ensemble_size", "processing_resolution", "seed", "dtype", "device", "variant",
            "batch_size")

    @classmethod
    def from_spec(cls, spec: dict) -> "PipelineSettings":
        """Read the settings keys of an estimator mapping; InputError on a bad value."""
        problems = settings_problems(spec)
        if problems:
            raise InputError("; ".join(f"{k}: {m}" for k, m in problems))
        kw = {k: spec[k] for k in cls.KEYS if k in spec and spec[k] is not None}
        return cls(**kw)

    def cache_fields(self, device: str, dtype: str) -> dict:
        """What changes the prediction: the settings with device type and dtype resolved."""
        d = asdict(self)
        d.pop("batch_size")  # batching does not change the result
        d.update(device=device.split(":")[0], dtype=dtype)
        return d


def settings_problems(spec: dict) -> list[tuple[str | None, str]]:
    """(key, message) for every bad pipeline setting in ``spec`` (no torch import)."""
    out = []

    def integer(k, lo, hi):
        v = spec.get(k)
        if v is None:
            return
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            out.append((k, f"expected an integer in [{lo}, {hi}], got {v!r}"))

    integer("steps", 1, 1000)
    integer("ensemble_size", 1, 64)
    integer("processing_resolution", 0, 8192)
    integer("seed", 0, 2**32 - 1)
    integer("batch_size", 1, 64)
    pr = spec.get("processing_resolution")
    if isinstance(pr, int) and not isinstance(pr, bool) and pr % 8:
        out.append(("processing_resolution", f"must be a multiple of 8 (the latent grid), got {pr}"))
    if spec.get("dtype") is not None and spec.get("dtype") not in DTYPES:
        out.append(("dtype", f"expected one of {', '.join(DTYPES)}, got {spec.get('dtype')!r}"))
    dev = spec.get("device")
    if dev is not None and not (isinstance(dev, str) and (dev in ("auto", "cpu", "cuda") or
                                                          (dev.startswith("cuda:") and dev[5:].isdigit()))):
        out.append(("device", f"expected auto, cpu, cuda or cuda:N, got {dev!r}"))
    var = spec.get("variant")
    if var is not None and not (isinstance(var, str) and var.isidentifier()):
        out.append(("variant", f"expected a weight-file variant such as fp16, got {var!r}"))
    return out


@dataclass
class PipelineInfo:
    """What the folder says about its outputs (read from model_index.json, no torch)."""

    folder: PipelineFolder
    task: str  # depth | normals | intrinsics
    runner: str  # the diffusers class used
    config: dict = field(default_factory=dict)

    @property
    def default_steps(self):
        return self.config.get("default_denoising_steps")

    @property
    def default_resolution(self):
        return self.config.get("default_processing_resolution")

    @property
    def target_properties(self) -> dict:
        return self.config.get("target_properties") or {}

    @property
    def target_names(self) -> list[str]:
        return list(self.target_properties.get("target_names") or [])


def pipeline_info(model_dir, *, what: str, variant: str | None = None,
                  pipeline: str | None = None) -> PipelineInfo:
    """Check a pipeline folder and say which task it performs.

    Args:
        model_dir: the folder.
        what: for messages ("normals model").
        variant: weight-file variant to require.
        pipeline: force the diffusers class (one of :data:`RUNNERS`' values) for a folder
            saved under another class name with the same components.
    Raises:
        WeightsError: files missing, or a pipeline zcomp cannot run.
    """
    folder = read_pipeline_folder(model_dir, what=what, variant=variant)
    name = pipeline or folder.class_name
    if pipeline is not None and pipeline not in RUNNERS.values():
        raise InputError(f"{what}: pipeline must be one of {', '.join(RUNNERS.values())}, got {pipeline!r}")
    if name in FOREIGN:
        raise WeightsError(
            f"{what}: {folder.path / 'model_index.json'} names {name} ({FOREIGN[name]}), a pipeline "
            "that ships its own code (custom classes loaded with trust_remote_code); zcomp runs only "
            f"diffusers' own {', '.join(RUNNERS.values())} and folders saved in their format")
    task = CLASS_TASKS.get(name)
    if task is None:
        raise WeightsError(
            f"{what}: {folder.path / 'model_index.json'} names {name or 'no class'}; zcomp runs "
            f"{', '.join(sorted(CLASS_TASKS))} (or give pipeline: {'|'.join(RUNNERS.values())} for a "
            "folder saved in their format under another name)")
    return PipelineInfo(folder, task, RUNNERS[task], dict(folder.config))


def resolve_device_dtype(device: str = "auto", dtype: str = "auto") -> tuple[str, str, str | None]:
    """(device, dtype, note): ``auto`` is CUDA when torch sees a GPU, else the CPU; the
    dtype ``auto`` is bf16 on a GPU that supports it, else fp16, and fp32 on the CPU. A
    half dtype asked for on the CPU runs in fp32 (the note says so): CPU kernels for
    half precision are slow or missing, and fp16 overflows into NaN."""
    import torch

    note = None
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise InputError(f"device {device!r} asked for, but torch sees no GPU (use device: auto or cpu)")
    if dtype == "auto":
        if device.startswith("cuda"):
            dtype = "bf16" if torch.cuda.is_bf16_supported() else "fp16"
        else:
            dtype = "fp32"
    elif dtype in ("fp16", "bf16") and device == "cpu":
        note = f"dtype {dtype} asked for on the CPU: running in fp32"
        dtype = "fp32"
    return device, dtype, note


def _torch_dtype(name: str):
    import torch

    return {"fp32": torch.float32, "fp16": torch.float16, "bf16": torch.bfloat16}[name]


def load_pipeline(info: PipelineInfo, device: str, dtype: str):
    """The diffusers pipeline of ``info`` on ``device`` in ``dtype``, loaded with
    ``local_files_only`` (kept for the next call; the text encoder is dropped once the
    constant empty-prompt embedding is computed)."""
    key = (str(info.folder.path.resolve()), info.runner, device, dtype, info.folder.variant)
    if key in _LOADED:
        _LOADED.move_to_end(key)
        return _LOADED[key]
    import diffusers
    import torch

    keep = MAX_LOADED_GPU if device.startswith("cuda") else MAX_LOADED_CPU
    while len(_LOADED) >= keep:
        _LOADED.popitem(last=False)
    cls = getattr(diffusers, info.runner, None)
    if cls is None:
        raise WeightsError(f"this diffusers ({diffusers.__version__}) has no {info.runner}; "
                           "the Marigold intrinsics pipeline needs diffusers >= 0.33")
    from zcomp_cli.estimators.weights import quiet_loading

    try:  # (load-time chatter: accelerate, per-component progress bars, off)
        with quiet_loading(diffusers.utils.logging), warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)  # torch_dtype is renamed dtype in newer diffusers
            pipe = cls.from_pretrained(str(info.folder.path), local_files_only=True,
                                       torch_dtype=_torch_dtype(dtype), variant=info.folder.variant,
                                       low_cpu_mem_usage=False, trust_remote_code=False)
    except Exception as exc:  # noqa: BLE001 - a damaged folder fails its scene's jobs, not the batch
        raise WeightsError(f"cannot load the {info.runner} in {info.folder.path}: {type(exc).__name__}: "
                           f"{str(exc)[:500]}") from exc
    pipe = pipe.to(device)
    pipe.set_progress_bar_config(disable=True)
    with torch.no_grad():  # the empty prompt's embedding, once, as the pipeline computes it
        ids = pipe.tokenizer("", padding="do_not_pad", max_length=pipe.tokenizer.model_max_length,
                             truncation=True, return_tensors="pt").input_ids.to(device)
        pipe.empty_text_embedding = pipe.text_encoder(ids)[0]
    pipe.text_encoder = None  # 1.4 GB for SD 2's CLIP that no later call needs
    _LOADED[key] = pipe
    return pipe


def release_pipelines() -> None:
    """Forget every loaded pipeline (tests, benchmarks)."""
    _LOADED.clear()


@dataclass
class PipelinePrediction:
    """Raw outputs of one run, in the model's conventions, at the image's size."""

    task: str
    maps: dict[str, np.ndarray]  # depth: {"depth": (H, W)}; normals: {"normals": (H, W, 3)};
    #                              intrinsics: {target name: (H, W, 3)}
    info: dict  # runner, device, dtype, steps, ensemble, resolution, seconds


def run_pipeline(info: PipelineInfo, image_lin, settings: PipelineSettings) -> PipelinePrediction:
    """Run the pipeline of ``info`` on a linear (H, W, 3) image (given to the model
    sRGB-encoded in [0, 1], as it was trained) and return its raw maps at (H, W)."""
    import torch

    img = np.asarray(image_lin, np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"{info.task} model: image must be (H, W, 3), got {img.shape}")
    device, dtype, note = resolve_device_dtype(settings.device, settings.dtype)
    steps = settings.steps if settings.steps is not None else info.default_steps
    res = settings.processing_resolution if settings.processing_resolution is not None else info.default_resolution
    if steps is None or res is None:
        raise WeightsError(f"{info.folder.path / 'model_index.json'} sets no default_denoising_steps / "
                           "default_processing_resolution: give steps and processing_resolution")
    pipe = load_pipeline(info, device, dtype)
    srgb = np.clip(linear_to_srgb(np.nan_to_num(img, nan=0.0, posinf=1.0, neginf=0.0)), 0.0, 1.0)
    gen = torch.Generator(device=device).manual_seed(int(settings.seed))
    log.info("%s: %s (%s) on %s %s, %d steps, ensemble %d, %s px ...", info.task, info.runner,
             info.folder.path, device, dtype, steps, settings.ensemble_size, res or "native")
    t = time.perf_counter()
    try:
        out = pipe(srgb, num_inference_steps=int(steps), ensemble_size=int(settings.ensemble_size),
                   processing_resolution=int(res), match_input_resolution=True, batch_size=settings.batch_size,
                   generator=gen, output_type="np")
    except (ValueError, RuntimeError) as exc:
        raise NumericalError(f"{info.runner} in {info.folder.path} failed: {exc}") from exc
    seconds = time.perf_counter() - t
    log.info("%s: predicted in %.1f s", info.task, seconds)
    pred = np.asarray(out.prediction, np.float32)
    h, w = img.shape[:2]
    if info.task == "depth":
        maps = {"depth": pred[0, ..., 0]}
    elif info.task == "normals":
        maps = {"normals": pred[0]}
    else:
        names = info.target_names or [f"target{i}" for i in range(pred.shape[0])]
        if len(names) != pred.shape[0]:
            raise WeightsError(f"{info.folder.path}: target_properties names {len(names)} targets, "
                               f"the model predicted {pred.shape[0]}")
        maps = dict(zip(names, pred))
    for k, v in maps.items():
        if v.shape[:2] != (h, w):
            raise NumericalError(f"{info.runner}: {k} came back {v.shape[:2]}, expected {(h, w)}")
    run = {"runner": info.runner, "device": device, "dtype": dtype, "steps": int(steps),
           "ensemble_size": int(settings.ensemble_size), "processing_resolution": int(res),
           "seed": int(settings.seed), "seconds": round(seconds, 3)}
    if note:
        run["note"] = note
    return PipelinePrediction(info.task, maps, run)
