"""Shared test helpers (a helper module, not a test file): tiny random Marigold pipelines
built the diffusers way (random components of Stable Diffusion 2's structure, shrunk)
and saved with ``save_pretrained``, so that zcomp loads them from disk exactly as it
would load the published weights.

The published families differ only in what ``model_index.json`` says and in the UNet's
input and output channels: ``4 * (1 + T)`` in and ``4 * T`` out for T predicted targets
(the Marigold trainer's ``_replace_unet_conv_in_out_multimodal``).
"""

from __future__ import annotations

import json
from pathlib import Path

# The pipelines' own settings, as the Marigold repository's training configs declare them
# (config/train_marigold_{depth,normals,iid_appearance,iid_lighting}.yaml, `pipeline.kwargs`;
# prediction_type / use_full_z_range as diffusers' pipelines register them).
APPEARANCE_TARGETS = {
    "target_names": ["albedo", "material"],
    "albedo": {"prediction_space": "srgb"},
    "material": {"prediction_space": "stack", "sub_target_names": ["roughness", "metallicity", None]},
    "roughness": {"prediction_space": "linear", "up_to_scale": False},
    "metallicity": {"prediction_space": "linear", "up_to_scale": False},
}
LIGHTING_TARGETS = {
    "target_names": ["albedo", "shading", "residual"],
    "albedo": {"prediction_space": "linear", "up_to_scale": False},
    "shading": {"prediction_space": "linear", "up_to_scale": True},
    "residual": {"prediction_space": "linear", "up_to_scale": True},
}
FAMILIES = {
    # name: (diffusers class, number of targets, pipeline config)
    "marigold-depth-v1-1": ("MarigoldDepthPipeline", 1, dict(
        prediction_type="depth", scale_invariant=True, shift_invariant=True,
        default_denoising_steps=4, default_processing_resolution=768)),
    "marigold-normals-v1-1": ("MarigoldNormalsPipeline", 1, dict(
        prediction_type="normals", use_full_z_range=True,
        default_denoising_steps=4, default_processing_resolution=768)),
    "marigold-iid-appearance-v1-1": ("MarigoldIntrinsicsPipeline", 2, dict(
        prediction_type="intrinsics", target_properties=APPEARANCE_TARGETS,
        default_denoising_steps=4, default_processing_resolution=768)),
    "marigold-iid-lighting-v1-1": ("MarigoldIntrinsicsPipeline", 3, dict(
        prediction_type="intrinsics", target_properties=LIGHTING_TARGETS,
        default_denoising_steps=4, default_processing_resolution=768)),
}
# SD 2's scheduler (v-prediction, scaled-linear betas) with the Marigold trainer's
# overrides: zero terminal SNR and trailing timesteps.
SCHEDULER = dict(num_train_timesteps=1000, beta_start=0.00085, beta_end=0.012, beta_schedule="scaled_linear",
                 prediction_type="v_prediction", clip_sample=False, set_alpha_to_one=False, steps_offset=1,
                 rescale_betas_zero_snr=True, timestep_spacing="trailing")


def tiny_tokenizer(folder: Path):
    """A CLIP BPE tokenizer with a handful of tokens (the pipelines only tokenize "")."""
    from transformers import CLIPTokenizer

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1, "a</w>": 2}
    (folder / "vocab.json").write_text(json.dumps(vocab))
    (folder / "merges.txt").write_text("#version: 0.2\n")
    return CLIPTokenizer(vocab_file=str(folder / "vocab.json"), merges_file=str(folder / "merges.txt"),
                         model_max_length=77)


def get_dummy_components(n_targets: int = 1, seed: int = 0, *, tokenizer_dir: Path, full_size: bool = False):
    """Random UNet, VAE (4 blocks: the latent grid is 8 px, as SD's), text encoder,
    tokenizer and DDIM scheduler, of SD 2's structure and tiny; ``full_size`` builds SD
    2's UNet and VAE at their real size (the published models' cost, random weights) and
    a 1-layer text encoder of SD 2's width (it runs once per load)."""
    import torch
    from diffusers import AutoencoderKL, DDIMScheduler, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel

    torch.manual_seed(seed)
    if full_size:  # stabilityai/stable-diffusion-2(-1) unet/config.json and vae/config.json
        unet = UNet2DConditionModel(
            sample_size=96, in_channels=4 * (n_targets + 1), out_channels=4 * n_targets, layers_per_block=2,
            block_out_channels=(320, 640, 1280, 1280), attention_head_dim=(5, 10, 20, 20),
            cross_attention_dim=1024, use_linear_projection=True,
            down_block_types=("CrossAttnDownBlock2D",) * 3 + ("DownBlock2D",),
            up_block_types=("UpBlock2D",) + ("CrossAttnUpBlock2D",) * 3)
        vae = AutoencoderKL(block_out_channels=(128, 256, 512, 512), latent_channels=4,
                            down_block_types=("DownEncoderBlock2D",) * 4, up_block_types=("UpDecoderBlock2D",) * 4,
                            layers_per_block=2, sample_size=768, scaling_factor=0.18215)
        te_cfg = dict(vocab_size=16, hidden_size=1024, intermediate_size=4096, num_attention_heads=16,
                      num_hidden_layers=1)
    else:
        unet = UNet2DConditionModel(
            block_out_channels=(8, 16), layers_per_block=1, sample_size=8, in_channels=4 * (n_targets + 1),
            out_channels=4 * n_targets, down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
            up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"), cross_attention_dim=16, attention_head_dim=2,
            norm_num_groups=4, use_linear_projection=True)
        vae = AutoencoderKL(block_out_channels=(8, 8, 8, 8), in_channels=3, out_channels=3,
                            down_block_types=("DownEncoderBlock2D",) * 4, up_block_types=("UpDecoderBlock2D",) * 4,
                            latent_channels=4, norm_num_groups=4, sample_size=32, layers_per_block=1,
                            scaling_factor=0.18215)
        te_cfg = dict(vocab_size=16, hidden_size=16, intermediate_size=16, num_attention_heads=2,
                      num_hidden_layers=1)
    te = CLIPTextModel(CLIPTextConfig(max_position_embeddings=77, projection_dim=16, bos_token_id=0,
                                      eos_token_id=1, pad_token_id=1, **te_cfg))
    return dict(unet=unet, vae=vae, text_encoder=te, tokenizer=tiny_tokenizer(tokenizer_dir),
                scheduler=DDIMScheduler(**SCHEDULER))


def save_pipeline(folder: Path, family: str = "marigold-normals-v1-1", *, seed: int = 0, full_size: bool = False,
                  **overrides) -> Path:
    """Build a tiny (or ``full_size``) pipeline of ``family`` (see FAMILIES),
    ``save_pretrained`` it into ``folder`` and return the folder. ``overrides`` replace
    entries of its config."""
    import diffusers

    cls_name, n, config = FAMILIES[family]
    folder = Path(folder)
    comps = get_dummy_components(n, seed, tokenizer_dir=folder.parent / f"{folder.name}_tok", full_size=full_size)
    pipe = getattr(diffusers, cls_name)(**comps, **{**config, **overrides})
    pipe.save_pretrained(folder)
    return folder
