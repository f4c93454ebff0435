"""OpenRooms and InteriorVerse training datasets, on tiny fakes written with the real
encodings (Radiance .hdr, OpenRooms .dat depth, 8-bit PNG maps, float EXR)."""

import warnings

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from zcomp_cli.conventions import normalize
from zcomp_cli.errors import InputError
from zcomp_cli.imageio import write_exr, write_png
from zcomp_cli.training.datasets import open_dataset
from zcomp_cli.training.datasets_external import (
    InteriorVerseDataset,
    OpenRoomsDataset,
    decode_official_normals,
    expose_p95,
    read_openrooms_depth,
)

H, W = 24, 32


def _png_normals(n):
    """What an OpenRooms normal PNG holds (DESIGN.md §4), written by hand so the fixture
    does not depend on the code under test: OpenGL camera normals * 0.5 + 0.5, no flip."""
    return np.asarray(n, np.float32) * 0.5 + 0.5


def write_hdr(path, img):
    import OpenImageIO as oiio

    path.parent.mkdir(parents=True, exist_ok=True)
    spec = oiio.ImageSpec(W, H, 3, oiio.FLOAT)
    out = oiio.ImageOutput.create(str(path))
    assert out is not None and out.open(str(path), spec), oiio.geterror()
    out.write_image(np.ascontiguousarray(img, np.float32))
    out.close()


def write_dat(path, depth, header=None):
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = header or depth.shape
    path.write_bytes(np.array([h, w], "<i4").tobytes() + np.asarray(depth, "<f4").tobytes())


def scene_truth(seed):
    """Known camera-frame maps: left half faces the camera, right half is a floor-like
    plane tilted up, a random patch elsewhere; depth 1-5 m; albedo 0.05-0.9."""
    rng = np.random.default_rng(seed)
    n = np.zeros((H, W, 3), np.float32)
    n[:, : W // 2] = (0, 0, 1)
    n[:, W // 2:] = normalize(np.array([0.6, 0.8, 0.3]))
    n[:4, :4] = normalize(rng.normal(size=(4, 4, 3)) + (0, 0, 2))
    depth = rng.uniform(1, 5, (H, W)).astype(np.float32)
    albedo = rng.uniform(0.05, 0.9, (H, W, 3)).astype(np.float32)
    shading = rng.uniform(0.2, 3.0, (H, W, 1)).astype(np.float32)
    return n, depth, albedo, albedo * shading


def make_openrooms(root, split="main_xml1", scene="scene0001_00", views=(1, 2), material=False):
    truth = {}
    for v in views:
        n, depth, albedo, img = scene_truth(v)
        rel = f"{split}/{scene}"
        write_hdr(root / "Image" / rel / f"im_{v}.hdr", img * 37.0)  # arbitrary absolute scale
        write_dat(root / "Geometry" / rel / f"imdepth_{v}.dat", depth)
        write_png(root / "Geometry" / rel / f"imnormal_{v}.png", _png_normals(n),
                  srgb_encode=False)
        write_png(root / "Material" / rel / f"imbaseColor_{v}.png", albedo ** (1 / 2.2),
                  srgb_encode=False)
        write_png(root / "Material" / rel / f"imroughness_{v}.png", np.full((H, W), 0.25),
                  srgb_encode=False)
        if material:
            write_png(root / "Material" / rel / f"immetallic_{v}.png", np.full((H, W), 0.75),
                      srgb_encode=False)
        mask = np.ones((H, W))
        mask[:, :3] = 0.0  # a window column: excluded from the exposure percentile
        write_png(root / "Mask" / rel / f"immask_{v}.png", mask, srgb_encode=False)
        truth[f"{rel}/{v}"] = (n, depth, albedo, img * 37.0, mask >= 0.9)
    return truth


def make_interiorverse(root, scenes=("L3D124S8ENDIDQ5QIAUI5NYALUF3P3XE888",), ids=("000", "001")):
    truth = {}
    for si, sc in enumerate(scenes):
        for k, i in enumerate(ids):
            n, depth, albedo, img = scene_truth(10 * si + k)
            d = root / sc
            mm = depth * 1000.0
            mm[0, -1] = np.inf  # no surface: a window
            nrm = _png_normals(n) * 2 - 1  # the official vector
            nrm[0, -1] = np.nan  # undefined where there is no surface: allowed
            write_exr(d / f"{i}_im.exr", img)
            write_exr(d / f"{i}_depth.exr", np.repeat(mm[..., None], 3, -1))
            write_exr(d / f"{i}_normal.exr", nrm)
            write_exr(d / f"{i}_albedo.exr", albedo)
            mat = np.stack([np.full((H, W), 0.3), np.full((H, W), 0.6), np.zeros((H, W))], -1)
            write_exr(d / f"{i}_material.exr", mat)
            truth[f"{sc}/{i}"] = (n, depth, albedo, img)
    return truth


# ----------------------------------------------------------------------------- unit


def test_openrooms_depth_reader_roundtrip_and_errors(tmp_path):
    d = np.arange(H * W, dtype=np.float32).reshape(H, W) / 100 + 1
    write_dat(tmp_path / "a.dat", d)
    out = read_openrooms_depth(tmp_path / "a.dat")
    assert out.dtype == np.float32 and out.shape == (H, W) and np.array_equal(out, d)
    write_dat(tmp_path / "b.dat", d[:-1], header=(H, W))  # body shorter than the header says
    with pytest.raises(InputError, match="needs"):
        read_openrooms_depth(tmp_path / "b.dat")
    write_dat(tmp_path / "c.dat", d, header=(-3, W))
    with pytest.raises(InputError, match="implausible"):
        read_openrooms_depth(tmp_path / "c.dat")
    (tmp_path / "e.dat").write_bytes(b"\x01\x00")
    with pytest.raises(InputError, match="too short"):
        read_openrooms_depth(tmp_path / "e.dat")
    with pytest.raises(InputError, match="not found"):
        read_openrooms_depth(tmp_path / "missing.dat")


def test_decode_normals_inverts_the_conditioning_encoding():
    rng = np.random.default_rng(0)
    n = normalize(rng.normal(size=(5, 7, 3)))
    n[0, 0] = 0.0  # unknown normal stays 0
    enc = _png_normals(n) * 2 - 1
    back = decode_official_normals(enc)
    assert back.dtype == np.float32 and np.allclose(back, n, atol=1e-6)
    # a camera-facing surface (zcomp +z) round-trips through the official encoding
    face = np.array([[[0, 0, 1]]], np.float32)
    assert np.allclose(decode_official_normals(_png_normals(face) * 2 - 1), face)
    with pytest.raises(InputError):
        decode_official_normals(np.zeros((4, 4)))


def test_expose_p95_removes_absolute_scale_and_floors_dark_images():
    rng = np.random.default_rng(1)
    img = rng.uniform(0, 2, (H, W, 3)).astype(np.float32)
    a, sa = expose_p95(img)
    b, sb = expose_p95(img * 1e4)  # HDR extreme: same exposed image
    assert np.allclose(a, b, atol=1e-5) and np.isclose(sa, sb * 1e4)
    assert abs(np.percentile(a, 95) - 0.9) < 1e-3 and a.min() >= 0 and a.max() <= 1
    dark, s = expose_p95(np.full((4, 4, 3), 1e-6, np.float32))  # floor: at most x9
    assert np.isclose(s, 9.0) and np.all(dark < 1e-4)
    zero, _ = expose_p95(np.zeros((4, 4, 3), np.float32))
    assert np.all(zero == 0)


# ----------------------------------------------------------------------------- OpenRooms


def test_openrooms_values_and_conventions(tmp_path):
    truth = make_openrooms(tmp_path / "or", material=True)
    ds = open_dataset("openrooms", tmp_path / "or", channels=13)
    assert isinstance(ds, OpenRoomsDataset) and len(ds) == 2
    for i in range(len(ds)):
        name = ds.sample_name(i)
        n, depth, albedo, hdr, valid = truth[name]
        s = ds[i]
        assert set(s) == {"image", "depth", "normals", "albedo", "roughness", "metallic"}
        assert all(v.dtype == np.float32 for v in s.values())
        assert s["image"].shape == s["normals"].shape == s["albedo"].shape == (H, W, 3)
        assert s["depth"].shape == s["roughness"].shape == (H, W)
        assert np.array_equal(s["depth"], depth)  # metres, bit exact
        assert np.allclose(s["normals"], n, atol=0.02)  # 8-bit quantisation
        assert np.allclose(s["normals"][5, 2], (0, 0, 1), atol=0.01)  # faces the camera
        # the conditioning the trainer builds equals the file's encoding
        png = _png_normals(n)
        assert np.allclose(_png_normals(s["normals"]), png, atol=0.01)
        assert np.allclose(s["albedo"], albedo, atol=0.006)  # gamma-2.2 PNG -> linear
        assert np.allclose(s["roughness"], 0.25, atol=0.003)
        assert np.allclose(s["metallic"], 0.75, atol=0.003)
        # exposure: p95 of the valid pixels -> 0.9, proportional to the radiance
        assert abs(np.percentile(s["image"][valid], 95) - 0.9) < 0.02
        ok = s["image"] < 0.99
        ratio = s["image"][ok] / hdr[ok]
        assert np.std(ratio) / np.mean(ratio) < 0.01  # RGBE precision


def test_openrooms_difflight_falls_back_to_main_and_flat_layout(tmp_path):
    make_openrooms(tmp_path / "or", split="main_xml")
    _, _, _, img = scene_truth(3)
    write_hdr(tmp_path / "or" / "Image" / "mainDiffLight_xml" / "scene0001_00" / "im_1.hdr", img)
    ds = OpenRoomsDataset(tmp_path / "or")
    names = [ds.sample_name(i) for i in range(len(ds))]
    assert "mainDiffLight_xml/scene0001_00/1" in names and len(ds) == 3
    j = names.index("mainDiffLight_xml/scene0001_00/1")
    assert np.array_equal(ds[j]["depth"], ds[names.index("main_xml/scene0001_00/1")]["depth"])
    # flat: all files of a view in one folder
    flat = tmp_path / "flat" / "scene0002_00"
    n, depth, albedo, img = scene_truth(4)
    write_hdr(flat / "im_7.hdr", img)
    write_dat(flat / "imdepth_7.dat", depth)
    write_png(flat / "imnormal_7.png", _png_normals(n), srgb_encode=False)
    write_png(flat / "imbaseColor_7.png", albedo ** (1 / 2.2), srgb_encode=False)
    s = OpenRoomsDataset(tmp_path / "flat")[0]
    assert np.array_equal(s["depth"], depth) and "roughness" not in s


def test_openrooms_errors_name_sample_and_file(tmp_path):
    root = tmp_path / "or"
    make_openrooms(root)
    rel = root / "Geometry" / "main_xml1" / "scene0001_00"
    (rel / "imnormal_2.png").unlink()
    with pytest.raises(InputError, match=r"main_xml1/scene0001_00/2.*imnormal_2\.png"):
        OpenRoomsDataset(root)
    with pytest.raises(InputError, match="immetallic_1.png"):  # 13 channels need metallic
        make_openrooms(tmp_path / "b")
        open_dataset("openrooms", tmp_path / "b", channels=13)
    make_openrooms(root, views=(2,))
    ds = OpenRoomsDataset(root)
    write_dat(rel / "imdepth_1.dat", np.ones((H // 2, W // 2), np.float32))
    with pytest.raises(InputError, match=r"scene0001_00/1.*imdepth_1\.dat.*shape"):
        ds[0]
    bad = np.ones((H, W), np.float32)
    bad[3, 3] = np.nan
    write_dat(rel / "imdepth_1.dat", bad)
    with pytest.raises(InputError, match=r"scene0001_00/1.*imdepth_1\.dat.*NaN"):
        ds[0]
    write_dat(rel / "imdepth_1.dat", bad[:-1], header=(H, W))
    with pytest.raises(InputError, match=r"scene0001_00/1.*imdepth_1\.dat"):
        ds[0]
    (rel / "imdepth_1.dat").write_bytes(b"")
    (root / "Material" / "main_xml1" / "scene0001_00" / "imbaseColor_2.png").write_bytes(b"junk")
    with pytest.raises(InputError, match=r"scene0001_00/2.*imbaseColor_2\.png"):
        ds[1]
    (tmp_path / "empty" / "Image").mkdir(parents=True)
    with pytest.raises(InputError, match="no im_"):
        OpenRoomsDataset(tmp_path / "empty")
    with pytest.raises(InputError, match="not found"):
        OpenRoomsDataset(tmp_path / "nope")


def test_backfacing_normals_warn_once(tmp_path):
    root = tmp_path / "or"
    make_openrooms(root)
    ds = OpenRoomsDataset(root)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds[0]
        ds[1]
    rel = root / "Geometry" / "main_xml1" / "scene0001_00"
    flipped = -scene_truth(1)[0]
    write_png(rel / "imnormal_1.png", _png_normals(flipped), srgb_encode=False)
    ds = OpenRoomsDataset(root)
    with pytest.warns(UserWarning, match="face away"):
        ds[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds[0]  # once per dataset


# ----------------------------------------------------------------------------- InteriorVerse


def test_interiorverse_values_and_conventions(tmp_path):
    truth = make_interiorverse(tmp_path / "iv")
    ds = open_dataset("interiorverse", tmp_path / "iv", channels=13)
    assert isinstance(ds, InteriorVerseDataset) and len(ds) == 2
    for i in range(len(ds)):
        n, depth, albedo, img = truth[ds.sample_name(i)]
        s = ds[i]
        assert set(s) == {"image", "depth", "normals", "albedo", "roughness", "metallic"}
        assert all(v.dtype == np.float32 and np.isfinite(v).all() for v in s.values())
        expect = depth.copy()
        expect[0, -1] = 0.0  # +inf mm = no surface -> 0
        assert np.allclose(s["depth"], expect, rtol=1e-6)  # mm -> m
        m = np.ones((H, W), bool)
        m[0, -1] = False
        assert np.allclose(s["normals"][m], n[m], atol=1e-5)
        assert np.array_equal(s["normals"][0, -1], (0, 0, 0))
        assert np.allclose(s["albedo"][m], albedo[m], atol=1e-6)  # linear as stored
        assert np.allclose(s["image"], np.clip(img, 0, 1), atol=1e-6)  # radiance kept, no rescale
        assert np.allclose(s["roughness"], 0.3) and np.allclose(s["metallic"], 0.6)
    # 11 channels: no material returned, material file not required
    for p in (tmp_path / "iv").glob("*/*_material.exr"):
        p.unlink()
    s = open_dataset("interiorverse", tmp_path / "iv", channels=11)[0]
    assert set(s) == {"image", "depth", "normals", "albedo"}


def test_interiorverse_errors_name_sample_and_file(tmp_path):
    root = tmp_path / "iv"
    make_interiorverse(root)
    sc = next(root.iterdir())
    ds = InteriorVerseDataset(root, need_material=True)
    bad = np.zeros((H, W, 3), np.float32)
    bad[5, 5] = np.nan  # NaN on a surface pixel: an error
    write_exr(sc / "001_normal.exr", bad)
    with pytest.raises(InputError, match=rf"{sc.name}/001.*001_normal\.exr.*NaN"):
        ds[1]
    write_exr(sc / "000_albedo.exr", np.zeros((H, W // 2, 3), np.float32))
    with pytest.raises(InputError, match=r"/000.*000_albedo\.exr.*shape"):
        ds[0]
    d = np.full((H, W), 1000.0, np.float32)
    d[2, 2] = np.nan
    write_exr(sc / "000_depth.exr", d)
    with pytest.raises(InputError, match=r"/000.*000_depth\.exr.*NaN"):
        ds[0]
    write_exr(sc / "000_material.exr", np.zeros((H, W), np.float32))  # one channel
    (sc / "000_depth.exr").unlink()
    with pytest.raises(InputError, match=r"/000.*000_depth\.exr"):
        InteriorVerseDataset(root)
    make_interiorverse(tmp_path / "m")
    for p in (tmp_path / "m").glob("*/001_material.exr"):
        p.unlink()
    with pytest.raises(InputError, match=r"/001.*001_material\.exr"):
        InteriorVerseDataset(tmp_path / "m", need_material=True)
    with pytest.raises(InputError, match="exposure"):
        InteriorVerseDataset(tmp_path / "m", exposure="auto")


# ----------------------------------------------------------------------------- training


@pytest.mark.slow
@pytest.mark.parametrize("layout,channels", [("openrooms", 11), ("interiorverse", 13)])
def test_zcomp_train_three_steps(tmp_path, layout, channels):
    from zcomp_cli.cli.train import train as train_cmd
    from zerocomp_dummy import save_dummy

    _, base = save_dummy(tmp_path / "w", channels)
    data = tmp_path / "data"
    (make_openrooms if layout == "openrooms" else make_interiorverse)(data)
    cfg = {"base": str(base), "dataset": {"layout": layout, "root": str(data)},
           "output_dir": str(tmp_path / "out"), "channels": channels, "resolution": 16,
           "batch_size": 2, "max_steps": 3, "save_every": 3, "seed": 0, "device": "cpu"}
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(train_cmd, [str(p), "--no-progress"])
    assert r.exit_code == 0, r.output + repr(r.exception)
    assert "step 3" in r.output
    ck = tmp_path / "out" / "checkpoint-3" / "controlnet" / "config.json"
    assert ck.is_file() and f'"conditioning_channels": {channels}' in ck.read_text()
    log = (tmp_path / "out" / "loss_log.tsv").read_text().splitlines()
    losses = [float(x.split()[1]) for x in log]
    assert len(losses) == 3 and np.all(np.isfinite(losses))
