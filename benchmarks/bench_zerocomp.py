"""Time one zerocomp job (background + composite passes) with random weights of the
full SD 2.1 architecture (UNet + 11-channel ControlNet + VAE; same FLOPs as the real model).

official: two separate unbatched passes, full frame.  zcomp: both passes in one batch
(crop mode resizes the crop to the same model resolution, so it changes quality, not cost).

  python benchmarks/bench_zerocomp.py --device cpu --steps 1 --res 256
  python benchmarks/bench_zerocomp.py --device cuda --steps 20 --res 512 --dtype bf16
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def build_models(device, dtype, channels=11):
    import torch
    from diffusers import AutoencoderKL, ControlNetModel, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel

    from zcomp_cli.renderers.zerocomp.loading import ZeroCompModels
    from diffusers import DDIMScheduler

    torch.manual_seed(0)
    unet = UNet2DConditionModel(  # SD 2.1 (768-v) UNet config
        sample_size=96, in_channels=4, out_channels=4, layers_per_block=2,
        block_out_channels=(320, 640, 1280, 1280), attention_head_dim=(5, 10, 20, 20),
        cross_attention_dim=1024, use_linear_projection=True,
        down_block_types=("CrossAttnDownBlock2D",) * 3 + ("DownBlock2D",),
        up_block_types=("UpBlock2D",) + ("CrossAttnUpBlock2D",) * 3)
    cn = ControlNetModel.from_unet(unet, conditioning_channels=channels)
    vae = AutoencoderKL(block_out_channels=(128, 256, 512, 512), latent_channels=4,
                        down_block_types=("DownEncoderBlock2D",) * 4,
                        up_block_types=("UpDecoderBlock2D",) * 4, layers_per_block=2,
                        scaling_factor=0.18215)
    # the text encoder runs once per job; a 1-layer stand-in of the right width suffices
    te = CLIPTextModel(CLIPTextConfig(vocab_size=49408, hidden_size=1024, num_hidden_layers=1,
                                      num_attention_heads=16, intermediate_size=4096))
    sched = DDIMScheduler(beta_schedule="scaled_linear", beta_start=0.00085, beta_end=0.012,
                          prediction_type="v_prediction", timestep_spacing="trailing",
                          rescale_betas_zero_snr=True, clip_sample=False)
    for m in (unet, cn, vae, te):
        m.to(device=device, dtype=dtype).eval().requires_grad_(False)
    return ZeroCompModels(unet, cn, vae, te, sched)


def main():
    import torch

    from zcomp_cli.renderers.zerocomp.dtype import resolve_device, resolve_dtype
    from zcomp_cli.renderers.zerocomp.pipeline import run_pipeline

    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="auto")
    ap.add_argument("--dtype", default="auto")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=1)
    a = ap.parse_args()
    dev = resolve_device(a.device)
    dt = resolve_dtype(a.dtype, dev)
    models = build_models(dev, dt)
    rng = np.random.default_rng(0)
    cond = rng.uniform(-1, 1, (2, 11, a.res, a.res)).astype(np.float32)

    def sync():
        if dev.startswith("cuda"):
            torch.cuda.synchronize()

    def official():
        for i in range(2):
            run_pipeline(models, cond[i:i + 1], steps=a.steps, seed=469, device=dev, dtype=dt)

    def zcomp():
        run_pipeline(models, cond, steps=a.steps, seed=469, device=dev, dtype=dt)

    res = {"device": dev, "dtype": str(dt), "steps": a.steps, "res": a.res}
    official()  # warm-up (kernels, allocator)
    for name, fn in (("official_s", official), ("zcomp_s", zcomp)):
        if dev.startswith("cuda"):
            torch.cuda.reset_peak_memory_stats()
        ts = []
        for _ in range(a.repeats):
            sync(); t = time.perf_counter(); fn(); sync()
            ts.append(time.perf_counter() - t)
        res[name] = min(ts)
        if dev.startswith("cuda"):
            res[name.replace("_s", "_peak_GiB")] = torch.cuda.max_memory_allocated() / 2 ** 30
    res["speedup"] = res["official_s"] / res["zcomp_s"]
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
