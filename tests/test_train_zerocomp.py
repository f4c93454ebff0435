import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from zcomp_cli.errors import InputError, UsageError
from zcomp_cli.training.config import load_config, parse_config
from zcomp_cli.training.datasets import open_dataset
from zcomp_cli.training.masks import random_shading_mask

from zerocomp_dummy import random_request as _request, save_dummy


def test_mask_branch_frequencies():
    rng = np.random.default_rng(0)
    n = 4000
    counts = {"shapes": 0, "full": 0, "none": 0}
    for _ in range(n):
        m, b = random_shading_mask(16, 20, rng)
        counts[b] += 1
        assert m.shape == (16, 20) and m.dtype == bool
        if b == "none":
            assert not m.any()
        elif b == "full":
            assert m.all()
        else:
            assert m.any()
    for b, p in (("shapes", 0.6), ("full", 0.3), ("none", 0.1)):
        assert abs(counts[b] / n - p) < 4 * np.sqrt(p * (1 - p) / n)
    with pytest.raises(InputError):
        random_shading_mask(0, 5, rng)


def _make_data(root, n=4, hw=16, material=False):
    rng = np.random.default_rng(1)
    for i in range(n):
        d = root / f"s{i}"
        d.mkdir(parents=True)
        nrm = rng.normal(size=(hw, hw, 3)).astype(np.float32)
        nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
        alb = rng.uniform(0.2, 0.8, (hw, hw, 3)).astype(np.float32)
        np.save(d / "albedo.npy", alb)
        np.save(d / "image.npy", alb * rng.uniform(0.5, 1.0, (hw, hw, 1)).astype(np.float32))
        np.save(d / "depth.npy", rng.uniform(1, 3, (hw, hw)).astype(np.float32))
        np.save(d / "normals.npy", nrm)
        if material:
            np.save(d / "roughness.npy", np.full((hw, hw), 0.5, np.float32))
            np.save(d / "metallic.npy", np.zeros((hw, hw), np.float32))


def test_config_errors_name_key(tmp_path):
    with pytest.raises(UsageError, match="'base'"):
        parse_config({"dataset": {"root": "x"}, "output_dir": "o"})
    with pytest.raises(UsageError, match="channels"):
        parse_config({"base": "b", "dataset": {"root": "x"}, "output_dir": "o", "channels": 12})
    with pytest.raises(UsageError, match="lr"):
        parse_config({"base": "b", "dataset": {"root": "x"}, "output_dir": "o", "lr": "fast"})
    with pytest.raises(UsageError, match="unknown"):
        parse_config({"base": "b", "dataset": {"root": "x"}, "output_dir": "o", "bogus": 1})


def test_dataset_validation(tmp_path):
    _make_data(tmp_path / "d", n=2)
    ds = open_dataset("zcomp", tmp_path / "d")
    assert len(ds) == 2 and ds[0]["image"].shape == (16, 16, 3)
    np.save(tmp_path / "d" / "s1" / "depth.npy", np.full((8, 8), np.nan, np.float32))
    with pytest.raises(InputError, match="s1"):
        ds[1]
    (tmp_path / "d" / "s0" / "albedo.npy").unlink()
    with pytest.raises(InputError, match="albedo"):
        ds[0]
    with pytest.raises(InputError, match="roughness"):
        _make_data(tmp_path / "e", n=1)
        open_dataset("zcomp", tmp_path / "e", channels=13)[0]


@pytest.mark.slow
def test_train_loss_decreases_checkpoint_loads_and_resumes(tmp_path):
    from zcomp_cli.cli.train import train as train_cmd
    from zcomp_cli.renderers.zerocomp import ZeroCompRenderer
    from zcomp_cli.training.trainer import train

    _, base = save_dummy(tmp_path / "w", 11)
    _make_data(tmp_path / "data")
    cfg = {"base": str(base), "dataset": {"layout": "zcomp", "root": str(tmp_path / "data")},
           "output_dir": str(tmp_path / "out"), "resolution": 16, "batch_size": 4, "lr": 2e-3,
           "max_steps": 40, "save_every": 20, "seed": 0, "device": "cpu"}
    steps = []
    res = train(parse_config(cfg), progress=lambda stage, done, total, label: steps.append(done))
    assert res.step == 40 and len(res.losses) == 40 and steps == list(range(1, 41))
    assert np.mean(res.losses[-10:]) < np.mean(res.losses[:10])
    ck = tmp_path / "out" / "checkpoint-40"
    assert (ck / "controlnet" / "config.json").is_file()
    assert (ck / "controlnet" / "diffusion_pytorch_model.safetensors").is_file()
    assert (tmp_path / "out" / "loss_log.tsv").read_text().count("\n") == 40
    # the renderer loads it

    img = ZeroCompRenderer(ck, base, steps=1, device="cpu", resolution=16).render([_request()]).images[0]
    assert np.isfinite(img).all()
    # resume through the CLI
    cfg.update(max_steps=42, resume="latest")
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(train_cmd, [str(p), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "step 42" in r.output and (tmp_path / "out" / "checkpoint-42" / "optimizer.pt").is_file()
    assert load_config(p).resume == "latest"
