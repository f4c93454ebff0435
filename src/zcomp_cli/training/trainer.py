"""ZeroComp ControlNet training loop: only the ControlNet trains (initialised from the base
UNet), MSE on v, AdamW, gradient clipping; checkpoints in the official layout
``<out>/checkpoint-<step>/controlnet/`` plus ``optimizer.pt`` and ``state.json`` for resume."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from zcomp_cli.conventions import GAMMA
from zcomp_cli.errors import NumericalError, UsageError
from zcomp_cli.training.config import TrainConfig


@dataclass
class TrainResult:
    step: int
    losses: list
    last_checkpoint: Path | None


def _latest_checkpoint(out: Path) -> Path | None:
    ck = sorted(out.glob("checkpoint-*"), key=lambda p: int(p.name.split("-")[1]))
    return ck[-1] if ck else None


def make_batch(samples, rng, cfg: TrainConfig, channels: int):
    """-> (target images B x 3 x R x R in [-1, 1] gamma-2.2, conditioning B x C x R x R).

    Each sample is cut to a random short-side square (the official short-side resize and
    random crop; never squashed), the same window for the target and the conditioning.
    Shading follows the official loader of the layout: OpenRooms feeds linear image /
    linear albedo; the other layouts use the inference encoding (gamma image / albedo)."""
    from zcomp_cli.camera import Camera
    from zcomp_cli.conventions import K_from_fov
    from zcomp_cli.maps import SceneMaps
    from zcomp_cli.renderers.base import RenderRequest
    from zcomp_cli.renderers.zerocomp.conditioning import (
        build_conditioning,
        linear_shading,
        resize_square,
        take_window,
    )
    from zcomp_cli.training.masks import random_shading_mask

    R = cfg.resolution
    encoding = "linear" if cfg.layout == "openrooms" else "inference"
    imgs, conds = [], []
    for s in samples:
        h, w = s["depth"].shape
        side = min(h, w)
        x0, y0 = int(rng.integers(0, w - side + 1)), int(rng.integers(0, h - side + 1))
        box = (x0, y0, x0 + side, y0 + side)
        masked, _ = random_shading_mask(side, side, rng)
        known = np.ones((h, w), bool)
        known[y0:y0 + side, x0:x0 + side] = ~masked
        alb = np.clip(s["albedo"], 0, 1)
        img = np.clip(s["image"], 0, None)
        shading = linear_shading(img, alb)
        maps = SceneMaps(s["depth"], s["normals"], alb, s.get("roughness"), s.get("metallic"))
        req = RenderRequest(maps, shading, known, Camera(K_from_fov(50, w, h), w, h), image=img)
        conds.append(build_conditioning(req, channels, R, box, shading=encoding))
        tgt = resize_square(take_window(np.clip(img, 0, 1) ** (1 / GAMMA), box), R)
        imgs.append(tgt.transpose(2, 0, 1) * 2 - 1)
    return np.stack(imgs).astype(np.float32), np.stack(conds)


def train(cfg: TrainConfig, *, progress: Callable[[str, int, int, str], None] | None = None) -> TrainResult:
    """Train the ControlNet. ``progress(stage, done, total, label)`` is called after every
    step with stage "training" (the same callback the batch commands use)."""
    import torch
    from diffusers import AutoencoderKL, ControlNetModel, UNet2DConditionModel
    from transformers import CLIPTextModel

    from zcomp_cli.renderers.zerocomp.dtype import resolve_device
    from zcomp_cli.renderers.zerocomp.loading import resolve_paths, scheduler_from_base
    from zcomp_cli.renderers.zerocomp.pipeline import empty_prompt_ids
    from zcomp_cli.training.datasets import open_dataset

    # 1. data and models
    ds = open_dataset(cfg.layout, cfg.data_root, channels=cfg.channels)
    out = Path(cfg.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    base = Path(cfg.base)
    from zcomp_cli.estimators.weights import check_folder_safety

    check_folder_safety(base, "training base")  # no model folder's own code runs
    device = resolve_device(cfg.device)
    kw = dict(local_files_only=True)
    unet = UNet2DConditionModel.from_pretrained(str(base), subfolder="unet", **kw).to(device)
    vae = AutoencoderKL.from_pretrained(str(base), subfolder="vae", **kw).to(device)
    te = CLIPTextModel.from_pretrained(str(base), subfolder="text_encoder", **kw).to(device)
    sched = scheduler_from_base(base)
    for m in (unet, vae, te):
        m.requires_grad_(False).eval()
    resume = _latest_checkpoint(out) if cfg.resume == "latest" else (Path(cfg.resume) if cfg.resume else None)
    step = 0
    if resume is not None:
        cdir, _ = resolve_paths(resume, base)
        cn = ControlNetModel.from_pretrained(str(cdir), **kw)
        step = json.loads((resume / "state.json").read_text())["step"]
    else:
        # the conditioning embedding must downsample like the VAE (x8 for SD 2.1)
        n = len(vae.config.block_out_channels)
        cn = ControlNetModel.from_unet(unet, conditioning_channels=cfg.channels,
                                       conditioning_embedding_out_channels=(16, 32, 96, 256)[:n])
    if cn.config.conditioning_channels != cfg.channels:
        raise UsageError(f"resume checkpoint has {cn.config.conditioning_channels} channels, "
                         f"config 'channels' says {cfg.channels}")
    cn.to(device).train()
    opt = torch.optim.AdamW(cn.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    if resume is not None and (resume / "optimizer.pt").is_file():
        opt.load_state_dict(torch.load(resume / "optimizer.pt", map_location=device))
    torch.manual_seed(cfg.seed + step)
    rng = np.random.default_rng(cfg.seed + step)
    with torch.no_grad():
        emb = te(empty_prompt_ids(te.config.max_position_embeddings).to(device))[0]
    T = sched.config.num_train_timesteps
    losses, last = [], None
    log_f = open(out / "loss_log.tsv", "a")
    try:
        # 2. loop
        while step < cfg.max_steps:
            idx = rng.integers(0, len(ds), cfg.batch_size)
            tgt, cond = make_batch([ds[int(i)] for i in idx], rng, cfg, cfg.channels)
            with torch.no_grad():
                lat = vae.encode(torch.from_numpy(tgt).to(device)).latent_dist.sample()
                lat = lat * vae.config.scaling_factor
            noise = torch.randn_like(lat)
            t = torch.randint(0, T, (lat.shape[0],), device=device)
            noisy = sched.add_noise(lat, noise, t)
            v_target = sched.get_velocity(lat, noise, t)
            e = emb.expand(lat.shape[0], -1, -1)
            down, mid = cn(noisy, t, encoder_hidden_states=e,
                           controlnet_cond=torch.from_numpy(cond).to(device), return_dict=False)
            v = unet(noisy, t, encoder_hidden_states=e, down_block_additional_residuals=down,
                     mid_block_additional_residual=mid, return_dict=False)[0]
            loss = torch.nn.functional.mse_loss(v.float(), v_target.float())
            if not torch.isfinite(loss):
                raise NumericalError(f"training loss is non-finite at step {step}")
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(cn.parameters(), cfg.grad_clip)
            opt.step()
            step += 1
            loss = loss.detach()
            losses.append(float(loss))
            log_f.write(f"{step}\t{float(loss):.6g}\n")
            if progress is not None:
                progress("training", step, cfg.max_steps, f"loss {float(loss):.4f}")
            if step % cfg.save_every == 0 or step == cfg.max_steps:
                last = save_checkpoint(out, step, cn, opt)
    finally:
        log_f.close()
    return TrainResult(step, losses, last)


def save_checkpoint(out: Path, step: int, cn, opt) -> Path:
    import torch

    d = out / f"checkpoint-{step}"
    cn.save_pretrained(d / "controlnet", safe_serialization=True)
    torch.save(opt.state_dict(), d / "optimizer.pt")
    (d / "state.json").write_text(json.dumps({"step": step}))
    return d
