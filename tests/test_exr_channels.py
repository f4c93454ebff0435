"""Issue 39, defect 8: an EXR's channels count against the pixel budget (a 619 KB bundle
EXR of 301 channels took 2.4 GB), and an error lists a bounded number of its layers."""

from __future__ import annotations

import numpy as np
import pytest

from zcomp_cli.errors import InputError


def test_channels_count_against_the_pixel_budget(tmp_path, monkeypatch):
    from zcomp_cli.imageio import read_exr_channels, write_exr
    from zcomp_cli.limits import MAX_PIXELS_ENV

    p = tmp_path / "many.exr"
    names = [f"layer{i:03d}.R" for i in range(301)]
    write_exr(p, np.zeros((32, 32, 301), np.float32), channel_names=names)
    monkeypatch.setenv(MAX_PIXELS_ENV, str(32 * 32 * 50))  # 50 RGBA images' worth
    with pytest.raises(InputError, match="301 channels"):
        read_exr_channels(p)
    monkeypatch.setenv(MAX_PIXELS_ENV, str(32 * 32 * 100))
    assert len(read_exr_channels(p)) == 301


def test_a_missing_layer_error_lists_a_bounded_number_of_layers(tmp_path):
    from zcomp_cli.datasets.bundle_exr import MAX_LAYERS_SHOWN, ZEROCOMP_READING, read_bundle
    from zcomp_cli.imageio import write_exr

    p = tmp_path / "bundle.exr"
    names = [f"junk{i:03d}.R" for i in range(300)]
    write_exr(p, np.zeros((8, 8, 300), np.float32), channel_names=names)
    with pytest.raises(InputError) as e:
        read_bundle(p, ZEROCOMP_READING)
    msg = str(e.value)
    assert "and 288 more" in msg and msg.count("junk") == MAX_LAYERS_SHOWN


def test_an_all_nan_normals_map_is_refused_not_made_one_constant_normal(tmp_path):
    """Issue 39 (low): an all-NaN normals layer was imported as one constant normal, and
    the bundle check said "nan%"."""
    from zcomp_cli.camera import Camera
    from zcomp_cli.datasets.importer import _read_bg_map
    from zcomp_cli.imageio import write_exr

    p = tmp_path / "normals.exr"
    write_exr(p, np.full((8, 8, 3), np.nan, np.float32))
    with pytest.raises(InputError, match="no finite value"):
        _read_bg_map("normals", p, Camera.from_fov(50.0, 8, 8))
    z = tmp_path / "zero.exr"
    write_exr(z, np.full((8, 8, 3), 0.5, np.float32))  # 2 e - 1 = 0: no normal at all
    with pytest.raises(InputError, match="no usable normal") as e:
        _read_bg_map("normals", z, Camera.from_fov(50.0, 8, 8))
    assert "nan%" not in str(e.value)


def test_object_crop_eval_skips_a_bad_or_tiny_mask_and_scores_the_rest(tmp_path):
    """Issue 39 (low): under --region object-crop a bad object mask aborted the whole
    eval, and a 1-pixel crop made the mean PSNR inf. Both pairs are now listed as not
    scored, with the reason, and the good pair is scored."""
    from zcomp_cli.imageio import write_png
    from zcomp_cli.metrics.evaluate import MIN_OBJECT_CROP_PX, Pair, evaluate

    rng = np.random.default_rng(0)
    pairs = []
    for name, mask in (("good", "big"), ("tiny", "one"), ("broken", "bad")):
        d = tmp_path / name
        d.mkdir()
        ref = rng.random((32, 32, 3)).astype(np.float32)
        write_png(d / "ref.png", ref)
        write_png(d / "pred.png", np.clip(ref + 0.05 * (name != "tiny"), 0, 1))
        m = np.zeros((32, 32), np.float32)
        if mask == "big":
            m[8:24, 8:24] = 1
        elif mask == "one":
            m[5, 5] = 1
        if mask == "bad":
            (d / "object_mask.png").write_bytes(b"not a png")
        else:
            write_png(d / "object_mask.png", m, srgb_encode=False)
        pairs.append(Pair(name, d / "pred.png", d / "ref.png", None, None, d / "object_mask.png"))
    res = evaluate(pairs, ["psnr", "mae"], region="object-crop")
    assert [p.name for p in res.pairs] == ["good"]
    assert np.isfinite(res.mean["psnr"])
    assert set(res.unscored) == {"tiny", "broken"}
    assert f"under {MIN_OBJECT_CROP_PX}x{MIN_OBJECT_CROP_PX}" in res.unscored["tiny"]
