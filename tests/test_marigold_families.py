"""Which published model families load, verified by their configuration (no weights can
be downloaded here): each family's pipeline settings as the Marigold repository's
training configs declare them, the UNet's channels as its trainer sets them, SD 2's
component classes; a tiny random pipeline of that structure is saved, its
``model_index.json`` checked, and it is loaded and run through zcomp.

Families: prs-eth/marigold-depth-v1-1, marigold-normals-v1-1, marigold-iid-appearance-v1-1,
marigold-iid-lighting-v1-1, also saved under the Marigold repository's own class names
(MarigoldPipeline, MarigoldIIDPipeline). StableNormal (YOSONormalsPipeline,
StableNormalPipeline) ships its own pipeline code and is refused
(test_estimators_diffusion.py)."""

import json
import shutil

import numpy as np
import pytest

from marigold_dummy import FAMILIES
from zcomp_cli.camera import Camera
from zcomp_cli.estimators import estimate_scene_maps
from zcomp_cli.estimators.diffusion import pipeline_info

FAST = {"steps": 1, "processing_resolution": 32}
TASK_SPEC = {"MarigoldDepthPipeline": "depth", "MarigoldNormalsPipeline": "normals",
             "MarigoldIntrinsicsPipeline": "albedo"}


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_family_structure_and_load(family, marigold_dirs):
    cls, n_targets, config = FAMILIES[family]
    folder = marigold_dirs[family]
    index = json.loads((folder / "model_index.json").read_text())
    assert index["_class_name"] == cls
    assert index["unet"] == ["diffusers", "UNet2DConditionModel"] and index["vae"] == ["diffusers", "AutoencoderKL"]
    assert index["scheduler"] == ["diffusers", "DDIMScheduler"]
    assert index["text_encoder"] == ["transformers", "CLIPTextModel"]
    assert index["tokenizer"] == ["transformers", "CLIPTokenizer"]
    for k, v in config.items():
        assert index[k] == v, k
    unet = json.loads((folder / "unet" / "config.json").read_text())
    assert (unet["in_channels"], unet["out_channels"]) == (4 * (n_targets + 1), 4 * n_targets)
    sched = json.loads((folder / "scheduler" / "scheduler_config.json").read_text())
    assert sched["prediction_type"] == "v_prediction" and sched["timestep_spacing"] == "trailing"
    assert sched["rescale_betas_zero_snr"] is True
    info = pipeline_info(folder, what=family)
    assert info.default_steps == 4 and info.default_resolution == 768
    spec = TASK_SPEC[cls]
    img = np.random.default_rng(0).uniform(0, 1, (40, 56, 3)).astype(np.float32)
    cam = Camera.from_fov(55, 56, 40)
    kw = {f"{spec}_spec": {"model": str(folder), **FAST}}
    if spec != "depth":
        kw["depth_spec"] = {"proxy": "ground_plane", "camera_height": 1.0, "pitch_deg": -15}
    est = estimate_scene_maps(img, cam, **kw)
    assert est.sources[spec] == f"learned:{folder}"
    for m in (est.depth, est.normals, est.albedo):
        assert np.isfinite(m).all()
    assert (est.roughness is not None) == (family == "marigold-iid-appearance-v1-1")


@pytest.mark.parametrize("family,original", [("marigold-depth-v1-1", "MarigoldPipeline"),
                                             ("marigold-iid-appearance-v1-1", "MarigoldIIDPipeline")])
def test_saved_by_the_marigold_repository(family, original, marigold_dirs, tmp_path):
    """The Marigold repository's own classes save the same components under their names."""
    folder = tmp_path / family
    shutil.copytree(marigold_dirs[family], folder)
    idx = json.loads((folder / "model_index.json").read_text())
    idx["_class_name"] = original
    idx.pop("prediction_type", None)  # the repository's classes do not register it
    (folder / "model_index.json").write_text(json.dumps(idx))
    info = pipeline_info(folder, what=family)
    assert info.runner == FAMILIES[family][0]
    spec = TASK_SPEC[info.runner]
    img = np.random.default_rng(1).uniform(0, 1, (40, 56, 3)).astype(np.float32)
    kw = {f"{spec}_spec": {"model": str(folder), **FAST}}
    if spec != "depth":
        kw["depth_spec"] = {"proxy": "ground_plane", "camera_height": 1.0, "pitch_deg": -15}
    est = estimate_scene_maps(img, Camera.from_fov(55, 56, 40), **kw)  # loaded and run by diffusers' class
    assert est.sources[spec] == f"learned:{folder}"
