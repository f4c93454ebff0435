"""Every convention of the ZeroComp / SpotLight archives, converted into zcomp's, on
hand-computed values (datasets/lvsn.py, datasets/bundle_exr.py, the background maps)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import gamma_encode
from zcomp_cli.datasets import lvsn
from zcomp_cli.datasets.bundle_exr import SPOTLIGHT_READING, ZEROCOMP_READING, _value_layer, read_bundle
from zcomp_cli.datasets.importer import _read_bg_map, safe_name
from zcomp_cli.datasets.lights import GT_FRAME, aligned_centre, lamp_entry, read_light_frames, select_frames
from zcomp_cli.errors import InputError
from zcomp_cli.imageio import write_exr
from zcomp_cli.metrics.protocol import object_crop_box


# ------------------------------------------------------------------ EXR layer layout
def test_channel_order_is_skylibs_hybrid():
    assert lvsn.order_channels(["A", "B", "G", "R"]) == ["R", "G", "B", "A"]
    assert lvsn.order_channels(["Z", "foo", "X", "Y"]) == ["X", "Y", "Z", "foo"]
    assert lvsn.order_channels(["V", "A"]) == ["A", "V"]  # unknown names come after


def test_group_layers_stacks_by_prefix_in_order():
    ch = {f"albedo.{c}": np.full((2, 3), v, np.float32) for c, v in zip("ABGR", (4, 3, 2, 1))}
    ch["mask.R"] = np.ones((2, 3), np.float32)
    layers = lvsn.group_layers(ch)
    assert set(layers) == {"albedo", "mask"}
    assert layers["albedo"].shape == (2, 3, 4)
    assert layers["albedo"][0, 0].tolist() == [1, 2, 3, 4]  # R, G, B, A
    assert layers["mask"].shape == (2, 3, 1)


def test_value_channel_zerocomp_0_spotlight_2_premultiplied_by_alpha():
    layer = np.array([[[1.0, 2.0, 3.0, 0.5]]], np.float32)  # R, G, B, A
    v0, pre = _value_layer(layer, ZEROCOMP_READING.value_channel)  # dataset_labo: [:, :, :1]
    v2, _ = _value_layer(layer, SPOTLIGHT_READING.value_channel)  # dataset_render: [:, :, 2:4]
    assert pre
    assert v0[0, 0] == pytest.approx(2.0)  # 1.0 / 0.5
    assert v2[0, 0] == pytest.approx(6.0)  # 3.0 / 0.5
    one, pre1 = _value_layer(np.array([[[1.5]]], np.float32), 2)  # 1 channel: it, no alpha
    assert not pre1 and one[0, 0] == pytest.approx(1.5)


def test_unpremultiply_known_values_and_degenerate_alpha():
    assert lvsn.unpremultiply(1.5, 0.5) == pytest.approx(3.0)
    assert lvsn.unpremultiply(0.2, 0.0) == 0.0  # no coverage: no data, not a division by 0
    assert lvsn.unpremultiply(0.2, 1e-6) == 0.0  # below ALPHA_EPS
    out = lvsn.unpremultiply(np.array([[np.nan, np.inf]]), np.array([[1.0, 1.0]]))
    assert out.tolist() == [[0.0, 0.0]]
    rgb = lvsn.unpremultiply(np.array([[[0.2, 0.4, 0.1]]]), np.array([[0.5]]))
    assert rgb[0, 0] == pytest.approx([0.4, 0.8, 0.2])


# ------------------------------------------------------------------ normals
def test_bundle_normals_zerocomp_negates_z():
    # Blender shader camera space (z forward): a face toward the camera is -z
    n = lvsn.bundle_normals_to_camera(np.array([0.6, 0.0, -0.8]), "blender-camera")
    assert n == pytest.approx([0.6, 0.0, 0.8])
    assert lvsn.bundle_normals_to_camera(np.array([0.6, 0.0, 0.8]), "opengl") == pytest.approx([0.6, 0.0, 0.8])


def test_bundle_normals_encoded_layer_is_decoded_first_by_the_zerocomp_rule():
    # every value >= 0: the layer holds n * 0.5 + 0.5 (comp_normal_to_openrooms_normal)
    e = np.array([[0.8, 0.5, 0.1], [0.5, 1.0, 0.5]])
    n = lvsn.bundle_normals_to_camera(e, "blender-camera", decode_nonnegative=True)
    assert n[0] == pytest.approx([0.6, 0.0, 0.8])
    assert n[1] == pytest.approx([0.0, 1.0, 0.0])
    # SpotLight's loader always reads signed vectors
    assert lvsn.bundle_normals_to_camera(e, "opengl")[0] == pytest.approx(np.array([0.8, 0.5, 0.1]) / np.sqrt(0.9))


def test_bundle_normals_premultiplied_are_renormalised_and_zero_stays_zero():
    n = lvsn.bundle_normals_to_camera(np.array([[0.3, 0.0, -0.4], [0.0, 0.0, 0.0], [-0.1, 0, 0]]), "blender-camera")
    assert n[0] == pytest.approx([0.6, 0.0, 0.8])
    assert n[1].tolist() == [0.0, 0.0, 0.0]


def test_stablenormal_png_negates_x():
    e = np.array([64, 128, 255]) / 255.0
    n = lvsn.stablenormal_png_to_camera_normals(e)
    # 2e - 1 = (-0.49804, 0.00392, 1.0); x negated; / 1.11716
    assert n == pytest.approx([0.44581, 0.00351, 0.89512], abs=1e-5)
    grey = lvsn.stablenormal_png_to_camera_normals(np.array([128, 128, 128]) / 255.0)
    assert grey.tolist() == [0.0, 0.0, 0.0]  # 8-bit "no normal", not a direction


def test_facing_fraction_counts_normals_toward_the_camera():
    K = Camera.from_fov(50, 4, 4).K
    n = np.zeros((4, 4, 3), np.float32)
    n[..., 2] = 1.0          # facing the camera everywhere
    n[0, :, 2] = -1.0        # one row faces away
    assert lvsn.facing_fraction(n, K) == pytest.approx(0.75)
    assert np.isnan(lvsn.facing_fraction(np.zeros((4, 4, 3)), K))


# ------------------------------------------------------------------ photos and PNG maps
def test_gamma_encode_is_the_official_gamma_correction():
    assert float(gamma_encode(0.5)) == pytest.approx(0.5 ** (1 / 2.2))
    assert float(gamma_encode(0.5)) == pytest.approx(0.72974, abs=1e-5)
    assert gamma_encode(np.array([1.5, -0.2, np.nan])).tolist() == [1.0, 0.0, 0.0]


def test_png_maps_are_data_not_srgb(tmp_path):
    cam = Camera.from_fov(50, 2, 2)
    Image.fromarray(np.full((2, 2, 3), 128, np.uint8)).save(tmp_path / "a_bg_diffuse.png")
    alb, note = _read_bg_map("albedo", tmp_path / "a_bg_diffuse.png", cam)
    assert alb[0, 0] == pytest.approx([128 / 255] * 3)  # 0.50196, not sRGB-decoded 0.2158
    assert "no sRGB" in note
    Image.fromarray(np.full((2, 2), 51, np.uint8)).save(tmp_path / "a_bg_roughness.png")
    r, _ = _read_bg_map("roughness", tmp_path / "a_bg_roughness.png", cam)
    assert r[0, 0] == pytest.approx(0.2)


def test_bg_depth_channel_0_metres_invalid_to_zero(tmp_path):
    cam = Camera.from_fov(50, 2, 2)
    d = np.array([[[2.5, 9, 9], [-1, 9, 9]], [[np.inf, 9, 9], [1e10, 9, 9]]], np.float32)
    write_exr(tmp_path / "a_bg_depth.exr", d)
    depth, _ = _read_bg_map("depth", tmp_path / "a_bg_depth.exr", cam)
    assert depth.tolist() == [[2.5, 0.0], [0.0, 0.0]]


def test_bg_normal_png_facing_away_is_refused(tmp_path):
    cam = Camera.from_fov(50, 4, 4)
    # n = (0, 0, -1) everywhere once decoded: every pixel faces away
    Image.fromarray(np.full((4, 4, 3), [128, 128, 0], np.uint8)).save(tmp_path / "a_bg_normal.png")
    with pytest.raises(InputError, match="face away"):
        _read_bg_map("normals", tmp_path / "a_bg_normal.png", cam)
    Image.fromarray(np.full((4, 4, 3), [128, 128, 255], np.uint8)).save(tmp_path / "b_bg_normal.png")
    n, _ = _read_bg_map("normals", tmp_path / "b_bg_normal.png", cam)
    assert n[0, 0] == pytest.approx([0.0, 0.0, 1.0], abs=0.01)


# ------------------------------------------------------------------ a bundle, hand-made
def _tiny_bundle(path, *, normal_z: float, drop=()):
    """4 x 4, the object on the 2 x 2 centre, depth 1.5 at alpha 0.5 (premultiplied:
    3 m), the footprint below it."""
    h = w = 4
    a = np.zeros((h, w), np.float32)
    a[1:3, 1:3] = 1.0
    a[1, 1] = 0.5
    layers = {
        "depth": np.stack([a * 3.0] * 3 + [a], -1),
        "footprint_depth": np.stack([np.pad(np.full((1, 4), 3.2, np.float32), ((3, 0), (0, 0)))] * 3
                                    + [np.pad(np.ones((1, 4), np.float32), ((3, 0), (0, 0)))], -1),
        "normals": np.stack([a * -0.36, a * 0.48, a * normal_z, a], -1),
        "albedo": np.stack([a * 0.5, a * 0.25, a * 0.1, a], -1),
        "background": np.full((h, w, 3), 0.3, np.float32),
        "composite": np.full((h, w, 3), 0.2, np.float32),
        "mask": a[..., None],
    }
    names, arrs = [], []
    for k, v in layers.items():
        if k in drop:
            continue
        for i in range(v.shape[-1]):
            names.append(f"{k}.{'R' if k == 'mask' else 'RGBA'[i]}")
            arrs.append(v[..., i])
    write_exr(path, np.stack(arrs, -1), channel_names=names)


def test_read_bundle_zerocomp_hand_values(tmp_path):
    _tiny_bundle(tmp_path / "c_bundle0001.exr", normal_z=-0.8)
    bc = read_bundle(tmp_path / "c_bundle0001.exr", ZEROCOMP_READING)
    b = bc.bundle
    assert b.camera.width == 4 and b.camera.fov_deg == pytest.approx(50.0)
    assert b.depth[1, 2] == pytest.approx(3.0) and b.depth[1, 1] == pytest.approx(3.0)  # 1.5 / 0.5
    assert b.depth[0, 0] == 0.0
    assert b.normals[1, 2] == pytest.approx([-0.36, 0.48, 0.8])  # z negated
    assert b.albedo[1, 1] == pytest.approx([0.5, 0.25, 0.1])  # straight, not halved
    assert b.mask[1, 1] == pytest.approx(0.5)
    assert b.footprint_depth[3].tolist() == pytest.approx([3.2] * 4)
    assert bc.background[0, 0] == pytest.approx([0.3] * 3) and bc.reference[0, 0] == pytest.approx([0.2] * 3)
    assert any("roughness" in n for n in bc.notes)
    assert bc.checks["object_normals_facing_fraction"] == 1.0


def test_read_bundle_wrong_frame_is_reported_not_passed_on(tmp_path):
    _tiny_bundle(tmp_path / "c_bundle0001.exr", normal_z=0.8)  # already +z: ZeroComp would flip it away
    with pytest.raises(InputError, match="face away.*--bundle-normals opengl"):
        read_bundle(tmp_path / "c_bundle0001.exr", ZEROCOMP_READING)
    n = read_bundle(tmp_path / "c_bundle0001.exr", ZEROCOMP_READING, normals_frame="opengl").bundle.normals
    assert n[1, 2] == pytest.approx([-0.36, 0.48, 0.8])
    assert read_bundle(tmp_path / "c_bundle0001.exr", SPOTLIGHT_READING).bundle.normals[1, 2, 2] > 0


def test_read_bundle_missing_layers_are_all_named(tmp_path):
    _tiny_bundle(tmp_path / "c_bundle0001.exr", normal_z=-0.8, drop=("normals", "footprint_depth"))
    with pytest.raises(InputError, match=r"c_bundle0001.exr: missing layers footprint_depth, normals"):
        read_bundle(tmp_path / "c_bundle0001.exr", ZEROCOMP_READING)


def test_read_bundle_empty_mask(tmp_path):
    names = ["mask.R"] + [f"{k}.R" for k in ("albedo", "depth", "footprint_depth", "normals",
                                             "background", "composite")]
    write_exr(tmp_path / "e_bundle0001.exr", np.zeros((3, 3, len(names)), np.float32), channel_names=names)
    with pytest.raises(InputError, match="mask layer is empty"):
        read_bundle(tmp_path / "e_bundle0001.exr", ZEROCOMP_READING)


def test_read_bundle_non_finite_layers_become_zero(tmp_path):
    _tiny_bundle(tmp_path / "c_bundle0001.exr", normal_z=-0.8)
    from zcomp_cli.imageio import read_exr_channels

    ch = read_exr_channels(tmp_path / "c_bundle0001.exr")
    ch["background.R"][0, 0] = np.nan
    ch["depth.R"][2, 2] = np.inf
    names = list(ch)
    write_exr(tmp_path / "n_bundle0001.exr", np.stack([ch[c] for c in names], -1), channel_names=names)
    bc = read_bundle(tmp_path / "n_bundle0001.exr", ZEROCOMP_READING)
    assert bc.background[0, 0, 0] == 0.0 and any("non-finite" in n for n in bc.notes)
    assert bc.bundle.depth[2, 2] == 0.0 and np.isfinite(bc.bundle.depth).all()


# ------------------------------------------------------------------ SpotLight lights
def test_spotlight_light_axes_and_distance():
    c = np.array([0.0, 0.0, -3.0])
    assert lvsn.spotlight_light_to_camera([0, 1, 0], c, 10) == pytest.approx([0, 0, -13])  # forward: away
    assert lvsn.spotlight_light_to_camera([1, 0, 0], c, 10) == pytest.approx([10, 0, -3])  # right
    assert lvsn.spotlight_light_to_camera([0, 0, 1], c, 10) == pytest.approx([0, 10, -3])  # up
    assert lvsn.spotlight_light_to_camera([0.3, -0.2, 0.9], [1, 2, -4], 10) == pytest.approx([4, 11, -2])
    with pytest.raises(ValueError):
        lvsn.spotlight_light_to_camera([np.nan, 0, 0], c, 10)


def test_lamp_entry_schema():
    from zcomp_cli.datasets.lights import LightFrame

    lamp = lamp_entry(LightFrame(GT_FRAME, (0.0, 0.0, 1.0)), [0.5, -1.0, -3.0])
    assert lamp == {"type": "lamp", "position": [0.5, 9.0, -3.0], "radius_m": 1.0, "power": "auto"}


def test_aligned_centre_moves_along_the_ray():
    from zcomp_cli.compositing.alignment import DepthAlignment

    c = aligned_centre([1.0, 0.5, -2.0], DepthAlignment(1.5, 0.5, "affine", 20, 0.0))  # z 2 -> 3.5
    assert c == pytest.approx([1.75, 0.875, -3.5])
    same = aligned_centre([1.0, 0.5, -2.0], DepthAlignment(-1.0, 0.0, "affine", 20, 0.0))
    assert same == pytest.approx([1.0, 0.5, -2.0])


def test_light_path_file_errors_name_the_field(tmp_path):
    p = tmp_path / "x_light_path_dto.json"
    p.write_text(json.dumps({"light_frames": [{"name": "0000", "blender_light_xyz_position_object_space": [1, 2]}]}))
    with pytest.raises(InputError, match=r"light_frames\[0\].blender_light_xyz_position_object_space"):
        read_light_frames(p)
    p.write_text("{not json")
    with pytest.raises(InputError, match="cannot read the light path"):
        read_light_frames(p)
    p.write_text(json.dumps({"light_frames": [{"name": "0000", "blender_light_xyz_position_object_space": [1, 0, 0]}]}))
    frames = read_light_frames(p)
    with pytest.raises(InputError, match="no light frame named 'gt_dir'.*0000"):
        select_frames(frames, "gt", str(p))
    assert select_frames(frames, "all", str(p)) == frames and select_frames(frames, "none", str(p)) == []


# ------------------------------------------------------------------ the object crop
def test_object_crop_box_grows_25_percent_each_side():
    m = np.zeros((64, 64))
    m[20:30, 10:20] = 1.0  # columns 10..19, rows 20..29
    assert object_crop_box(m) == (7, 17, 23, 33)  # 10 - 2.5 -> 7, 20 + 2.5 -> 23
    m2 = np.zeros((16, 16))
    m2[0:4, 12:16] = 1.0
    assert object_crop_box(m2) == (11, 0, 16, 5)  # clipped to the image
    with pytest.raises(InputError, match="selects no pixel"):
        object_crop_box(np.zeros((4, 4)))


def test_case_names_become_unique_zcomp_names():
    taken: set[str] = set()
    assert safe_name("9C4A1774-12d053d172_06_crop_B07QFB1TMP", taken) == "9C4A1774-12d053d172_06_crop_B07QFB1TMP"
    assert safe_name("a b/c", taken) == "a_b_c"
    assert safe_name("a b/c", taken) == "a_b_c-2"
    assert safe_name(".hidden", taken) == "hidden"
    assert len(safe_name("x" * 300, taken)) <= 100


# ------------------------------------------------------------------ published figures
def test_bundled_figures_are_the_supplementary_tables():
    from zcomp_cli.metrics.published import PUBLISHED, format_value, rows_for

    entry, crop = rows_for("zerocomp-labo", "object-crop")
    assert entry is PUBLISHED["zerocomp-labo"] and len(crop) == 13
    assert all(set(r["metrics"]) == {"psnr", "rmse", "si-rmse", "ssim", "mae", "lpips", "flip"} for r in crop)
    zc = {r["name"]: r["metrics"] for r in crop}
    assert zc["ZeroComp OpenRooms"]["psnr"] == 24.4 and zc["ZeroComp InteriorVerse"]["lpips"] == 0.0872
    _, full = rows_for("zerocomp-labo", "full")
    assert [r["metrics"]["psnr"] for r in full] == [31.7]
    assert all("supp" in r["source"] for r in crop + full)
    assert rows_for("spotlight", "full")[1] == [] and rows_for(None, "full") == (None, [])
    assert (format_value("psnr", 24.4), format_value("ssim", 0.87), format_value("lpips", 0.067)) == \
        ("24.4", "0.870", "0.0670")
