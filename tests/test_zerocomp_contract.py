"""The official-checkpoint contract (DESIGN.md section 4), encoded independently of the
code under test: expected channel values are written out by hand, windows are checked on
the conditioning's own gradients, and the blur is compared with a reflect-padded
convolution built here (torch's pad + conv2d: what torchvision's GaussianBlur runs)."""

import json

import numpy as np
import pytest

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import K_from_fov
from zcomp_cli.errors import WeightsError
from zcomp_cli.maps import SceneMaps
from zcomp_cli.renderers.base import RenderRequest
from zcomp_cli.renderers.zerocomp.conditioning import build_conditioning, square_window

from zerocomp_dummy import save_dummy

S = 8  # a square frame: conditioning at S needs no resize, so values are exact


def _uniform(normal, albedo, image, depth=2.0, known=True, size=S):
    maps = SceneMaps(depth=np.full((size, size), depth, np.float32),
                     normals=np.broadcast_to(np.asarray(normal, np.float32), (size, size, 3)).copy(),
                     albedo=np.full((size, size, 3), albedo, np.float32))
    img = np.full((size, size, 3), image, np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        shading = np.clip(np.nan_to_num(img / np.float32(albedo), nan=1e-5, posinf=1e3), 1e-5, 1e3)
    kn = np.full((size, size), known, bool)
    cam = Camera(K_from_fov(50, size, size), size, size)
    return RenderRequest(maps, shading.astype(np.float32), kn, cam, image=img)


def _pixel(req, channels=11):
    c = build_conditioning(req, channels, S)
    assert c.shape == (channels, S, S)
    assert np.all(c == c[:, :1, :1])  # uniform input -> uniform conditioning
    return c[:, 0, 0]


def test_camera_facing_plane_by_hand():
    # grey plane 2 m away, facing the camera, albedo 0.5, linear radiance 0.25:
    # shading = 0.25 ** (1 / 2.2) / 0.5 = 0.532520... / 0.5 = 1.065041...
    c = _pixel(_uniform((0, 0, 1), 0.5, 0.25))
    expect = [2.0, 0.5, 0.5, 1.0, 0.5, 0.5, 0.5, 1.0650411, 1.0650411, 1.0650411, 1.0]
    np.testing.assert_allclose(c, expect, rtol=1e-6)


def test_floor_by_hand():
    # a floor seen by a level camera: normal +y (up) -> green = 1, blue = 0.5 (not 0 or 1)
    # albedo 0.8, radiance 0.1: 0.1 ** (1/2.2) = 0.351119..., / 0.8 = 0.438899...
    c = _pixel(_uniform((0, 1, 0), 0.8, 0.1, depth=3.5))
    expect = [3.5, 0.5, 1.0, 0.5, 0.8, 0.8, 0.8, 0.4388990, 0.4388990, 0.4388990, 1.0]
    np.testing.assert_allclose(c, expect, rtol=1e-6)
    # a wall on the right of the view faces left: -x -> red = 0
    np.testing.assert_allclose(_pixel(_uniform((-1, 0, 0), 0.8, 0.1))[1:4], [0.0, 0.5, 0.5])


def test_zero_albedo_gives_floor_not_spike():
    # official: shading = 1e-5 wherever albedo <= 1e-5 (not 1e3)
    for alb in (0.0, 1e-6, 1e-5):
        c = _pixel(_uniform((0, 0, 1), alb, 0.3))
        np.testing.assert_allclose(c[7:10], [1e-5] * 3, rtol=1e-6)
        np.testing.assert_allclose(c[4:7], [alb] * 3, atol=1e-12)
    # above the threshold the division happens: 0.3 ** (1/2.2) / 2e-3 = 289.27 ...
    c = _pixel(_uniform((0, 0, 1), 2e-3, 0.3))
    np.testing.assert_allclose(c[7], 289.2663, rtol=1e-5)


def test_over_range_pixel_is_clipped_before_gamma():
    # HDR radiance 4.0 on albedo 0.5: official clips to 1 first -> 1 / 0.5 = 2.0
    # (without the clip: 4 ** (1/2.2) / 0.5 = 3.75)
    c = _pixel(_uniform((0, 0, 1), 0.5, 4.0))
    np.testing.assert_allclose(c[7:10], [2.0] * 3, rtol=1e-6)
    # and a bright pixel on a dark albedo hits the 1e3 ceiling
    c = _pixel(_uniform((0, 0, 1), 5e-4, 1.0))
    np.testing.assert_allclose(c[7:10], [1e3] * 3, rtol=1e-6)


def test_masked_pixels_are_minus_one():
    c = _pixel(_uniform((0, 0, 1), 0.5, 0.25, known=False))
    np.testing.assert_array_equal(c[7:11], [-1, -1, -1, -1])
    np.testing.assert_allclose(c[:7], [2.0, 0.5, 0.5, 1.0, 0.5, 0.5, 0.5], rtol=1e-6)


def _ramp_request(h=480, w=640, g=0.01, roi=None):
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    depth = 1.0 + g * (xx + yy)  # equal gradient (g metres / pixel) along x and y
    maps = SceneMaps(depth=depth, normals=np.broadcast_to(np.float32([0, 0, 1]), (h, w, 3)).copy(),
                     albedo=np.full((h, w, 3), 0.5, np.float32))
    shading = np.ones((h, w, 3), np.float32)
    return RenderRequest(maps, shading, np.ones((h, w), bool), Camera(K_from_fov(50, w, h), w, h),
                         roi=roi)


@pytest.mark.parametrize("roi", [None, (20, 300, 140, 470), (500, 10, 639, 200)])
def test_640x480_depth_ramp_keeps_equal_gradients(roi):
    R = 128
    req = _ramp_request(roi=roi)
    box = square_window(roi, (480, 640))
    assert box[2] - box[0] == box[3] - box[1] == 480  # the official short-side scale
    if roi is not None:  # the job's region lies inside its window
        assert box[0] <= roi[0] and roi[2] <= box[2] and box[1] <= roi[1] and roi[3] <= box[3]
    d = build_conditioning(req, 11, R, box)[0]
    inner = d[4:-4, 4:-4]
    gx = np.diff(inner, axis=1).mean()
    gy = np.diff(inner, axis=0).mean()
    # isotropic: 480 frame px -> 128 model px, so 0.01 * 480 / 128 m per model pixel on both
    # axes; a squash to 128 x 128 would give 0.05 along x and 0.0375 along y
    assert gx == pytest.approx(0.0375, rel=1e-3)
    assert gy == pytest.approx(0.0375, rel=1e-3)
    # the window is where it says: its top-left model pixel is the box's top-left depth
    x0, y0 = box[0], box[1]
    assert d[0, 0] == pytest.approx(1.0 + 0.01 * (x0 + y0 + 480 / R / 2 - 0.5), abs=0.02)


def test_long_roi_is_padded_not_cut():
    # an object region wider than the frame is tall: the window grows to hold it and the
    # rows past the frame are unknown (mask -1), never squashed
    req = _ramp_request(h=100, w=300, roi=(10, 20, 290, 80))
    box = square_window(req.roi, (100, 300))
    assert box == (10, -90, 290, 190)
    c = build_conditioning(req, 11, 56, box)
    assert (c[10, :16] == -1).all() and (c[10, 22:34] == 1).all() and (c[10, -16:] == -1).all()


def _torchvision_blur(mask, size=15, sigma=1.5):
    """torchvision.transforms.functional.gaussian_blur on a float image, step by step:
    kernel from linspace, reflect pad (torch.nn.functional.pad), conv2d."""
    import torch

    half = (size - 1) * 0.5
    x = torch.linspace(-half, half, steps=size, dtype=torch.float64)
    k1 = torch.exp(-0.5 * (x / sigma) ** 2)
    k1 = k1 / k1.sum()
    k2 = k1[:, None] * k1[None, :]
    img = torch.from_numpy(np.asarray(mask, np.float64))[None, None]
    p = size // 2
    img = torch.nn.functional.pad(img, [p, p, p, p], mode="reflect")
    return torch.nn.functional.conv2d(img, k2[None, None])[0, 0].numpy()


def test_blur_at_frame_border_matches_reflect_convolution():
    from zcomp_cli.compositing import blur_weight

    s = np.zeros((40, 48), bool)
    s[:, :4] = True          # a band along the left border
    s[30:, 20:30] = True     # a block touching the bottom border
    s[0, 40] = True          # a single pixel on the top border
    w = blur_weight(s)
    ref = _torchvision_blur(s)
    np.testing.assert_allclose(w, ref, atol=1e-6)
    # independent of torch too: numpy's reflect pad and a direct 2-D sum
    k = np.exp(-0.5 * (np.arange(-7, 8) / 1.5) ** 2)
    k /= k.sum()
    padded = np.pad(s.astype(np.float64), 7, mode="reflect")
    direct = np.zeros(s.shape)
    for dy in range(15):
        for dx in range(15):
            direct += k[dy] * k[dx] * padded[dy:dy + 40, dx:dx + 48]
    np.testing.assert_allclose(w, direct, atol=1e-6)
    # zero padding fades the band at the border (0.73); reflection keeps it near full (0.98)
    zero = np.pad(s.astype(np.float64), 7, mode="constant")
    direct_zero = sum(k[dy] * k[dx] * zero[dy:dy + 40, dx:dx + 48] for dy in range(15) for dx in range(15))
    assert w[20, 0] > 0.98 and direct_zero[20, 0] < 0.75
    # 'symmetric' (edge repeated, scipy's "reflect") is a different, wrong answer
    sym = np.pad(s.astype(np.float64), 7, mode="symmetric")
    direct_sym = sum(k[dy] * k[dx] * sym[dy:dy + 40, dx:dx + 48] for dy in range(15) for dx in range(15))
    assert np.abs(direct_sym - w).max() > 1e-3


def test_epsilon_prediction_base_is_refused(tmp_path):
    from zcomp_cli.renderers.zerocomp import ZeroCompRenderer

    ck, base = save_dummy(tmp_path, 11)
    cfg_path = base / "scheduler" / "scheduler_config.json"
    cfg = json.loads(cfg_path.read_text())
    cfg["prediction_type"] = "epsilon"
    cfg_path.write_text(json.dumps(cfg))
    r = ZeroCompRenderer(ck, base, steps=1, device="cpu", resolution=16)
    with pytest.raises(WeightsError, match="prediction_type='epsilon'"):
        r.render([_uniform((0, 0, 1), 0.5, 0.25, size=16)])


def test_training_shading_follows_the_official_loader():
    from zcomp_cli.training.config import TrainConfig
    from zcomp_cli.training.trainer import make_batch

    h, w = 12, 20  # non-square: cut to a 12 x 12 window, not squashed
    sample = {"image": np.full((h, w, 3), 0.25, np.float32),
              "depth": np.tile(np.arange(w, dtype=np.float32), (h, 1)) + 1.0,
              "normals": np.broadcast_to(np.float32([0, 0, 1]), (h, w, 3)).copy(),
              "albedo": np.full((h, w, 3), 0.5, np.float32)}
    got = {}
    for layout in ("openrooms", "zcomp"):
        cfg = TrainConfig(base="b", data_root="d", output_dir="o", layout=layout, resolution=12)
        rng = np.random.default_rng(3)
        vals = []
        for _ in range(10):
            tgt, cond = make_batch([sample], rng, cfg, 11)
            assert tgt.shape == (1, 3, 12, 12) and cond.shape == (1, 11, 12, 12)
            np.testing.assert_allclose(np.diff(cond[0, 0], axis=1), 1.0, rtol=1e-6)  # 1 m / px
            known = cond[0, 10] == 1
            vals.append(cond[0, 7][known])
        got[layout] = np.concatenate(vals)
        assert got[layout].size > 0
    np.testing.assert_allclose(got["openrooms"], 0.5, rtol=1e-6)        # 0.25 / 0.5
    np.testing.assert_allclose(got["zcomp"], 1.0650411, rtol=1e-6)      # 0.25 ** (1/2.2) / 0.5
