"""LPIPS: equality with the reference ``lpips`` package (identical random backbone
weights, its shipped v0.1 linear weights) and the missing-weights errors.

lpips imports torchvision at import time and torchvision cannot be installed beside
the project's CPU torch, so a minimal fake ``torchvision`` module is put into
``sys.modules`` whose ``models.alexnet`` returns OUR AlexNet with seeded random weights.
"""

import importlib
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch

from zcomp_cli.errors import WeightsError
from zcomp_cli.metrics import lpips as L


@pytest.fixture
def ref_lpips(monkeypatch):
    """(reference LPIPS module, our AlexNet features it computes with)."""
    if importlib.util.find_spec("lpips") is None:
        pytest.skip("lpips not installed (pip install --no-deps lpips)")
    torch.manual_seed(0)
    feats = L.make_alexnet_features()

    def alexnet(pretrained=False, **kw):
        assert not pretrained, "the test must never ask for downloaded weights"
        return types.SimpleNamespace(features=feats.features)

    tv = types.ModuleType("torchvision")
    tv_models = types.ModuleType("torchvision.models")
    tv_models.alexnet = alexnet
    tv.models = tv_models
    monkeypatch.setitem(sys.modules, "torchvision", tv)
    monkeypatch.setitem(sys.modules, "torchvision.models", tv_models)
    # Import lpips under the fake and forget it afterwards (no leak to other tests).
    for name in [n for n in sys.modules if n == "lpips" or n.startswith("lpips.")]:
        monkeypatch.delitem(sys.modules, name)
    lpips = importlib.import_module("lpips")
    ref = lpips.LPIPS(net="alex", pnet_rand=True, verbose=False).eval()
    yield ref, feats, Path(lpips.__file__).parent / "weights" / "v0.1" / "alex.pth"
    for name in [n for n in sys.modules if n == "lpips" or n.startswith("lpips.")]:
        sys.modules.pop(name, None)


@pytest.fixture
def weight_files(ref_lpips, tmp_path):
    """A torchvision-style AlexNet state dict (with a classifier to ignore) + alex.pth."""
    _, feats, alex = ref_lpips
    sd = {k: v.clone() for k, v in feats.state_dict().items()}
    sd["classifier.1.weight"] = torch.zeros(4, 4)
    backbone = tmp_path / L.BACKBONE_FILE
    torch.save(sd, backbone)
    return backbone, alex


def _images(seed, h=48, w=64):
    rng = np.random.default_rng(seed)
    return rng.random((h, w, 3)).astype(np.float32), rng.random((h, w, 3)).astype(np.float32)


def test_equals_reference_lpips(ref_lpips, weight_files):
    ref, _, _ = ref_lpips
    model = L.load_lpips(*weight_files)
    a, b = _images(1)
    for size in (None, 256):
        x0, x1 = L.to_lpips_tensor(a, size=size), L.to_lpips_tensor(b, size=size)
        with torch.no_grad():
            want = float(ref(x0, x1))
        got = L.lpips_distance(model, a, b, size=size)
        assert got == pytest.approx(want, abs=1e-5, rel=1e-5)
        assert got > 0
    # Identical images: exactly 0.
    assert L.lpips_distance(model, a, a) == 0.0
    # A full mask agrees with the reference's spatial (upsampled) map mean.
    x0, x1 = L.to_lpips_tensor(a), L.to_lpips_tensor(b)
    ref_sp = lpips_spatial(ref, x0, x1)
    assert L.lpips_distance(model, a, b, np.ones(a.shape[:2])) == pytest.approx(ref_sp, abs=1e-5)


def lpips_spatial(ref, x0, x1):
    import lpips

    sp = lpips.LPIPS(net="alex", pnet_rand=True, spatial=True, verbose=False).eval()
    sp.load_state_dict(ref.state_dict())
    with torch.no_grad():
        return float(sp(x0, x1).mean())


def test_input_scaling_is_srgb_to_minus_one_one():
    t = L.to_lpips_tensor(np.ones((4, 4, 3), np.float32), size=None)
    assert t.shape == (1, 3, 4, 4) and torch.all(t == 1.0)
    t = L.to_lpips_tensor(np.zeros((300, 200, 3), np.float32))
    assert t.shape == (1, 3, 256, 256) and torch.all(t == -1.0)


def test_missing_weights_name_the_paths(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "th"))
    monkeypatch.delenv(L.ENV_BACKBONE, raising=False)
    with pytest.raises(WeightsError) as ei:
        L.load_lpips()
    msg = str(ei.value)
    assert str(tmp_path / "th" / "hub" / "checkpoints" / L.BACKBONE_FILE) in msg
    assert "--lpips-backbone" in msg and L.ENV_BACKBONE in msg
    monkeypatch.setenv(L.ENV_BACKBONE, str(tmp_path / "nope.pth"))
    with pytest.raises(WeightsError, match="nope.pth"):
        L.load_lpips()
    st = L.try_load_lpips()
    assert st.model is None and "nope.pth" in st.reason


def test_wrong_weights_rejected(tmp_path):
    bad = tmp_path / "bad.pth"
    torch.save({"foo": torch.zeros(1)}, bad)
    with pytest.raises(WeightsError, match="AlexNet"):
        L.load_lpips(bad, bad)
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(WeightsError, match="cannot read"):
        L.load_lpips(junk, junk)


def test_cli_eval_with_lpips_weights(weight_files, tmp_path):
    import json

    from click.testing import CliRunner

    from zcomp_cli.cli import cli
    from zcomp_cli.conventions import linear_to_srgb
    from zcomp_cli.imageio import read_image, write_png

    backbone, alex = weight_files
    a, b = _images(3, 32, 40)
    write_png(tmp_path / "p" / "x.png", a)
    write_png(tmp_path / "r" / "x.png", b)
    args = ["eval", "--metrics", "lpips,psnr", "--lpips-backbone", str(backbone),
            "--lpips-weights", str(alex), str(tmp_path / "p"), str(tmp_path / "r")]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    data = json.loads((tmp_path / "p" / "eval.json").read_text())
    assert data["unavailable"] == {}
    model = L.load_lpips(backbone, alex)
    # The CLI scores the sRGB encoding of what it read (PNG -> linear -> sRGB).
    pa = linear_to_srgb(read_image(tmp_path / "p" / "x.png"))
    pb = linear_to_srgb(read_image(tmp_path / "r" / "x.png"))
    assert data["images"][0]["lpips"] == pytest.approx(L.lpips_distance(model, pa, pb), abs=1e-6)
    assert data["mean"]["lpips"] > 0
