"""Normals, albedo and depth from diffusers pipelines saved on disk (estimators/diffusion.py,
learned_maps.py): tiny random Marigold pipelines built the diffusers way and loaded
through zcomp, each output checked against the pipeline's own prediction converted by
hand; missing files, foreign pipelines, NaN outputs, the cache, the settings."""

import json
import shutil

import numpy as np
import pytest

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError, NumericalError, WeightsError
from zcomp_cli.estimators import estimate_scene_maps
from zcomp_cli.estimators.diffusion import PipelineSettings, pipeline_info, release_pipelines

FAST = {"steps": 1, "processing_resolution": 32}
H, W = 48, 64


@pytest.fixture(autouse=True)
def _fresh_loads():
    release_pipelines()
    yield
    release_pipelines()


def _image(seed=0):
    return np.random.default_rng(seed).uniform(0.02, 0.9, (H, W, 3)).astype(np.float32)


def _camera():
    return Camera.from_fov(50, W, H)


def _reference(folder, image_lin, seed=469, **kw):
    """The pipeline's own output, called directly through diffusers with what zcomp gives
    it: the sRGB-encoded image in [0, 1], the seed's generator, the settings."""
    import diffusers
    import torch

    from zcomp_cli.conventions import linear_to_srgb

    name = json.loads((folder / "model_index.json").read_text())["_class_name"]
    pipe = getattr(diffusers, name).from_pretrained(str(folder), local_files_only=True)
    pipe.set_progress_bar_config(disable=True)
    out = pipe(linear_to_srgb(image_lin), num_inference_steps=kw.get("steps", 1),
               processing_resolution=kw.get("processing_resolution", 32),
               ensemble_size=kw.get("ensemble_size", 1), generator=torch.Generator().manual_seed(seed),
               output_type="np")
    return np.asarray(out.prediction, np.float64)


def test_normals_are_the_pipeline_output_in_zcomp_frame(marigold_dirs):
    folder = marigold_dirs["marigold-normals-v1-1"]
    img = _image()
    ref = _reference(folder, img)[0]  # Marigold: x right, y up, z toward the viewer, [-1, 1]
    est = estimate_scene_maps(img, _camera(), depth_spec={"proxy": "ground_plane", "camera_height": 1.0,
                                                          "pitch_deg": -20},
                              normals_spec={"model": str(folder), **FAST})
    expect = ref / np.linalg.norm(ref, axis=-1, keepdims=True)  # same frame: only renormalised
    np.testing.assert_allclose(est.normals, expect, atol=2e-5)
    assert est.sources["normals"] == f"learned:{folder}"
    # The same model declared as an OpenCV-frame model: y and z flip, by hand.
    cv = estimate_scene_maps(img, _camera(), depth_spec={"proxy": "ground_plane", "camera_height": 1.0,
                                                         "pitch_deg": -20},
                             normals_spec={"model": str(folder), "frame": "opencv", **FAST})
    np.testing.assert_allclose(cv.normals, expect * [1, -1, -1], atol=2e-5)
    # Normals beside a ground plane: their disagreement with it is measured, in degrees.
    assert est.agreement.shape == (H, W) and est.fits["agreement"]["pixels"] > 0
    assert any(n.startswith("normals vs depth: median") for n in est.notes)


def test_appearance_albedo_and_materials_decoded_by_hand(marigold_dirs):
    folder = marigold_dirs["marigold-iid-appearance-v1-1"]
    img = _image(1)
    ref = _reference(folder, img)  # [albedo, material] in [0, 1], both x ** (1/2.2)-encoded
    est = estimate_scene_maps(img, _camera(), depth_spec={"proxy": "ground_plane", "camera_height": 1.0,
                                                          "pitch_deg": -20},
                              albedo_spec={"model": str(folder), **FAST})
    np.testing.assert_allclose(est.albedo, np.clip(ref[0], 0, 1) ** 2.2, atol=2e-5)
    np.testing.assert_allclose(est.roughness, np.clip(ref[1][..., 0], 0, 1) ** 2.2, atol=2e-5)
    np.testing.assert_allclose(est.metallic, np.clip(ref[1][..., 1], 0, 1) ** 2.2, atol=2e-5)
    assert est.sources["roughness"] == est.sources["albedo"] == f"learned:{folder}"
    lit = est.albedo > 0.05  # shading = image / albedo (clamped where albedo ~ 0)
    np.testing.assert_allclose((est.shading * est.albedo)[lit], img[lit], rtol=1e-4)
    # Materials can be declined; a target the model does not predict is an error.
    no_mat = estimate_scene_maps(img, _camera(), depth_spec={"proxy": "ground_plane", "camera_height": 1.0,
                                                             "pitch_deg": -20},
                                 albedo_spec={"model": str(folder), "materials": False, **FAST})
    assert no_mat.roughness is None and no_mat.metallic is None
    with pytest.raises(WeightsError, match="no 'shading'"):
        estimate_scene_maps(img, _camera(), depth_spec={"proxy": "ground_plane", "camera_height": 1.0,
                                                        "pitch_deg": -20},
                            albedo_spec={"model": str(folder), "target": "shading", **FAST})


def test_lighting_albedo_is_linear_already(marigold_dirs):
    folder = marigold_dirs["marigold-iid-lighting-v1-1"]
    img = _image(2)
    ref = _reference(folder, img)  # [albedo, shading, residual], albedo linear
    est = estimate_scene_maps(img, _camera(), depth_spec={"proxy": "ground_plane", "camera_height": 1.0,
                                                          "pitch_deg": -20},
                              albedo_spec={"model": str(folder), **FAST})
    np.testing.assert_allclose(est.albedo, np.clip(ref[0], 0, 1), atol=2e-5)
    assert est.roughness is None  # the lighting model predicts no material
    assert est.fits["albedo_model"]["space"] == "linear"


def test_marigold_depth_aligned_by_hand(marigold_dirs):
    folder = marigold_dirs["marigold-depth-v1-1"]
    img = _image(3)
    p = _reference(folder, img)[0, ..., 0]  # affine-invariant depth in [0, 1], near = 0
    est = estimate_scene_maps(img, _camera(), depth_spec={"model": str(folder), "align": "median",
                                                          "median_depth": 2.0, **FAST})
    lo, hi = np.percentile(p, [2, 98])
    t = (hi - 4 * lo) / 3  # the documented assumption: far/near = 4 between the percentiles,
    z = np.maximum(p + t, (lo + t) / 4)  # nearer outliers kept at >= a quarter of the near end
    expect = z * 2.0 / np.median(z)
    np.testing.assert_allclose(est.depth, expect, rtol=1e-4)
    assert est.sources["depth"] == f"learned:{folder}" and "assumed" in est.fits["depth"]


def test_depth_and_normals_models_together_fit_the_shift(marigold_dirs):
    img = _image(4)
    est = estimate_scene_maps(img, _camera(),
                              depth_spec={"model": str(marigold_dirs["marigold-depth-v1-1"]), **FAST},
                              normals_spec={"model": str(marigold_dirs["marigold-normals-v1-1"]), **FAST})
    fit = est.fits["depth_shift_fit"]  # align: auto with learned normals and no ground plane
    assert fit["median_deg"] <= fit["median_deg_default_shift"] + 1e-6
    assert "fitted to the normals" in est.fits["depth"]
    assert est.fits["agreement"]["median_deg"] == pytest.approx(fit["median_deg"], abs=1.0)
    assert np.isfinite(est.depth).all() and (est.depth >= 0).all()


def test_missing_weights_file_is_named(marigold_dirs, tmp_path):
    src = marigold_dirs["marigold-normals-v1-1"]
    broken = tmp_path / "normals"
    shutil.copytree(src, broken)
    (broken / "unet" / "diffusion_pytorch_model.safetensors").unlink()
    (broken / "scheduler" / "scheduler_config.json").unlink()
    with pytest.raises(WeightsError) as e:
        estimate_scene_maps(_image(), _camera(), depth_spec={"proxy": "ground_plane", "camera_height": 1.0,
                                                             "pitch_deg": -20},
                            normals_spec={"model": str(broken), **FAST})
    msg = str(e.value)
    assert str(broken / "unet" / "diffusion_pytorch_model.safetensors") in msg
    assert str(broken / "scheduler" / "scheduler_config.json") in msg
    assert "never downloads" in msg
    (broken / "model_index.json").unlink()
    with pytest.raises(WeightsError, match="model_index.json"):
        pipeline_info(broken, what="normals model")
    with pytest.raises(WeightsError, match="neither a diffusers depth pipeline"):
        estimate_scene_maps(_image(), _camera(), depth_spec={"model": str(tmp_path / "absent")})


def test_fp16_variant_files_are_found(marigold_dirs, tmp_path):
    folder = tmp_path / "fp16"
    shutil.copytree(marigold_dirs["marigold-normals-v1-1"], folder)
    for p in list(folder.rglob("*.safetensors")):  # as the Hub's fp16 variant names them
        p.rename(p.with_name(p.name.replace(".safetensors", ".fp16.safetensors")))
    info = pipeline_info(folder, what="normals model")
    assert info.folder.variant == "fp16"
    est = estimate_scene_maps(_image(), _camera(), depth_spec={"proxy": "ground_plane", "camera_height": 1.0,
                                                               "pitch_deg": -20},
                              normals_spec={"model": str(folder), **FAST})
    assert np.isfinite(est.normals).all()


def test_foreign_and_mismatched_pipelines_are_refused(marigold_dirs, tmp_path):
    folder = tmp_path / "yoso"
    shutil.copytree(marigold_dirs["marigold-normals-v1-1"], folder)
    idx = json.loads((folder / "model_index.json").read_text())
    idx["_class_name"] = "YOSONormalsPipeline"
    (folder / "model_index.json").write_text(json.dumps(idx))
    with pytest.raises(WeightsError, match="StableNormal.*trust_remote_code"):
        pipeline_info(folder, what="normals model")
    # A folder saved in Marigold's format under another name runs when told which class.
    idx["_class_name"] = "MyFinetunedNormals"
    (folder / "model_index.json").write_text(json.dumps(idx))
    with pytest.raises(WeightsError, match="pipeline: "):
        pipeline_info(folder, what="normals model")
    assert pipeline_info(folder, what="normals model", pipeline="MarigoldNormalsPipeline").task == "normals"
    with pytest.raises(InputError, match="not a normals model"):
        estimate_scene_maps(_image(), _camera(), depth_spec={"proxy": "ground_plane", "camera_height": 1.0,
                                                             "pitch_deg": -20},
                            normals_spec={"model": str(marigold_dirs["marigold-depth-v1-1"]), **FAST})


def test_nan_outputs_are_refused_and_not_cached(marigold_dirs, tmp_path):
    import torch
    from diffusers import AutoencoderKL

    folder = tmp_path / "nan"
    shutil.copytree(marigold_dirs["marigold-normals-v1-1"], folder)
    vae = AutoencoderKL.from_pretrained(str(folder / "vae"))
    with torch.no_grad():
        vae.decoder.conv_out.bias[0] = float("nan")  # what an fp16 overflow does to a decoder
    vae.save_pretrained(str(folder / "vae"))
    cache = tmp_path / "cache"
    with pytest.raises(NumericalError, match="NaN or infinite.*refused"):
        estimate_scene_maps(_image(), _camera(), depth_spec={"proxy": "ground_plane", "camera_height": 1.0,
                                                             "pitch_deg": -20},
                            normals_spec={"model": str(folder), **FAST}, cache_dir=cache)
    assert not cache.exists() or not any(cache.iterdir())


def test_cache_per_image_content_and_settings(marigold_dirs, tmp_path):
    folder = str(marigold_dirs["marigold-normals-v1-1"])
    gp = {"proxy": "ground_plane", "camera_height": 1.0, "pitch_deg": -20}
    cache = tmp_path / "cache"

    def run(img, **kw):
        return estimate_scene_maps(img, _camera(), depth_spec=gp, normals_spec={"model": folder, **FAST, **kw},
                                   cache_dir=cache)

    a = run(_image())
    assert "cached" not in a.fits["normals_model"]
    b = run(_image())
    assert b.fits["normals_model"]["cached"] is True
    np.testing.assert_array_equal(a.normals, b.normals)
    c = run(_image(), seed=7)  # another seed: another estimate
    assert "cached" not in c.fits["normals_model"] and not np.array_equal(a.normals, c.normals)
    d = run(_image(9))  # another image
    assert "cached" not in d.fits["normals_model"]
    e = run(_image(), frame="opencv")  # a convention is applied after the cache
    assert e.fits["normals_model"]["cached"] is True


def test_settings_are_checked_and_half_precision_on_cpu_runs_fp32(marigold_dirs):
    folder = str(marigold_dirs["marigold-normals-v1-1"])
    gp = {"proxy": "ground_plane", "camera_height": 1.0, "pitch_deg": -20}
    for bad in ({"steps": 0}, {"processing_resolution": 30}, {"dtype": "fp8"}, {"device": "tpu"},
                {"ensemble_size": True}, {"frame": "ogl"}, {"colour": 1}):
        with pytest.raises(InputError):
            estimate_scene_maps(_image(), _camera(), depth_spec=gp, normals_spec={"model": folder, **FAST, **bad})
    with pytest.raises(InputError):
        PipelineSettings.from_spec({"seed": -1})
    est = estimate_scene_maps(_image(), _camera(), depth_spec=gp,
                              normals_spec={"model": folder, "dtype": "fp16", "device": "cpu", **FAST})
    run = est.fits["normals_model"]
    assert run["dtype"] == "fp32" and "fp16 asked for on the CPU" in run["note"]
    # An ensemble runs (3 members, Marigold's "closest" reduction) and stays unit length.
    ens = estimate_scene_maps(_image(), _camera(), depth_spec=gp,
                              normals_spec={"model": folder, "ensemble_size": 3, **FAST})
    np.testing.assert_allclose(np.linalg.norm(ens.normals, axis=-1), 1.0, atol=1e-5)
