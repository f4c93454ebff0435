"""Render passes for compositors (compositing/aovs.py): they recombine into the composite."""

import numpy as np

from zcomp_cli.compositing.aovs import LAYERS, aov_layers, channel_names, recombine
from zcomp_cli.compositing.compositor import composite


def test_the_layers_recombine_into_the_composite():
    rng = np.random.default_rng(3)
    H, W = 24, 32
    bg = rng.uniform(0.0, 4.0, (H, W, 3)).astype(np.float32)  # HDR plate
    f_bg = rng.uniform(0.1, 1.0, (H, W, 3)).astype(np.float32)
    f_comp = f_bg * rng.uniform(0.3, 1.0, (H, W, 1)).astype(np.float32)
    s = np.zeros((H, W), bool)
    s[6:18, 8:26] = True
    m = np.zeros((H, W), np.float32)
    m[9:15, 12:20] = 1.0
    m[9, 12:20] = 0.4  # an anti-aliased edge
    res = composite(bg, f_bg, f_comp, s, m)
    layers = aov_layers(bg, f_bg, f_comp, res.ratio_blurred, m, res.balance, res.image)
    assert set(layers) == set(LAYERS) and all(v.dtype == np.float32 for v in layers.values())
    assert layers["object"].shape == (H, W, 4) and layers["shadow"].shape == (H, W, 1)
    assert np.allclose(recombine(layers), res.image, atol=1e-5)
    data, names = channel_names(layers)
    assert data.shape == (H, W, len(names)) and "object.A" in names and "shadow.Y" in names
    assert len(set(names)) == len(names)


def test_composite_aovs_writes_layers_that_recombine(tmp_path):
    """Through the CLI: ``--aovs`` writes aovs.exr per job, its layers recombine into
    composite.exr, the report records it, and ``--resume --aovs`` adds it to jobs made
    without it."""
    import json

    from hostile_project import make_project, run_composite
    from zcomp_cli.imageio import read_exr_channels, read_map

    make_project(tmp_path)
    out = tmp_path / "out"
    assert run_composite(tmp_path / "jobs.yaml", out).exit_code == 0
    assert not (out / "000_room_ball" / "aovs.exr").exists()
    assert run_composite(tmp_path / "jobs.yaml", out, "--resume", "--aovs").exit_code == 0
    for job in ("000_room_ball", "001_room_card"):
        ch = read_exr_channels(out / job / "aovs.exr")
        layers = {}
        for name in LAYERS:
            chans = sorted((k for k in ch if k.split(".")[0] == name), key=lambda k: "RGBAY".index(k[-1]))
            layers[name] = np.stack([ch[k] for k in chans], -1)
        comp = read_map(out / job / "composite.exr", channels=3)
        assert np.allclose(layers["composite"], comp, atol=1e-6)
        assert np.allclose(recombine(layers), comp, atol=1e-5)
        assert layers["object"][..., 3].max() > 0.5  # the object is in its layer
        assert "aovs.exr" in json.loads((out / job / "report.json").read_text())["outputs"]
    assert run_composite(tmp_path / "jobs.yaml", out, "--resume", "--aovs").exit_code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert {j["this_run"] for j in summary["jobs"]} == {"skipped"}
