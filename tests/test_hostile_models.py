"""Hostile model folders (issue 39, defects 1, 3, 4, 5): no code from a model folder ever
runs and stdin is never read; a damaged or absurd weights file is refused by its header
and size before any library reads it, or fails its scene's jobs alone; new weights in
the same folder make the job changed for --resume."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from zcomp_cli.cli import cli
from zcomp_cli.estimators import weights as W

MANIFEST = """version: 1
defaults: {renderer: physical}
scenes:
  learned:
    image: photo.png
    fov_deg: 50
    depth: {model: MODEL}
  plain:
    image: photo.png
    fov_deg: 50
    depth: {proxy: ground_plane, camera_height: 0.6, pitch_deg: -30}
objects:
  card: {image: obj.png, mask: mask.png}
jobs:
  - {scene: learned, object: card, placement: {pixel: [70, 100], height: 0.12}}
  - {scene: plain, object: card, placement: {pixel: [70, 100], height: 0.12}}
"""


def _project(make, tmp_path, model_dir):
    """conftest's photo project (``photo_manifest``: the photograph, the card and its
    mask) with this file's two-scene manifest."""
    make(tmp_path)
    (tmp_path / "jobs.yaml").write_text(MANIFEST.replace("MODEL", str(model_dir)))
    return tmp_path / "jobs.yaml"


def _copy(src, dst):
    shutil.copytree(src, dst)
    return dst


EVIL = """import pathlib
pathlib.Path(r"MARKER").write_text("the folder's code ran")
from transformers import DPTForDepthEstimation as EvilModel
"""


@pytest.mark.parametrize("how", ["auto_map", "py_beside", "component_library"])
def test_a_model_folder_with_its_own_code_is_refused_and_nothing_runs(tmp_path, tiny_dpt, how, monkeypatch, photo_manifest):
    """A depth folder whose config names its own code (auto_map), that merely carries a
    .py file, or a pipeline taking a component from another library: refused at
    validation with the reason (exit 2), even with "y" waiting on stdin; the code never
    runs and nothing lands in the Hugging Face modules cache."""
    monkeypatch.setenv("HF_MODULES_CACHE", str(tmp_path / "hf_modules"))
    d = _copy(tiny_dpt, tmp_path / "evil")
    marker = tmp_path / "ran.txt"
    (d / "evil.py").write_text(EVIL.replace("MARKER", str(marker)))
    if how == "auto_map":
        cfg = json.loads((d / "config.json").read_text())
        cfg["auto_map"] = {"AutoConfig": "evil.EvilConfig", "AutoModelForDepthEstimation": "evil.EvilModel"}
        cfg["model_type"] = "evil-dpt"
        (d / "config.json").write_text(json.dumps(cfg))
    elif how == "component_library":
        (d / "evil.py").unlink()
        (d / "model_index.json").write_text(json.dumps({"_class_name": "MarigoldDepthPipeline",
                                                        "unet": ["evil_library", "EvilUNet"]}))
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["composite", str(_project(photo_manifest, tmp_path, d)), "--out", str(out)], input="y\ny\ny\n")
    assert r.exit_code == 2, r.output
    assert "scenes.learned.depth.model" in r.output
    assert ("own code" in r.output) or ("Python code" in r.output), r.output
    assert not marker.exists()
    assert not out.exists()
    assert not (tmp_path / "hf_modules").exists()


def test_loading_never_asks_and_never_runs_the_folders_code(tmp_path, tiny_dpt, monkeypatch):
    """Past validation too (the loader called directly on a folder with auto_map and no
    .py check): transformers is told trust_remote_code=False, so it refuses instead of
    asking on stdin; stdin is never read."""
    import sys

    from zcomp_cli.errors import WeightsError
    from zcomp_cli.estimators import learned

    d = _copy(tiny_dpt, tmp_path / "evil")
    marker = tmp_path / "ran.txt"
    (tmp_path / "mods").mkdir()
    cfg = json.loads((d / "config.json").read_text())
    cfg["auto_map"] = {"AutoConfig": "evil.EvilConfig", "AutoModelForDepthEstimation": "evil.EvilModel"}
    cfg["model_type"] = "evil-dpt"
    (d / "config.json").write_text(json.dumps(cfg))
    (d / "evil.py").write_text(EVIL.replace("MARKER", str(marker)))
    monkeypatch.setenv("HF_MODULES_CACHE", str(tmp_path / "hf_modules"))

    class NoStdin:
        def read(self, *a):
            raise AssertionError("stdin was read")

        readline = read

    monkeypatch.setattr(sys, "stdin", NoStdin())
    monkeypatch.setattr("builtins.input", lambda *a: (_ for _ in ()).throw(AssertionError("asked on stdin")))
    monkeypatch.setattr(W, "check_folder_safety", lambda *a, **k: None)  # as if validation were bypassed
    with pytest.raises(WeightsError):
        learned.load_depth_model(d)
    assert not marker.exists()


def _safetensors(path, tensors: dict, header_extra: dict | None = None, n_override=None, cut=None):
    header, blob = {}, b""
    for name, arr in tensors.items():
        a = np.ascontiguousarray(arr, np.float32)
        header[name] = {"dtype": "F32", "shape": list(a.shape), "data_offsets": [len(blob), len(blob) + a.nbytes]}
        blob += a.tobytes()
    header.update(header_extra or {})
    h = json.dumps(header).encode()
    data = (len(h) if n_override is None else n_override).to_bytes(8, "little") + h + blob
    path.write_bytes(data[:cut] if cut is not None else data)


@pytest.mark.parametrize("damage, words", [
    ("empty", "is empty"),
    ("truncated", "truncated"),
    ("absurd_header", "header claims"),
    ("deep_header", "nested too deeply"),
    ("sparse", "sparse"),
])
def test_a_damaged_weights_file_is_refused_by_its_header_before_loading(tmp_path, tiny_dpt, damage, words, photo_manifest):
    d = _copy(tiny_dpt, tmp_path / "m")
    w = d / "model.safetensors"
    if damage == "empty":
        w.write_bytes(b"")
    elif damage == "truncated":
        _safetensors(w, {"a": np.ones((64, 64))}, cut=2000)
    elif damage == "absurd_header":
        _safetensors(w, {"a": np.ones(4)}, n_override=1 << 62)
    elif damage == "deep_header":
        h = ("[" * 100_000 + "]" * 100_000).encode()
        w.write_bytes(len(h).to_bytes(8, "little") + h)
    else:  # a 10 GB file of holes: a few KB on disk
        with open(w, "wb") as f:
            f.truncate(10 << 30)
    problem = W.weights_file_problem(w)
    assert problem and words in problem, problem
    # at validation: exit 2, the scene's field and the file named, nothing written
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["composite", str(_project(photo_manifest, tmp_path, d)), "--out", str(out)])
    assert r.exit_code == 2, r.output
    assert "scenes.learned.depth.model" in r.output and "model.safetensors" in r.output
    assert not out.exists()


def test_a_weights_file_only_loading_can_refuse_fails_its_scene_alone(tmp_path, tiny_dpt, photo_manifest):
    """A pytorch_model.bin that torch's weights_only unpickler refuses (a pickle naming
    an arbitrary callable) passes every header check: its scene's job fails with the
    reason, the other scene's job is done, no traceback, exit 1."""
    import pickle

    d = _copy(tiny_dpt, tmp_path / "m")
    (d / "model.safetensors").unlink()

    class Evil:
        def __reduce__(self):
            return (os.system, ("echo pwned > " + str(tmp_path / "pwned"),))

    (d / "pytorch_model.bin").write_bytes(pickle.dumps({"weight": Evil()}))
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["composite", str(_project(photo_manifest, tmp_path, d)), "--out", str(out)])
    assert r.exit_code == 1, r.output
    assert "Traceback" not in r.output
    assert not (tmp_path / "pwned").exists()
    summary = json.loads((out / "summary.json").read_text())
    by_scene = {j["name"]: j for j in summary["jobs"]}
    learned = next(j for n, j in by_scene.items() if "learned" in n)
    plain = next(j for n, j in by_scene.items() if "plain" in n)
    assert learned["status"] == "failed" and "depth model" in learned["reason"]
    assert plain["status"] == "done"


def test_new_weights_in_the_same_folder_change_the_job(tmp_path, tiny_dpt, photo_manifest):
    """--resume after the model folder's weights change: the job is changed, not skipped
    (the estimate cache already saw the change; the job fingerprint now does too)."""
    import torch
    from transformers import DPTForDepthEstimation

    d = _copy(tiny_dpt, tmp_path / "m")
    manifest = _project(photo_manifest, tmp_path, d)
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["composite", str(manifest), "--out", str(out), "--jobs", "0"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["composite", str(manifest), "--out", str(out), "--jobs", "0", "--resume"])
    assert r.exit_code == 0 and "1 skipped" in r.output, r.output
    model = DPTForDepthEstimation.from_pretrained(d)
    torch.manual_seed(1)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(torch.randn_like(p))
    model.save_pretrained(d)
    r = CliRunner().invoke(cli, ["composite", str(manifest), "--out", str(out), "--jobs", "0", "--resume"])
    assert r.exit_code != 0 or "1 skipped" not in r.output, r.output
    assert "changed" in r.output
    r = CliRunner().invoke(cli, ["status", str(out), "--manifest", str(manifest)])
    assert "changed" in r.output, r.output


def test_a_narrow_probe_is_refused_and_its_steps_are_bounded(tmp_path, examples_dir):
    """Defect 2: a 10 x 2000 probe EXR (a few hundred bytes) peaked at 18.9 GB in the
    prefilter's dense matrix. The manifest refuses a probe that is not 2:1 (exit 2, the
    field named, nothing written); a map handed to the renderer directly is resampled to
    2:1 at most max_width wide, so every step is bounded by its output size (measured:
    the peak of numpy's allocations under 200 MB)."""
    import tracemalloc

    import yaml

    from zcomp_cli.imageio import write_exr
    from zcomp_cli.scene.probe import load_probe
    from zcomp_cli.worldframe import ground_frame

    img = np.zeros((2000, 10, 3), np.float32)
    img[5, 5] = 100.0
    img[100:, :] = 0.1
    write_exr(tmp_path / "narrow.exr", img)
    m = yaml.safe_load((examples_dir / "jobs.yaml").read_text())
    sc = m["scenes"]["room_lit"]
    for k in ("image", "depth", "normals", "albedo"):
        sc[k] = str(examples_dir / sc[k])
    sc["light"] = [{"type": "probe", "hdr": str(tmp_path / "narrow.exr")}]
    mm = {"version": 1, "scenes": {"room_lit": sc}, "objects": {"vase": {"mesh": str(examples_dir / "objects/vase.glb")}},
          "jobs": [{"scene": "room_lit", "object": "vase", "placement": {"pixel": [200, 300], "height": 0.3}}]}
    (tmp_path / "jobs.yaml").write_text(yaml.safe_dump(mm))
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["composite", str(tmp_path / "jobs.yaml"), "--out", str(out)])
    assert r.exit_code == 2, r.output
    assert "scenes.room_lit.light" in r.output and "10x2000" in r.output and "twice as wide" in r.output
    assert not out.exists()
    tracemalloc.start()
    lights = load_probe(tmp_path / "narrow.exr", ground_frame(np.array([0.0, 1.0, 0.0])))
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 200 << 20, peak / 2**20
    h, w = lights.residual.shape[:2]
    assert w == 2 * h and w <= 2048  # every later step (the sky's SH, the glossy prefilter) bounded by it


@pytest.mark.parametrize("edit", ["config", "weights"])
def test_weights_that_do_not_fit_the_config_fail_their_scene(tmp_path, tiny_dpt, photo_manifest, edit):
    """Found by the fuzzer: transformers loads a model whose weights lack tensors by
    filling them with random values (a load report, no error), and the job was done
    with a depth map of noise. Now that scene's jobs fail, naming the keys. (A config
    edited to other shapes is refused by transformers itself.)"""
    from safetensors.numpy import load_file, save_file

    d = _copy(tiny_dpt, tmp_path / "m")
    if edit == "config":
        cfg = json.loads((d / "config.json").read_text())
        cfg["hidden_size"] = 4
        (d / "config.json").write_text(json.dumps(cfg))
    else:
        tensors = load_file(d / "model.safetensors")
        save_file({k: v for i, (k, v) in enumerate(sorted(tensors.items())) if i % 2}, d / "model.safetensors")
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["composite", str(_project(photo_manifest, tmp_path, d)), "--out", str(out)])
    assert r.exit_code == 1, r.output
    jobs = {j["name"]: j for j in json.loads((out / "summary.json").read_text())["jobs"]}
    learned = next(j for n, j in jobs.items() if "learned" in n)
    assert learned["status"] == "failed", learned
    if edit == "config":  # transformers itself refuses mismatched shapes (after its report)
        assert "ignore_mismatched_sizes" in learned["reason"] or "mismatched keys" in learned["reason"]
    else:
        assert "does not match its config.json" in learned["reason"] and "missing keys" in learned["reason"]
    assert next(j for n, j in jobs.items() if "plain" in n)["status"] == "done"
