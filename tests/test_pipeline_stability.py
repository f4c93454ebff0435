"""Numerical stability of the whole compositing path (manifest -> scene -> job ->
outputs) with the physical renderer, on analytic scenes and sphere bundles (no Blender):
every case gives either a finite composite or a clear per-job error."""

import json

import numpy as np
import pytest
import yaml

from zcomp_cli.imageio import read_image, write_exr
from zcomp_cli.pipeline.batch import run_batch
from zcomp_cli.pipeline.manifest import load_manifest
from zcomp_cli.testing import floor_scene, sphere_object_bundle

# Light estimation is the expensive part; keep it small for CI.
FAST = {"name": "physical", "n_light_candidates": 64, "max_resolution": 64}


def make_case(tmp_path, *, w=64, h=48, fov=50.0, edit=None, sphere_xz=(0.0, -3.0), radius=0.25,
              camera_height=1.2, pitch=-25.0):
    """Write a floor scene + a sphere bundle standing on the floor, and a manifest."""
    s = floor_scene(w, h, fov_deg=fov, with_box=True, box_center=(0.8, -3.5), camera_height=camera_height,
                    pitch_deg=pitch)
    image, depth, normals, albedo = s.image.copy(), s.depth.copy(), s.normals.copy(), s.albedo.copy()
    if edit is not None:
        image, depth, normals, albedo = edit(image, depth, normals, albedo)
    for name, arr in (("image", image), ("depth", depth), ("normals", normals), ("albedo", albedo)):
        write_exr(tmp_path / f"{name}.exr", arr)
    center = s.world_to_camera(np.array([sphere_xz[0], radius, sphere_xz[1]]))
    b = sphere_object_bundle(s.camera, center, radius, albedo=(0.7, 0.2, 0.2), floor_normal=s.up_cam)
    b.save(tmp_path / "sphere")
    K = s.camera.K.tolist()
    m = {
        "version": 1,
        "defaults": {"renderer": FAST},
        "scenes": {"s": {"image": "image.exr", "K": K, "depth": "depth.exr", "normals": "normals.exr",
                         "albedo": "albedo.exr"}},
        "objects": {"ball": {"bundle": "sphere"}},
        "jobs": [{"scene": "s", "object": "ball", "pose": {"position": [0, 0, -1]}, "output": "job"}],
    }
    (tmp_path / "jobs.yaml").write_text(yaml.safe_dump(m))
    return s, b


def run(tmp_path):
    summary = run_batch(load_manifest(tmp_path / "jobs.yaml"), tmp_path / "out")
    st = summary.statuses[0]
    return st, tmp_path / "out" / "job"


def assert_finite_composite(out_dir):
    img = read_image(out_dir / "composite.exr")
    assert np.all(np.isfinite(img))
    rep = json.loads((out_dir / "report.json").read_text())
    assert rep["status"] == "done"
    return img, rep


def test_reference_case_casts_shadow_and_keeps_far_pixels(tmp_path):
    s, b = make_case(tmp_path, w=96, h=72)
    st, out = run(tmp_path)
    assert st.status == "done", st.reason
    img, rep = assert_finite_composite(out)
    bg = read_image(tmp_path / "image.exr")
    m = b.mask > 0
    off = ~m
    ratio = (img @ [0.299, 0.587, 0.114]) / np.maximum(bg @ [0.299, 0.587, 0.114], 1e-6)
    assert (ratio[off] < 0.8).sum() >= 5  # a cast shadow
    assert rep["shading_mask"]["frac"] < 0.5
    x0, y0, x1, y1 = rep["roi"]["box"]
    far = np.ones(m.shape, bool)
    far[max(0, y0 - 8):y1 + 8, max(0, x0 - 8):x1 + 8] = False
    assert far.any() and np.array_equal(img[far], bg[far])


@pytest.mark.parametrize("value", [0.0, 1.0, 1e4])
def test_black_saturated_hdr_backgrounds(tmp_path, value):
    make_case(tmp_path, edit=lambda i, d, n, a: (np.full_like(i, value), d, n, a))
    st, out = run(tmp_path)
    assert st.status == "done", st.reason
    img, _ = assert_finite_composite(out)
    assert img.max() <= max(value, 1.0) * 4 + 1e-3  # colour balance is clamped


def test_nan_inf_in_provided_maps(tmp_path):
    def edit(i, d, n, a):
        i, d, n, a = i.copy(), d.copy(), n.copy(), a.copy()
        d[5:15, 5:15] = np.nan
        d[20:22, :] = np.inf
        n[30:34, 10:20] = np.inf
        a[2:6, 30:40] = np.nan
        i[40:44, 0:8] = np.nan
        return i, d, n, a

    make_case(tmp_path, edit=edit)
    st, out = run(tmp_path)
    assert st.status == "done", st.reason
    _, rep = assert_finite_composite(out)
    assert any("non-finite" in note or "invalid" in note for note in rep["notes"])


def test_zero_albedo_pixels(tmp_path):
    def edit(i, d, n, a):
        a = a.copy()
        a[:, ::2] = 0.0  # every other column black
        return i, d, n, a

    make_case(tmp_path, edit=edit)
    st, out = run(tmp_path)
    assert st.status == "done", st.reason
    assert_finite_composite(out)


def test_empty_footprint_falls_back(tmp_path):
    make_case(tmp_path)
    fp = tmp_path / "sphere" / "footprint_depth.exr"
    write_exr(fp, np.zeros((48, 64), np.float32))
    st, out = run(tmp_path)
    assert st.status == "done", st.reason
    _, rep = assert_finite_composite(out)
    assert rep["alignment"]["mode"] == "none" and "footprint" in rep["alignment"]["fallback"]


def test_one_pixel_object(tmp_path):
    make_case(tmp_path, w=48, h=36, radius=0.02, sphere_xz=(0.0, -4.0))
    st, out = run(tmp_path)
    assert st.status == "done", st.reason
    _, rep = assert_finite_composite(out)
    assert rep["object_pixels"] <= 4


def test_object_filling_the_frame(tmp_path):
    make_case(tmp_path, radius=1.2, sphere_xz=(0.0, -2.0))
    st, out = run(tmp_path)
    assert st.status == "done", st.reason
    _, rep = assert_finite_composite(out)
    assert rep["object_coverage_frac"] > 0.5


def test_object_cut_by_border(tmp_path):
    make_case(tmp_path, sphere_xz=(1.3, -2.5), radius=0.4)
    st, out = run(tmp_path)
    assert st.status == "done", st.reason
    assert_finite_composite(out)


def test_object_outside_frame_is_a_clear_error(tmp_path):
    make_case(tmp_path, sphere_xz=(30.0, -3.0))
    st, out = run(tmp_path)
    assert st.status == "failed" and "outside the frame" in st.reason
    assert not (out / "report.json").exists()


@pytest.mark.parametrize("fov", [5.0, 150.0])
def test_extreme_fov(tmp_path, fov):
    # At 5 degrees the view is a narrow window far down the floor; at 150 nearly all of it.
    xz = (0.0, -3.0) if fov > 90 else (0.0, -1.2 / np.tan(np.radians(25)))
    make_case(tmp_path, fov=fov, sphere_xz=xz, radius=0.05 if fov < 10 else 0.25)
    st, out = run(tmp_path)
    if st.status == "done":
        assert_finite_composite(out)
    else:  # a clear per-job error, never a crash
        assert st.reason and "internal error" not in st.reason
