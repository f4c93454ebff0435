"""Test-wide settings (no network for model hubs, caches in a temporary folder) and the
helpers several test files share, as fixtures."""

import os
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
os.environ.setdefault("HF_HUB_DISABLE_TELEMETRY", "1")
# No LPIPS download from the tests (the weights' loopback test allows its own server)
os.environ.setdefault("ZCOMP_OFFLINE", "1")


@pytest.fixture(autouse=True, scope="session")
def _zcomp_cache(tmp_path_factory):
    """Object renders and estimates are cached under a per-session folder, so tests
    never read a cache left by an earlier run or by the user."""
    path = tmp_path_factory.mktemp("zcomp-cache")
    old = os.environ.get("ZCOMP_CACHE_DIR")
    os.environ["ZCOMP_CACHE_DIR"] = str(path)
    yield path
    if old is None:
        os.environ.pop("ZCOMP_CACHE_DIR", None)
    else:
        os.environ["ZCOMP_CACHE_DIR"] = old


@pytest.fixture
def examples_dir() -> Path:
    """The shipped example (examples/jobs.yaml and its scene and objects)."""
    return EXAMPLES


PHOTO_MANIFEST = """version: 1
defaults: {renderer: RENDERER}
scenes:
  table:
    image: photo.png
    fov_deg: 50
    depth: {proxy: ground_plane, camera_height: 0.6, pitch_deg: -30}
objects:
  card: {image: obj.png, mask: mask.png}
jobs:
  - {scene: table, object: card, placement: {pixel: [70, 100], height: 0.12}}
"""


@pytest.fixture
def photo_manifest():
    """``make(folder, renderer) -> jobs.yaml``: a real photograph (scikit-image's coffee
    cup, 160x120) with only ``image:`` and a ground-plane line, and a 2D card object."""
    from PIL import Image
    from skimage import data as skdata

    def make(folder: Path, renderer: str = "naive") -> Path:
        folder = Path(folder)
        Image.fromarray(skdata.coffee()).resize((160, 120)).save(folder / "photo.png")
        m = np.zeros((60, 30), np.uint8)
        m[4:56, 4:26] = 255
        Image.fromarray(m).save(folder / "mask.png")
        Image.fromarray(np.full((60, 30, 3), 200, np.uint8)).save(folder / "obj.png")
        (folder / "jobs.yaml").write_text(PHOTO_MANIFEST.replace("RENDERER", renderer))
        return folder / "jobs.yaml"

    return make


@pytest.fixture
def small_example():
    """``make(folder, jobs=None) -> jobs.yaml``: a copy of the shipped example manifest
    working at 256 x 192 (4 Cycles samples), with absolute paths; ``jobs`` picks a
    subset by index. Placement pixels stay as written: they are the scene image's own
    pixels, which zcomp scales to the working size."""
    import yaml

    def make(folder: Path, jobs=None) -> Path:
        m = yaml.safe_load((EXAMPLES / "jobs.yaml").read_text())
        m["defaults"]["resolution"] = [256, 192]
        m["defaults"]["samples"] = 4
        for s in m["scenes"].values():
            for k in ("image", "depth", "normals", "albedo"):
                s[k] = str(EXAMPLES / s[k])
            for light in s.get("light") or []:
                if "hdr" in light:
                    light["hdr"] = str(EXAMPLES / light["hdr"])
        for o in m["objects"].values():
            o["mesh"] = str(EXAMPLES / o["mesh"])
        for j in m["jobs"]:
            if "reference" in j:
                j["reference"] = str(EXAMPLES / j["reference"])
        if jobs is not None:
            m["jobs"] = [m["jobs"][i] for i in jobs]
        p = Path(folder) / "jobs.yaml"
        p.write_text(yaml.safe_dump(m))
        return p

    return make


@pytest.fixture(scope="session")
def marigold_dirs(tmp_path_factory):
    """Tiny random pipelines of the four Marigold families (tests/marigold_dummy.py),
    saved once per session: family name -> folder. Tests must not modify them (copy
    first)."""
    from marigold_dummy import FAMILIES, save_pipeline

    root = tmp_path_factory.mktemp("marigold")
    return {name: save_pipeline(root / name, name) for name in FAMILIES}


@pytest.fixture(scope="session")
def tiny_dpt(tmp_path_factory):
    """A tiny random transformers DPT depth model with its image processor (32x32 input),
    saved once per session. Tests must not modify it (copy first)."""
    import torch
    from transformers import DPTConfig, DPTForDepthEstimation, DPTImageProcessor

    torch.manual_seed(0)
    cfg = DPTConfig(hidden_size=16, num_hidden_layers=4, num_attention_heads=2, intermediate_size=32,
                    image_size=32, patch_size=8, backbone_out_indices=[0, 1, 2, 3],
                    neck_hidden_sizes=[8, 8, 8, 8], fusion_hidden_size=8, reassemble_factors=[4, 2, 1, 0.5])
    path = tmp_path_factory.mktemp("tiny_dpt")
    DPTForDepthEstimation(cfg).save_pretrained(path)
    DPTImageProcessor(size={"height": 32, "width": 32}, keep_aspect_ratio=False).save_pretrained(path)
    return path


@pytest.fixture
def no_ray(monkeypatch):
    """``no_ray()``: from then on, ``import ray`` fails as on a plain install."""
    import builtins

    real = builtins.__import__

    def blocked(name, *a, **k):
        if name == "ray" or name.startswith("ray."):
            raise ImportError("No module named 'ray'")
        return real(name, *a, **k)

    return lambda: monkeypatch.setattr(builtins, "__import__", blocked)



@pytest.fixture(scope="session")
def stability_sweep():
    """``benchmarks/stability_sweep.py`` as a module: its scenes, cells and CI slice
    (tests/test_stability_sweep.py, tests/test_working_scale.py)."""
    import importlib.util
    import sys

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "stability_sweep.py"
    spec = importlib.util.spec_from_file_location("stability_sweep", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["stability_sweep"] = mod
    spec.loader.exec_module(mod)
    return mod
