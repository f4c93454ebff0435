"""A synthetic output folder for ``zcomp report``'s benchmark and tests: job folders
with report.json files shaped as the pipeline writes them (about 15 kB each, the
physical renderer's light summary included), a tiny composite.png per finished job, a
summary.json listing done and failed jobs, an eval.json, and the jobs.yaml the reports
name (its scenes' photographs are the backgrounds). No rendering: thousands of jobs
in seconds."""

from __future__ import annotations

import hashlib
import json
import random
import zlib
from pathlib import Path


def tiny_png(rgb: tuple[int, int, int], width: int = 16, height: int = 12) -> bytes:
    """A valid solid-colour 8-bit RGB PNG (no image library: fast)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (len(data).to_bytes(4, "big") + kind + data
                + (zlib.crc32(kind + data) & 0xFFFFFFFF).to_bytes(4, "big"))

    row = b"\x00" + bytes(rgb) * width
    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 2, 0, 0, 0])
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(row * height))
            + chunk(b"IEND", b""))


def _light(rng: random.Random, k: int) -> dict:
    from zcomp_cli.worldframe import direction_from_angles

    up = [0.0, 0.927, 0.375]
    d = direction_from_angles(rng.uniform(0, 360), rng.uniform(10, 80), up).tolist()
    unfixed = k % 7 == 0
    unc = rng.uniform(40, 70) if unfixed else rng.uniform(2, 25)
    note = (f"the photograph fixes the light's direction to within {unc:.0f} deg (RMS): drawn as the posterior's "
            "3 likeliest lights (12%, 9%, 7% of the light), each at the light's size (0.265 deg, not measured: the "
            "documented default), the rest of the posterior as sky") if unfixed else ""
    sh = [[rng.uniform(-1, 2) for _ in range(3)] for _ in range(9)]
    return {"source": "manifest" if k % 5 == 0 else "estimated", "shadow": "cast shadow", "up_camera": up,
            "up_from": "read off the support plane",
            "lights": [{"kind": "sun", "direction_camera": d, "direction_from": "read off the photograph's shadows",
                        "angular_radius_deg": 0.265 if unfixed else 1.5,
                        "angular_radius_from": "not measured: the documented default" if unfixed else
                        "read off the photograph's cast shadows",
                        "irradiance_rgb": [rng.random() for _ in range(3)], "strength_from": "fitted"},
                       {"kind": "sky", "radiance_sh_rgb": sh, "shading_up_rgb": [0.9, 0.85, 0.96],
                        "ground_radiance_rgb": [0.59, 0.41, 0.31], "strength_from": "fitted"}],
            "direction": d, "ambient_share": rng.random(), "specular_roughness": 0.5,
            "fallback": note or None,
            "fit": {"shadow_blocks": rng.random(), "direction_uncertainty_deg": unc, "residual": rng.random() / 10,
                    "fit_pixels": 2000, "exposure": None, "note": note, "unfixed": unfixed,
                    "modes": [{"kind": "sun", "toward": d, "share": s_} for s_ in ((0.12, 0.09, 0.07) if unfixed
                                                                                   else (0.97,))]},
            "probe": None, "walls": []}


def _settings(rng: random.Random) -> dict:
    """Renderer settings of about the size the physical renderer records."""
    groups = {}
    for g in ("mesh", "evidence", "search", "sky", "shadow", "fit", "probe", "walls", "estimate", "colour"):
        groups[g] = {f"{g}_{i}_setting": round(rng.uniform(0, 10), 4) for i in range(12)}
    groups["search"]["radii_deg"] = [0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0]
    return {"name": "physical", "n_light_candidates": 256, "march_steps": 32, **groups}


def make_output_folder(root, n_jobs: int, *, n_scenes: int = 20, failed_every: int = 10, seed: int = 0,
                       eval_metrics=("psnr", "ssim", "lpips", "flip")) -> Path:
    """Write ``root/project`` (scene photographs, a card object, jobs.yaml) and the
    output folder ``root/out`` of ``n_jobs`` jobs: one in ``failed_every`` failed
    (reason in the summary, no folder), the rest done with a report.json and a tiny
    composite.png; eval.json scores every other finished job. Returns ``root/out``."""
    rng = random.Random(seed)
    root = Path(root)
    proj, out = root / "project", root / "out"
    proj.mkdir(parents=True, exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    scenes = {}
    for k in range(n_scenes):
        (proj / f"scene{k}.png").write_bytes(tiny_png((40 + 9 * k % 200, 120, 200 - 7 * k % 150), 32, 24))
        scenes[f"scene{k}"] = {"image": f"scene{k}.png"}
    (proj / "card.png").write_bytes(tiny_png((200, 60, 40), 8, 8))
    (proj / "card_mask.png").write_bytes(tiny_png((255, 255, 255), 8, 8))
    names, lines = [], []
    for i in range(n_jobs):
        name = f"{i:05d}_scene{i % n_scenes}_card"
        names.append(name)
        lines.append(f"  - {{output: {name}, scene: scene{i % n_scenes}, object: card, "
                     f"placement: {{pixel: [16, 18], height: 0.2}}}}")
    scene_yaml = "".join(f"  {k}: {{image: {v['image']}, fov_deg: 50, "
                         f"depth: {{proxy: ground_plane, camera_height: 1.5, pitch_deg: -10}}}}\n"
                         for k, v in scenes.items())
    manifest = proj / "jobs.yaml"
    manifest.write_text("version: 1\ndefaults: {renderer: physical}\nscenes:\n" + scene_yaml
                        + "objects:\n  card: {image: card.png, mask: card_mask.png}\njobs:\n" + "\n".join(lines) + "\n")
    settings = _settings(rng)
    summary_jobs, images = [], []
    colours = [tiny_png((30 + 11 * c % 220, 90 + 5 * c % 160, 140 + 3 * c % 110)) for c in range(32)]
    for i, name in enumerate(names):
        scene = f"scene{i % n_scenes}"
        secs = rng.uniform(0.3, 3.0)
        if failed_every and i % failed_every == failed_every - 1:
            reason = rng.choice(["object is behind the camera", "GeometryError: the object lies outside the frame",
                                 f"{proj}/card.png: cannot read image"])
            summary_jobs.append({"index": i, "name": name, "status": "failed", "reason": reason, "seconds": secs,
                                 "this_run": "failed"})
            continue
        d = out / name
        d.mkdir(exist_ok=True)
        png = colours[i % len(colours)]
        (d / "composite.png").write_bytes(png)
        report = {
            "status": "done", "zcomp_version": "0.1.0", "fingerprint": f"{i:016x}",
            "renderer_spec": {"name": "physical", "settings": {}},
            "job": {"index": i, "name": name, "scene": scene, "object": "card", "manifest": str(manifest),
                    "line": 8 + i},
            "pose": {"position": [rng.uniform(-1, 1), -0.3, -3.0], "quaternion": [1.0, 0.0, 0.0, 0.0],
                     "scale": 1.0, "height": 0.2},
            "scene": {"key": f"{i % n_scenes:016x}", "size": [32, 24],
                      "K": [[26.0, 0.0, 16.0], [0.0, 26.0, 12.0], [0.0, 0.0, 1.0]]},
            "renderer": {"settings": settings, "info": {"light": (lt := _light(rng, i)), "fallback": lt["fallback"],
                                                        "shadow": "cast shadow"},
                         "timings": {"estimate": secs / 3, "synthesis": secs / 2}},
            "timings": {"render_s": secs * 0.8, "write_s": 0.05, "job_total_s": secs},
            "notes": [],
            "outputs": {"composite.png": {"bytes": len(png), "sha256": hashlib.sha256(png).hexdigest()}},
        }
        (d / "report.json").write_text(json.dumps(report, indent=2))
        summary_jobs.append({"index": i, "name": name, "status": "done", "reason": None, "seconds": secs,
                             "this_run": "done"})
        if i % 2 == 0:
            img = {"name": name, "pred": str(d / "composite.png"), "ref": str(proj / f"{scene}.png"), "mask": None}
            img.update({m: round(rng.uniform(0.01, 0.5) if m != "psnr" else rng.uniform(18, 40), 6)
                        for m in eval_metrics})
            images.append(img)
    done = sum(1 for j in summary_jobs if j["status"] == "done")
    summary = {"done": done, "failed": len(summary_jobs) - done, "pending": 0, "skipped": 0,
               "this_run": {"done": done, "skipped": 0, "failed": len(summary_jobs) - done},
               "seconds": sum(j["seconds"] for j in summary_jobs), "blender": {}, "shard": None,
               "executor": {"name": "local"}, "jobs": summary_jobs}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    mean = {m: sum(x[m] for x in images) / max(1, len(images)) for m in eval_metrics}
    (out / "eval.json").write_text(json.dumps(
        {"metrics": list(eval_metrics), "colour_space": "srgb", "images": images, "mean": mean, "unavailable": {},
         "unscored": {}, "partial": {}, "protocol": {"name": "zcomp", "encoding": "srgb", "region": "full",
                                                     "dataset": None}}, indent=2))
    return out


__all__ = ["make_output_folder", "tiny_png"]
