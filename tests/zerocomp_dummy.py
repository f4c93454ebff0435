"""Shared zerocomp test helpers (a helper module, not a test file): tiny random
SD-2.1-shaped components saved in the official on-disk layout, and random requests."""

from __future__ import annotations

from pathlib import Path


def get_dummy_components(channels: int = 11, seed: int = 0):
    import torch
    from diffusers import AutoencoderKL, ControlNetModel, DDIMScheduler, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel

    torch.manual_seed(seed)
    unet = UNet2DConditionModel(
        block_out_channels=(8, 16), layers_per_block=1, sample_size=8, in_channels=4,
        out_channels=4, down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
        up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"), cross_attention_dim=32,
        attention_head_dim=2, norm_num_groups=4)
    cn = ControlNetModel.from_unet(unet, conditioning_channels=channels,
                                   conditioning_embedding_out_channels=(4, 8))
    # Random (non-zero) zero-convs so the conditioning actually changes the output.
    with torch.no_grad():
        for blk in list(cn.controlnet_down_blocks) + [cn.controlnet_mid_block]:
            blk.weight.normal_(0, 0.1)
        cn.controlnet_cond_embedding.conv_out.weight.normal_(0, 0.1)
    vae = AutoencoderKL(block_out_channels=(8, 16), in_channels=3, out_channels=3,
                        down_block_types=("DownEncoderBlock2D",) * 2,
                        up_block_types=("UpDecoderBlock2D",) * 2, latent_channels=4,
                        norm_num_groups=4, sample_size=16)
    te = CLIPTextModel(CLIPTextConfig(vocab_size=49408, hidden_size=32, intermediate_size=37,
                                      num_attention_heads=4, num_hidden_layers=2,
                                      max_position_embeddings=77, projection_dim=32))
    sched = DDIMScheduler(beta_schedule="scaled_linear", beta_start=0.00085, beta_end=0.012,
                          prediction_type="v_prediction", clip_sample=False,
                          set_alpha_to_one=False, steps_offset=1)
    return dict(unet=unet, controlnet=cn, vae=vae, text_encoder=te, scheduler=sched)


def save_dummy(root: Path, channels: int = 11, seed: int = 0) -> tuple[Path, Path]:
    """Returns (controlnet_ckpt_dir, base_dir)."""
    comps = get_dummy_components(channels, seed)
    base, ckpt = Path(root) / "sd21", Path(root) / f"ckpt{channels}"
    for k in ("unet", "vae", "text_encoder", "scheduler"):
        comps[k].save_pretrained(base / k)
    comps["controlnet"].save_pretrained(ckpt / "controlnet")
    return ckpt, base


H, W = 24, 32


def random_request(seed=0, rough=False, known=None):
    """A random (H, W) request with a masked rectangle and roi (10, 8, 20, 16)."""
    import numpy as np

    from zcomp_cli.camera import Camera
    from zcomp_cli.conventions import K_from_fov
    from zcomp_cli.maps import SceneMaps
    from zcomp_cli.renderers.base import RenderRequest

    rng = np.random.default_rng(seed)
    n = rng.normal(size=(H, W, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    maps = SceneMaps(depth=rng.uniform(0.5, 5, (H, W)).astype(np.float32), normals=n,
                     albedo=rng.uniform(0.1, 0.9, (H, W, 3)).astype(np.float32),
                     roughness=np.full((H, W), 0.3, np.float32) if rough else None,
                     metallic=np.full((H, W), 0.7, np.float32) if rough else None)
    if known is None:
        known = np.ones((H, W), bool)
        known[8:16, 10:20] = False
    shading = rng.uniform(0.2, 2.0, (H, W, 3)).astype(np.float32)
    cam = Camera(K_from_fov(50, W, H), W, H)
    return RenderRequest(maps, shading, known, cam, roi=(10, 8, 20, 16))
