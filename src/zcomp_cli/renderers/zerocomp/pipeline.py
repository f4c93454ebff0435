"""ZeroComp sampling loop (DDIM, v-prediction, no CFG), both passes in one batch."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zcomp_cli.renderers.zerocomp.dtype import check_finite

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


def vae_scale(vae) -> int:
    return 2 ** (len(vae.config.block_out_channels) - 1)


def run_pipeline(models, cond: np.ndarray, *, steps: int, seed: int, device: str, dtype) -> PipelineOutput:
    """cond: B x C x R x R float32 conditioning. One latent noise (from ``seed``) is shared
    by every batch element, as the official background/composite passes do."""
    import torch

    b, _, r, _ = cond.shape
    f = vae_scale(models.vae)
    with torch.no_grad():
        # 1. empty-prompt text embedding (constant ids, no tokenizer)
        ids = empty_prompt_ids(models.text_encoder.config.max_position_embeddings).to(device)
        emb = models.text_encoder(ids)[0].to(dtype).expand(b, -1, -1)
        # 2. scheduler
        sched = models.scheduler
        sched.set_timesteps(steps, device=device)
        # 3. one latent noise, reused for every pass (generated on CPU: device-independent)
        g = torch.Generator("cpu").manual_seed(int(seed))
        lat_ch = models.unet.config.in_channels
        noise = torch.randn((1, lat_ch, r // f, r // f), generator=g, dtype=torch.float32)
        latents = (noise * sched.init_noise_sigma).to(device, dtype).expand(b, -1, -1, -1).clone()
        c = torch.from_numpy(cond).to(device, dtype)
        # 4. denoising loop
        for t in sched.timesteps:
            x = sched.scale_model_input(latents, t)
            down, mid = models.controlnet(x, t, encoder_hidden_states=emb, controlnet_cond=c,
                                          conditioning_scale=1.0, return_dict=False)
            v = models.unet(x, t, encoder_hidden_states=emb, down_block_additional_residuals=down,
                            mid_block_additional_residual=mid, return_dict=False)[0]
            check_finite(v, f"UNet step t={int(t)}")
            latents = sched.step(v, t, latents, eta=0.0, return_dict=False)[0]
        # 5. decode
        img = models.vae.decode(latents / models.vae.config.scaling_factor, return_dict=False)[0]
        check_finite(img, "VAE decode")
        img = (img.float() / 2 + 0.5).clamp(0, 1)
    return PipelineOutput(img.permute(0, 2, 3, 1).cpu().numpy().astype(np.float32))
