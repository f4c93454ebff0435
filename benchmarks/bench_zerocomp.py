"""zerocomp throughput: official-style loop vs zcomp's batched path, in one run.

Models: the full-size SD 2.1 (768-v) UNet, an 11-channel ControlNet made from it and the
SD VAE, with random weights (configs built here, nothing downloaded; same FLOPs as the
real checkpoints). The text encoder runs once per process (its output is cached), so a
1-layer stand-in of the right width is used.

* official-style: for each job, two unbatched passes (background, composite), fp16
  weights under ``torch.autocast(float16)`` (the official setting), full frame
  conditioning at ``--res`` prepared in advance (its CPU cost is not counted), DDIM.
* zcomp: ``ZeroCompRenderer.render_jobs`` on all jobs at once (4:3 frames, square
  window, conditioning built on a CPU thread and counted), ``batch_size`` jobs (x 2
  passes) per UNet/ControlNet call, bf16 (GPU) / fp32 (CPU), SDPA, channels_last (GPU),
  optional ``torch.compile``.

Reported per mode: jobs/s, s/job, peak GPU memory, achieved TFLOP/s and its fraction of the
device's dense bf16 peak (FLOPs counted once with ``torch.utils.flop_counter`` on one
ControlNet+UNet step and one VAE decode at batch 1, then multiplied by passes x steps).

Needs: torch, diffusers, transformers, numpy, opencv (``cv2``), scipy; not bpy. On a bare
GPU host, from the repository root:

    pip install "numpy<2" diffusers transformers opencv-python-headless scipy
    PYTHONPATH=src python benchmarks/bench_zerocomp.py --device cuda --res 512 --steps 20 \\
        --jobs 16 --batch-sizes 1,4,8,16 --json bench_zerocomp_gpu.json

CPU (what was run without a GPU; reduced size, numbers are only relative):

    PYTHONPATH=src python benchmarks/bench_zerocomp.py --device cpu --res 128 --steps 2 \\
        --jobs 2 --batch-sizes 1,2 --warmup 0
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

# dense bf16 tensor-core peaks (TFLOP/s), by substring of torch.cuda.get_device_name()
BF16_PEAK_TFLOPS = {"H200": 989.4, "H100 PCIe": 756.0, "H100": 989.4, "A100": 312.0,
                    "L40S": 362.0, "A10G": 70.0, "L4": 121.0, "RTX 4090": 165.2}


def build_models(device, dtype, channels=11):
    import torch
    from diffusers import AutoencoderKL, ControlNetModel, DDIMScheduler, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel

    from zcomp_cli.renderers.zerocomp.loading import ZeroCompModels

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
    te = CLIPTextModel(CLIPTextConfig(vocab_size=49408, hidden_size=1024, num_hidden_layers=1,
                                      num_attention_heads=16, intermediate_size=4096))
    sched = DDIMScheduler(beta_schedule="scaled_linear", beta_start=0.00085, beta_end=0.012,
                          prediction_type="v_prediction", timestep_spacing="trailing",
                          rescale_betas_zero_snr=True, clip_sample=False)
    for m in (unet, cn, vae, te):
        m.to(device=device, dtype=dtype).eval().requires_grad_(False)
    return ZeroCompModels(unet, cn, vae, te, sched)


def count_flops(models, res, device, dtype):
    """(FLOPs of one ControlNet+UNet step, FLOPs of one VAE decode) at batch 1, counted
    with ``torch.utils.flop_counter`` while the classic (bmm + softmax) attention runs, so
    attention matmuls are counted whatever fused SDPA kernel the device would pick."""
    import torch
    from diffusers.models.attention_processor import AttnProcessor
    from torch.utils.flop_counter import FlopCounterMode

    mods = (models.unet, models.controlnet, models.vae)
    saved = [m.attn_processors for m in mods]
    for m in mods:
        m.set_attn_processor(AttnProcessor())
    f = 2 ** (len(models.vae.config.block_out_channels) - 1)
    lat = torch.randn(1, 4, res // f, res // f, device=device, dtype=dtype)
    cond = torch.rand(1, models.conditioning_channels, res, res, device=device, dtype=dtype)
    emb = torch.randn(1, 77, models.unet.config.cross_attention_dim, device=device, dtype=dtype)
    t = torch.tensor([999], device=device)
    try:
        with torch.inference_mode():
            with FlopCounterMode(display=False) as fc:
                down, mid = models.controlnet(lat, t, encoder_hidden_states=emb,
                                              controlnet_cond=cond, return_dict=False)
                models.unet(lat, t, encoder_hidden_states=emb, down_block_additional_residuals=down,
                            mid_block_additional_residual=mid, return_dict=False)
            step = fc.get_total_flops()
            with FlopCounterMode(display=False) as fc:
                models.vae.decode(lat, return_dict=False)
            vae = fc.get_total_flops()
    finally:
        for m, p in zip(mods, saved):
            m.set_attn_processor(p)
    return step, vae


def make_jobs(n, res, seed=0):
    """n jobs, each [background, composite] requests on 4:3 frames whose short side is
    ``res`` (the window is then res x res: no resize, like the official full frame)."""
    from zcomp_cli.camera import Camera
    from zcomp_cli.conventions import K_from_fov
    from zcomp_cli.maps import SceneMaps
    from zcomp_cli.renderers.base import RenderRequest

    h, w = res, res * 4 // 3
    rng = np.random.default_rng(seed)
    jobs = []
    for j in range(n):
        n3 = rng.normal(size=(h, w, 3)).astype(np.float32) + (0, 0, 2)
        n3 /= np.linalg.norm(n3, axis=-1, keepdims=True)
        bg = SceneMaps(rng.uniform(1, 5, (h, w)).astype(np.float32), n3,
                       rng.uniform(0.1, 0.9, (h, w, 3)).astype(np.float32))
        comp = SceneMaps(bg.depth.copy(), bg.normals.copy(), bg.albedo.copy())
        roi = (w // 4, h // 4, 3 * w // 4, 3 * h // 4)
        comp.albedo[roi[1]:roi[3], roi[0]:roi[2]] = 0.6
        known = np.ones((h, w), bool)
        known[roi[1]:roi[3], roi[0]:roi[2]] = False
        sh = rng.uniform(0.3, 2.0, (h, w, 3)).astype(np.float32)
        cam = Camera(K_from_fov(50, w, h), w, h)
        jobs.append([RenderRequest(m, sh, known, cam, roi=roi, image=sh * bg.albedo) for m in (bg, comp)])
    return jobs


def main():
    import copy

    import torch

    from zcomp_cli.renderers.zerocomp import ZeroCompRenderer
    from zcomp_cli.renderers.zerocomp.conditioning import build_conditioning
    from zcomp_cli.renderers.zerocomp.dtype import autocast_context, resolve_device, resolve_dtype
    from zcomp_cli.renderers.zerocomp.pipeline import optimise_models, run_pipeline

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="auto")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=16)
    ap.add_argument("--batch-sizes", default="1,4,8,16",
                    help="jobs per UNet/ControlNet call (x 2 passes each)")
    ap.add_argument("--zcomp-dtype", default="auto", help="auto = bf16 on GPU, fp32 on CPU")
    ap.add_argument("--official-dtype", default=None,
                    help="default fp16-autocast on GPU, fp32 on CPU (CPU fp16 is not representative)")
    ap.add_argument("--compile", action="store_true", help="also time zcomp with torch.compile")
    ap.add_argument("--warmup", type=int, default=1, help="warm-up jobs per mode (not timed)")
    ap.add_argument("--peak-tflops", type=float, default=None, help="bf16 peak; default by GPU name")
    ap.add_argument("--json", default=None, help="also write the results here")
    a = ap.parse_args()

    dev = resolve_device(a.device)
    cuda = dev.startswith("cuda")
    off_setting = a.official_dtype or ("fp16-autocast" if cuda else "fp32")
    off_dtype = resolve_dtype(off_setting, dev)
    zc_dtype = resolve_dtype(a.zcomp_dtype, dev)
    name = torch.cuda.get_device_name() if cuda else f"cpu ({os.cpu_count()} threads visible)"
    peak = a.peak_tflops
    if peak is None and cuda:
        peak = next((v for k, v in BF16_PEAK_TFLOPS.items() if k in name), None)
    bss = [int(b) for b in a.batch_sizes.split(",")]

    t = time.perf_counter()
    base = build_models("cpu", torch.float32)
    build_s = time.perf_counter() - t
    off_models = base if not cuda else build_like(base, dev, off_dtype)
    step_flops, vae_flops = count_flops(off_models, a.res, dev, off_dtype)
    job_flops = 2 * (a.steps * step_flops + vae_flops)
    results = {"device": name, "res": a.res, "steps": a.steps, "jobs": a.jobs,
               "official_dtype": off_setting, "zcomp_dtype": str(zc_dtype),
               "torch": torch.__version__, "flops_per_job": job_flops, "bf16_peak_tflops": peak,
               "model_build_s": build_s, "modes": []}

    def sync():
        if cuda:
            torch.cuda.synchronize()

    def record(label, seconds, batch):
        r = {"mode": label, "batch_jobs": batch, "passes_per_call": 2 * batch if batch else 1, "seconds": seconds,
             "jobs_per_s": a.jobs / seconds, "s_per_job": seconds / a.jobs,
             "achieved_tflops": job_flops * a.jobs / seconds / 1e12}
        if cuda:
            r["peak_gpu_GiB"] = torch.cuda.max_memory_allocated() / 2 ** 30
        if peak:
            r["frac_bf16_peak"] = r["achieved_tflops"] / peak
        results["modes"].append(r)
        print(json.dumps(r), flush=True)

    jobs = make_jobs(a.jobs, a.res)
    seeds = [469] * a.jobs

    # 1. official-style: per job, two unbatched passes; conditioning prepared beforehand
    conds = [build_conditioning(q, 11, a.res)[None] for j in jobs for q in j]

    def official(n_jobs):
        for c in conds[:2 * n_jobs]:
            run_pipeline(off_models, c, steps=a.steps, seed=469, device=dev, dtype=off_dtype,
                         autocast=autocast_context(off_setting, dev), vae_batch=1)

    if a.warmup:
        official(a.warmup)
    if cuda:
        torch.cuda.reset_peak_memory_stats()
    sync(); t = time.perf_counter(); official(a.jobs); sync()
    record(f"official ({off_setting}, unbatched)", time.perf_counter() - t, 0)
    if cuda:
        del off_models
        torch.cuda.empty_cache()

    # 2. zcomp: the renderer on all requests at once
    zc_models = build_like(base, dev, zc_dtype) if cuda else base
    optimise_models(zc_models, channels_last=cuda, compile=False)
    variants = [(bs, False) for bs in bss] + ([(max(bss), True)] if a.compile else [])
    for bs, comp in variants:
        r = ZeroCompRenderer(steps=a.steps, device=dev, dtype=a.zcomp_dtype, batch_size=bs,
                             resolution=a.res)
        m = zc_models
        if comp:
            m = copy.copy(zc_models)
            m.cache = {}
            optimise_models(m, channels_last=False, compile=True)
        r._models, r._device, r._dtype = m, dev, zc_dtype
        if a.warmup:
            n = max(a.warmup, bs)
            r.render_jobs(jobs[:n], seeds[:n])
        if cuda:
            torch.cuda.reset_peak_memory_stats()
        sync(); t = time.perf_counter(); outs = r.render_jobs(jobs, seeds); sync()
        record(f"zcomp ({zc_dtype}, batch {bs} jobs{', compiled' if comp else ''})",
               time.perf_counter() - t, bs)
        results["modes"][-1]["cpu_conditioning_s"] = sum(o.timings["conditioning_cpu"] for o in outs)
    off = results["modes"][0]["jobs_per_s"]
    for r in results["modes"]:
        r["speedup_vs_official"] = r["jobs_per_s"] / off
    print_table(results)
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1))


def build_like(base, device, dtype):
    """A copy of the CPU fp32 models on ``device`` in ``dtype`` (same random weights)."""
    import copy

    m = copy.deepcopy(base)
    for mod in (m.unet, m.controlnet, m.vae, m.text_encoder):
        mod.to(device=device, dtype=dtype)
    m.cache = {}
    return m


def print_table(res):
    print(f"\n{res['device']}, {res['res']}x{res['res']}, {res['steps']} steps, {res['jobs']} jobs, "
          f"{res['flops_per_job'] / 1e12:.2f} TFLOP/job")
    print("| mode | passes/call | jobs/s | s/job | peak GPU GiB | TFLOP/s | frac bf16 peak | speedup |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in res["modes"]:
        mem = f"{r['peak_gpu_GiB']:.1f}" if "peak_gpu_GiB" in r else "n/a (CPU)"
        frac = f"{r['frac_bf16_peak']:.1%}" if "frac_bf16_peak" in r else "n/a"
        print(f"| {r['mode']} | {r['passes_per_call']} | {r['jobs_per_s']:.4f} | {r['s_per_job']:.2f} | "
              f"{mem} | {r['achieved_tflops']:.3f} | {frac} | {r['speedup_vs_official']:.2f}x |")


if __name__ == "__main__":
    main()
