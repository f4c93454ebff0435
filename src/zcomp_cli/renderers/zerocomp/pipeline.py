"""ZeroComp sampling loop (DDIM, v-prediction, no CFG): any number of passes (a chunk of
jobs x their background and composite passes) denoised in one batch."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zcomp_cli.renderers.zerocomp.dtype import check_conditioning, check_finite

# SD 2.1's (OpenCLIP-derived) tokenizer on "": <|startoftext|>=49406, <|endoftext|>=49407,
# then padding with pad_token "!" whose id is 0 (SD 1.x pads with 49407 instead).
BOS_ID, EOS_ID, PAD_ID, MAX_LEN = 49406, 49407, 0, 77


def empty_prompt_ids(max_len: int = MAX_LEN):
    import torch

    ids = [BOS_ID, EOS_ID] + [PAD_ID] * (max_len - 2)
    return torch.tensor([ids], dtype=torch.long)


@dataclass
class PipelineOutput:
    images: np.ndarray  # B x R x R x 3 float32, gamma-2.2 encoded [0, 1]
    latents: np.ndarray | None = None  # B x 4 x R/f x R/f float32, the denoised latents (before decoding)


def vae_scale(vae) -> int:
    return 2 ** (len(vae.config.block_out_channels) - 1)


def optimise_models(models, *, channels_last: bool = True, compile: bool = False) -> None:
    """One-time speed settings: SDPA attention (fused flash/memory-efficient kernels),
    channels_last convolutions, and optionally ``torch.compile`` of the UNet and ControlNet
    (long first call; worth it for large batches of jobs)."""
    import torch
    from diffusers.models.attention_processor import AttnProcessor2_0

    for m in (models.unet, models.controlnet, models.vae):
        m.set_attn_processor(AttnProcessor2_0())
        if channels_last:
            m.to(memory_format=torch.channels_last)
    if compile:
        models.unet = torch.compile(models.unet)
        models.controlnet = torch.compile(models.controlnet)


def initial_noise(seed: int, shape, dtype=None):
    """The latent noise of one pass, drawn on the CPU from ``seed`` (device-independent).
    Every pass of every job in a call gets this same tensor, so a job's result does not
    depend on which other jobs share its batch."""
    import torch

    g = torch.Generator("cpu").manual_seed(int(seed))
    return torch.randn(tuple(shape), generator=g, dtype=torch.float32)


def run_pipeline(models, cond: np.ndarray, *, steps: int, seed, device: str, dtype,
                 autocast=None, vae_batch: int = 4) -> PipelineOutput:
    """cond: B x C x R x R float32 conditioning, B passes denoised together (one
    UNet/ControlNet call per step).

    seed: one int (every pass gets the noise of that seed, as the official background and
    composite passes share one noise) or B ints (pass i gets the noise of ``seed[i]``: the
    passes of one job share its seed, so batching jobs changes no job's noise).

    autocast: an optional context manager (``dtype.autocast_context``) around the models.
    vae_batch: passes decoded at once (the VAE decoder at 512 px is memory-hungry)."""
    import contextlib

    import torch

    b, _, r, _ = cond.shape
    f = vae_scale(models.vae)
    ctx = autocast if autocast is not None else contextlib.nullcontext()
    with torch.inference_mode(), ctx:
        # 1. empty-prompt text embedding (constant ids, no tokenizer), cached per device
        key = ("emb", str(device), str(dtype))
        if key not in models.cache:
            ids = empty_prompt_ids(models.text_encoder.config.max_position_embeddings).to(device)
            models.cache[key] = models.text_encoder(ids)[0].to(dtype)
        emb = models.cache[key].expand(b, -1, -1)
        # 2. scheduler
        sched = models.scheduler
        sched.set_timesteps(steps, device=device)
        # 3. one latent noise, reused for every pass
        lat_ch = models.unet.config.in_channels
        seeds = [int(seed)] * b if np.ndim(seed) == 0 else [int(v) for v in seed]
        if len(seeds) != b:
            raise ValueError(f"run_pipeline: {len(seeds)} seeds for {b} passes")
        shape = (1, lat_ch, r // f, r // f)
        by_seed = {v: initial_noise(v, shape) for v in set(seeds)}
        noise = torch.cat([by_seed[v] for v in seeds])
        # the sampler's state in fp32 whatever the models' dtype: in bf16 (8 bits of
        # mantissa) each step's update rounded the latent, and the error grew with the
        # steps (5.7 % at 200 steps against 2.2 % at 50: the stability sweep, issue 49).
        # fp16-autocast (``autocast`` given) keeps the official pipeline's state dtype.
        state = dtype if autocast is not None else torch.float32
        latents = (noise * sched.init_noise_sigma).to(device, state)
        check_conditioning(cond, dtype)  # (fp16: a depth past 65 km would be Inf)
        c = torch.from_numpy(cond).to(device, dtype, non_blocking=True)
        # 4. denoising loop
        for t in sched.timesteps:
            x = sched.scale_model_input(latents, t).to(dtype)
            down, mid = models.controlnet(x, t, encoder_hidden_states=emb, controlnet_cond=c,
                                          conditioning_scale=1.0, return_dict=False)
            v = models.unet(x, t, encoder_hidden_states=emb, down_block_additional_residuals=down,
                            mid_block_additional_residual=mid, return_dict=False)[0]
            check_finite(v, f"UNet step t={int(t)}")
            latents = sched.step(v.to(latents.dtype), t, latents, eta=0.0, return_dict=False)[0]
        # 5. decode, a few passes at a time
        imgs = []
        for i in range(0, b, max(1, int(vae_batch))):
            lat = latents[i:i + vae_batch] / models.vae.config.scaling_factor
            img = models.vae.decode(lat.to(dtype), return_dict=False)[0]
            check_finite(img, "VAE decode")
            imgs.append((img.float() / 2 + 0.5).clamp(0, 1).permute(0, 2, 3, 1).cpu())
    return PipelineOutput(torch.cat(imgs).numpy().astype(np.float32), latents.float().cpu().numpy())
