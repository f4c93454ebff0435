"""Fuzzing the surfaces added after issue 12's fuzzer (issue 39): ``zcomp import``
archives, estimator model folders, given lights and renderer plugins.

Each test draws hostile variations of a valid input with Hypothesis and runs them
through the real CLI in process, keeping the invariants of ``tests/test_fuzz.py``:

* the exit code is 0, 1 or 2 and no Python exception escapes, no traceback is printed;
* nothing is written outside the output (``--out``, or for ``import`` the manifest and
  its data folder), no litter is left there nor in ``/tmp``;
* every JSON written parses strictly; every finished composite is finite.

And per surface:

* **import**: one damaged case never sinks the others: the imported and failed cases
  are exactly those selected, exit 1 iff one failed, and the manifest written loads;
* **model folders**: stdin is never read, no code from the folder runs, nothing is
  copied into the Hugging Face modules cache, and the other scene's job is done
  whenever the manifest was accepted;
* **lights**: a light is refused (exit 2), fails its job (exit 1) or gives finite
  composites;
* **plugins**: whatever a plugin's import or its renderer does (raise, exit, return
  NaN, 3e38, the wrong shape or type), the registry lists it as a problem or the job
  fails with a reason; a finished job is finite and in radiance bounds.

Issue 50's surfaces:

* **cycles**: the cycles renderer's settings (manifest and ``--samples``), hostile or
  plausible, with given lights: refused with the field (exit 2), or its jobs run in
  Blender (done, or failed with a reason that names Blender's log when it keeps one);
* **preview**: preview-light's options (scenes, pixel, diameter, samples), the state of
  ``OUT/preview`` (sheets there, a link out, a FIFO for a sheet) and a damaged depth:
  every sheet written has its numbers (PNG and JSON together), nothing outside --out;
* **balls**: chrome-ball photographs (float TIFF, 16-bit, NaN, tiny, a ball off the
  frame) with hostile centres, radii and reflectances;
* **report**: an output folder of hostile content (names and reasons aimed at the page:
  its template's slots, quotes, handlers, undecodable bytes, 100 kB texts; damaged or
  deep reports, summaries, eval files; FIFOs; linked job folders): the page is written
  or refused (exit 2), is valid UTF-8, carries no event handler and one nonce'd script,
  and nothing but the page and its thumbnails is written.

Profiles (``ZCOMP_FUZZ_PROFILE``): ``ci`` (default, a slice of each: see ``EXAMPLES``),
``full`` (10x):

    ZCOMP_FUZZ_PROFILE=full pytest -m fuzz tests/test_fuzz_surfaces.py -q -s
"""

from __future__ import annotations

import io
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lvsn_replica as replica
from hostile_project import base_manifest, make_project
from test_fuzz import _numbers, _snapshot, _strict_json, _tmp_zcomp_entries, _values, _vec, _weird_text
from zcomp_cli.cli import cli
from zcomp_cli.errors import NumericalError
from zcomp_cli.renderers.base import Renderer, RenderOutput

PROFILE = os.environ.get("ZCOMP_FUZZ_PROFILE", "ci")
# examples per surface in the ci profile (the full profile runs ten times as many)
EXAMPLES = {"import": 60, "models": 30, "lights": 100, "plugins": 30,
            # issue 50's surfaces: the cycles renderer's inputs and preview-light run Blender
            # when a case gets past validation (seconds each), the others do not
            "cycles": 12, "preview": 10, "balls": 40, "report": 60}
STATS: dict[str, dict] = {k: {"cases": 0, "exit": {0: 0, 1: 0, 2: 0}} for k in EXAMPLES}


def _settings(surface: str):
    n = EXAMPLES[surface] * (10 if PROFILE == "full" else 1)
    return settings(max_examples=n, deadline=None, derandomize=PROFILE == "ci", print_blob=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])


class _NoStdin(io.RawIOBase):
    """stdin for the CLI: reading it fails the test (a model folder must never make
    zcomp ask a question)."""

    def readable(self):
        return True

    def readinto(self, b):
        if len(b) == 0:
            return 0
        raise AssertionError("zcomp read stdin")


def _invoke(args, surface: str):
    r = CliRunner().invoke(cli, ["-q", *map(str, args)], input=io.BufferedReader(_NoStdin()))
    assert r.exception is None or isinstance(r.exception, SystemExit), (
        f"uncaught {type(r.exception).__name__}: {r.exception}", r.exc_info)
    assert r.exit_code in (0, 1, 2), (r.exit_code, r.output)
    assert "Traceback" not in r.output, r.output
    STATS[surface]["cases"] += 1
    STATS[surface]["exit"][r.exit_code] += 1
    return r


def _check_out(out: Path) -> None:
    """Strict JSON everywhere, finite composites, no litter."""
    if not out.exists():
        return
    for p in out.rglob("*"):
        assert not p.is_symlink(), p
        if p.suffix == ".json":
            _strict_json(p)
        assert not (p.name.startswith(".zcomp-") or ".tmp" in p.name or ".partial" in p.name
                    or ".old-" in p.name or p.name.endswith(".lock")), f"litter left: {p}"
    from zcomp_cli.imageio import read_image

    for rep in out.glob("*/report.json"):
        if _strict_json(rep).get("status") == "done":
            img = read_image(rep.parent / "composite.exr")
            assert np.isfinite(img).all() and img.min() >= -1e-3 and img.max() <= 1e6, rep


def _unchanged_outside(root: Path, out: Path, before: dict, tmp_before: set) -> None:
    after = _snapshot(root, out)
    changed = {p for p in set(before) | set(after) if before.get(p) != after.get(p)}
    assert not changed, f"written outside the output: {sorted(changed)[:5]}"
    assert _tmp_zcomp_entries() <= tmp_before, "temporary files left in /tmp"


# ============================================================================ import
_case_names = st.sampled_from(["7", "summary.json", "report.html", "0-3", "a b", "x" * 150, "é", "caf\udce9",
                               "new\nline", "-dash", "CON", "preview"])
_light_docs = st.one_of(
    _values,
    st.builds(lambda v: {"light_frames": [{"name": "gt_dir", "blender_light_xyz_position_object_space": v}]},
              st.one_of(_vec(3), _values, st.just([10 ** 400, 0, 1]))),
    st.builds(lambda names: {"light_frames": [{"name": n, "blender_light_xyz_position_object_space": [0, 0, 1]}
                                              for n in names]},
              st.lists(st.one_of(_weird_text, st.integers(), st.none(), st.just("gt_dir")), max_size=5)),
)
_damages = st.sampled_from(["light_doc", "light_deep", "light_bytes", "light_fifo", "light_missing",
                            "bundle_empty", "bundle_cut", "bundle_noise", "map_missing", "map_fifo", "map_cut",
                            "map_small", "rename"])


@st.composite
def import_cases(draw):
    damage = draw(st.dictionaries(st.integers(0, 2), st.tuples(_damages, _light_docs, _case_names,
                                                                st.integers(0, 4000)), max_size=3))
    opts = draw(st.fixed_dictionaries({}, optional={"--lights": st.sampled_from(["gt", "all", "none"]),
                                                    "--limit": st.integers(1, 3)}))
    return damage, opts


def _damage_case(root: Path, name: str, kind: str, doc, new_name: str, k: int) -> None:
    from zcomp_cli.imageio import write_exr

    folder = root / name
    est = root.parent / "WACV_bg_estimates" / name
    light = folder / f"{name}_light_path_dto.json"
    bundle = folder / f"{name}_bundle0001.exr"
    normal = est / f"{name}_bg_normal.png"
    if kind == "light_doc":
        light.write_text(json.dumps(doc, allow_nan=True))
    elif kind == "light_deep":
        light.write_text("[" * (k * 30) + "]" * (k * 30))
    elif kind == "light_bytes":
        light.write_bytes(os.urandom(k % 64) + b"\xff\xfe")
    elif kind == "light_fifo":
        light.unlink()
        os.mkfifo(light)
    elif kind == "light_missing":
        light.unlink()
    elif kind == "bundle_empty":
        bundle.write_bytes(b"")
    elif kind == "bundle_cut":
        bundle.write_bytes(bundle.read_bytes()[:k])
    elif kind == "bundle_noise":
        data = bytearray(bundle.read_bytes())
        for i in range(0, len(data), max(1, len(data) // (k % 50 + 1))):
            data[i] ^= 0x5A
        bundle.write_bytes(bytes(data))
    elif kind == "map_missing":
        normal.unlink()
    elif kind == "map_fifo":
        normal.unlink()
        os.mkfifo(normal)
    elif kind == "map_cut":
        normal.write_bytes(normal.read_bytes()[:k % 200])
    elif kind == "map_small":
        write_exr(est / f"{name}_bg_depth.exr", np.full((2, 3, 3), 2.0, np.float32))
    elif kind == "rename":
        for d in (folder, est):
            moved = d.parent / new_name.replace("/", "_")
            d.rename(moved)
            for f in moved.iterdir():
                f.rename(moved / f.name.replace(name, new_name))


@pytest.fixture(scope="module")
def spot_archive(tmp_path_factory):
    data = tmp_path_factory.mktemp("fuzz_spot") / "data"
    cases = replica.make_spotlight_archive(data, 3)
    return data, [c.name for c in cases]


@pytest.mark.fuzz
@pytest.mark.slow
@_settings("import")
@given(case=import_cases())
def test_fuzz_import(spot_archive, case, tmp_path_factory):
    from zcomp_cli.pipeline.manifest import load_manifest

    src, names = spot_archive
    damage, opts = case
    work = tmp_path_factory.mktemp("imp")
    data = work / "data"
    shutil.copytree(src, data)
    root = data / "rendered_2024-10-20_19-07-58_control"
    for i, (kind, doc, new_name, k) in damage.items():
        try:
            _damage_case(root, names[i], kind, doc, new_name, k)
        except OSError:  # two cases renamed alike, a name the file system refuses: that damage is not made
            pass
    out = work / "o" / "jobs.yaml"
    before, tmp_before = _snapshot(work, out.parent), _tmp_zcomp_entries()
    args = ["import", "spotlight", root, "--out", out, "--maps", "provided"]
    for k, v in opts.items():
        args += [k, v]
    r = _invoke(args, "import")
    _unchanged_outside(work, out.parent, before, tmp_before)
    if r.exit_code == 2:
        assert not out.exists()
    elif out.exists():
        rep = _strict_json(out.parent / "jobs_data" / "import.json")
        assert bool(rep["failed"]) == (r.exit_code == 1), r.output
        selected = len([d for d in root.iterdir() if d.is_dir() and not d.name.startswith(".")])
        assert len(rep["imported"]) + len(rep["failed"]) == min(selected, opts.get("--limit", selected))
        load_manifest(out)
        assert sorted(p.name for p in out.parent.iterdir()) == ["jobs.yaml", "jobs_data"]
    else:
        assert r.exit_code == 1 and not out.parent.exists(), r.output  # no case imported: nothing kept
    shutil.rmtree(work, ignore_errors=True)


# ============================================================================ model folders
MODELS_MANIFEST = """version: 1
defaults: {renderer: physical}
scenes:
  learned: {image: photo.png, fov_deg: 50, depth: {model: MODEL}}
  plain: {image: photo.png, fov_deg: 50, depth: {proxy: ground_plane, camera_height: 0.6, pitch_deg: -30}}
objects:
  card: {image: obj.png, mask: mask.png}
jobs:
  - {scene: learned, object: card, placement: {pixel: [70, 100], height: 0.12}}
  - {scene: plain, object: card, placement: {pixel: [70, 100], height: 0.12}}
"""
EVIL = 'import pathlib\npathlib.Path(r"MARKER").write_text("ran")\n'

_config_keys = st.sampled_from(["model_type", "auto_map", "architectures", "hidden_size", "num_hidden_layers",
                                "image_size", "patch_size", "torch_dtype", "_name_or_path", "custom_pipeline"])
_model_damage = st.one_of(
    st.tuples(st.just("config_key"), _config_keys, st.one_of(_values, st.just({"AutoModel": "evil.Evil"}),
                                                              st.sampled_from(["nope", "dpt", 10 ** 30]))),
    st.tuples(st.just("config_text"), st.sampled_from(["", "{", "[" * 50_000, "null", "1e999", '"x"']), st.none()),
    st.tuples(st.just("weights_cut"), st.integers(0, 3000), st.none()),
    st.tuples(st.just("weights_header"), st.integers(0, 2 ** 64 - 1), st.none()),
    st.tuples(st.just("weights_bytes"), st.binary(max_size=64), st.none()),
    st.tuples(st.just("weights_sparse"), st.integers(1, 40), st.none()),
    st.tuples(st.just("bin_pickle"), st.binary(max_size=64), st.none()),
    st.tuples(st.just("py_beside"), st.sampled_from(["evil.py", "modeling_dpt.py", "__init__.py"]), st.none()),
    st.tuples(st.just("model_index"), st.one_of(_values, st.just("[" * 50_000)), st.none()),
    st.tuples(st.just("drop"), st.sampled_from(["config.json", "preprocessor_config.json", "model.safetensors"]),
              st.none()),
    st.tuples(st.just("preprocessor_key"), st.sampled_from(["size", "image_processor_type", "auto_map"]), _values),
)


def _damage_model(d: Path, damage, marker: Path) -> None:
    kind, a, b = damage
    w = d / "model.safetensors"
    if kind == "config_key":
        cfg = json.loads((d / "config.json").read_text())
        cfg[a] = b
        (d / "config.json").write_text(json.dumps(cfg, allow_nan=True))
    elif kind == "config_text":
        (d / "config.json").write_text(a)
    elif kind == "weights_cut":
        with open(w, "r+b") as f:  # (after weights_sparse the file is 10 GB of holes: not read whole)
            f.truncate(min(a, os.fstat(f.fileno()).st_size))
    elif kind == "weights_header":
        with open(w, "r+b") as f:
            f.write(a.to_bytes(8, "little"))
    elif kind == "weights_bytes":
        w.write_bytes(a)
    elif kind == "weights_sparse":
        with open(w, "r+b") as f:
            f.truncate(a << 28)
    elif kind == "bin_pickle":
        w.unlink()
        (d / "pytorch_model.bin").write_bytes(a)
    elif kind == "py_beside":
        (d / a).write_text(EVIL.replace("MARKER", str(marker)))
    elif kind == "model_index":
        (d / "model_index.json").write_text(b if isinstance(b, str) and b.startswith("[") else json.dumps(a, allow_nan=True))
    elif kind == "drop":
        (d / a).unlink()
    elif kind == "preprocessor_key":
        p = d / "preprocessor_config.json"
        cfg = json.loads(p.read_text())
        cfg[a] = b
        p.write_text(json.dumps(cfg, allow_nan=True))


@pytest.mark.fuzz
@pytest.mark.slow
@_settings("models")
@given(damages=st.lists(_model_damage, min_size=1, max_size=3))
def test_fuzz_model_folders(tiny_dpt, photo_manifest, damages, tmp_path_factory):
    from transformers.dynamic_module_utils import HF_MODULES_CACHE

    work = tmp_path_factory.mktemp("mod")
    d = work / "model"
    shutil.copytree(tiny_dpt, d)
    marker = work / "MARKER"
    for dmg in damages:
        try:
            _damage_model(d, dmg, marker)
        except (OSError, ValueError, TypeError, RecursionError):  # an earlier damage took what this one edits (a dropped or unparsable file)
            pass
    photo_manifest(work)
    manifest = work / "jobs.yaml"
    manifest.write_text(MODELS_MANIFEST.replace("MODEL", str(d)))
    modules = set(Path(HF_MODULES_CACHE).rglob("*.py")) if Path(HF_MODULES_CACHE).exists() else set()
    out = work / "out"
    before, tmp_before = _snapshot(work, out), _tmp_zcomp_entries()
    r = _invoke(["composite", manifest, "--out", out], "models")
    assert not marker.exists(), "the model folder's code ran"
    assert (set(Path(HF_MODULES_CACHE).rglob("*.py")) if Path(HF_MODULES_CACHE).exists() else set()) == modules
    _unchanged_outside(work, out, before, tmp_before)
    _check_out(out)
    if r.exit_code == 2:
        assert not out.exists()
    else:  # one bad model never sinks the other scene
        jobs = {j["name"]: j for j in _strict_json(out / "summary.json")["jobs"]}
        assert next(j for n, j in jobs.items() if "plain" in n)["status"] == "done", jobs
    shutil.rmtree(work, ignore_errors=True)


# ============================================================================ lights
def _mostly(plausible, hostile):
    """Mostly values a user would write (so the fuzz reaches the renderer), sometimes
    hostile ones."""
    # (seven distinct strategies: one_of drops repeats of the same one, which made it 1:1)
    return st.one_of(*[plausible.map(lambda v: v) for _ in range(7)], hostile)


def _f(lo, hi):
    return st.floats(lo, hi, allow_nan=False)


_dir3 = _mostly(st.lists(_f(-1, 1), min_size=3, max_size=3),
                st.one_of(_vec(3), st.sampled_from([[0, 1, 0], [0, -1, 0], [0, 0, 0], [1e308, 0, 0]])))
_position = _mostly(st.tuples(_f(-2, 2), _f(-1.5, 2.5), _f(-6, -0.5)).map(list),
                    st.one_of(_vec(3), st.sampled_from([[0.0, -1.2, -3.0], [0.0, 0.5, -2.5], [0, -6, -3]])))
_colour = _mostly(st.lists(_f(0, 2), min_size=3, max_size=3),
                  st.one_of(_vec(3), _values, st.sampled_from([[1e30, 1, 1], [0, 0, 0]])))
_sun_where = st.one_of(st.fixed_dictionaries({"direction": _dir3}),
                       st.fixed_dictionaries({"azimuth_deg": _mostly(_f(0, 360), _numbers),
                                              "elevation_deg": _mostly(_f(-10, 90), _numbers)}),
                       st.fixed_dictionaries({}, optional={"direction": _dir3, "azimuth_deg": _numbers}))
_sun = st.builds(lambda where, rest: {"type": "sun", **where, **rest}, _sun_where, st.fixed_dictionaries({}, optional={
    "irradiance": _mostly(st.one_of(_f(0, 10), st.just("auto")), _numbers),
    "angular_radius_deg": _mostly(_f(0, 10), _numbers), "color": _colour}))
_lamp = st.fixed_dictionaries({"type": st.just("lamp"), "position": _position}, optional={
    "power": _mostly(st.one_of(_f(0, 300), st.just("auto")), _numbers), "radius_m": _mostly(_f(0, 0.5), _numbers),
    "facing": _dir3, "color": _colour})
PROBES = ["ok.exr", "narrow.exr", "tall.exr", "tiny.exr", "nan.exr", "hot.exr", "black.exr", "room.png"]
_probe = st.fixed_dictionaries({"type": st.just("probe"), "hdr": st.sampled_from(PROBES)}, optional={
    "rotation_deg": _mostly(_f(-360, 360), _numbers), "strength": _mostly(_f(0, 10), _numbers),
    "convention": st.sampled_from(["zcomp", "skylibs", "blender", "mirrored", "nope"])})
_ball = st.fixed_dictionaries({"type": st.just("chrome_ball"), "image": st.sampled_from(PROBES),
                               "center": _mostly(st.tuples(_f(0, 64), _f(0, 32)).map(list), _vec(2)),
                               "radius": _mostly(_f(1, 20), st.one_of(_numbers, _vec(2)))}, optional={
    "reflectance": _mostly(_f(0, 1), _numbers), "strength": _mostly(_f(0, 10), _numbers)})
# lights a user would write (every field plausible: they reach the renderer), beside
# the hostile mixes above
_unit = st.lists(_f(-1, 1), min_size=3, max_size=3)
_user_light = st.one_of(
    st.fixed_dictionaries({"type": st.just("sun"), "azimuth_deg": _f(0, 360), "elevation_deg": _f(-5, 90)},
                          optional={"irradiance": _f(0, 10), "angular_radius_deg": _f(0, 10),
                                    "color": st.lists(_f(0.01, 2), min_size=3, max_size=3)}),
    st.fixed_dictionaries({"type": st.just("sun"), "direction": _unit}),
    st.fixed_dictionaries({"type": st.just("lamp"), "position": st.tuples(_f(-2, 2), _f(-1.5, 2.5),
                                                                          _f(-6, -0.5)).map(list)},
                          optional={"power": st.one_of(_f(0, 300), st.just("auto")), "radius_m": _f(0.001, 0.5),
                                    "facing": _unit}),
    st.fixed_dictionaries({"type": st.just("probe"), "hdr": st.sampled_from(PROBES)},
                          optional={"rotation_deg": _f(-360, 360), "strength": _f(0, 10)}),
    st.fixed_dictionaries({"type": st.just("chrome_ball"), "image": st.sampled_from(PROBES),
                           "center": st.tuples(_f(0, 64), _f(0, 32)).map(list), "radius": _f(1, 20)}),
)
_light = st.one_of(_sun, _lamp, _probe, _ball, st.lists(st.one_of(_sun, _lamp, _probe), min_size=1, max_size=4),
                   _values, st.just("estimate"), _user_light, _user_light, _user_light,
                   st.lists(_user_light, min_size=1, max_size=3))


@pytest.fixture(scope="module")
def light_project(tmp_path_factory):
    from zcomp_cli.imageio import write_exr

    shared = tmp_path_factory.mktemp("fuzz_lights")
    make_project(shared)
    p = shared / "probes"
    p.mkdir()
    sky = np.full((32, 64, 3), 0.5, np.float32)
    sky[4:8, 40:44] = 500.0
    write_exr(p / "ok.exr", sky)
    write_exr(p / "narrow.exr", np.ones((2000, 10, 3), np.float32))
    write_exr(p / "tall.exr", np.ones((64, 32, 3), np.float32))
    write_exr(p / "tiny.exr", np.ones((1, 2, 3), np.float32))
    write_exr(p / "nan.exr", np.full((16, 32, 3), np.nan, np.float32))
    write_exr(p / "hot.exr", np.full((16, 32, 3), 6e4, np.float32))
    write_exr(p / "black.exr", np.zeros((16, 32, 3), np.float32))
    shutil.copy(shared / "scenes/room.png", p / "room.png")
    return shared


def _with_probe_paths(light):
    if isinstance(light, dict):
        return {k: (f"probes/{v}" if k in ("hdr", "image") and isinstance(v, str) and v in PROBES else
                    _with_probe_paths(v)) for k, v in light.items()}
    if isinstance(light, list):
        return [_with_probe_paths(v) for v in light]
    return light


@pytest.mark.fuzz
@pytest.mark.slow
@_settings("lights")
@given(light=_light, pitch=st.one_of(st.none(), _mostly(_f(-60, 10), _numbers)), renderer=st.sampled_from(["physical",
                                                                                                  "naive"]))
def test_fuzz_lights(light_project, light, pitch, renderer, tmp_path_factory):
    _light_case(light_project, _with_probe_paths(light), renderer, "lights", tmp_path_factory, pitch)


def _light_case(project: Path, light, renderer, surface: str, tmp_path_factory, pitch=None) -> None:
    """``zcomp composite`` of the project's manifest with the scene's ``light`` (and
    ``pitch_deg``), on ``renderer``: the invariants of the module docstring."""
    work = tmp_path_factory.mktemp(surface)
    shutil.copytree(project, work, dirs_exist_ok=True)
    doc = base_manifest()
    doc["defaults"]["renderer"] = renderer
    doc["scenes"]["room"]["light"] = light
    if pitch is not None:
        doc["scenes"]["room"]["pitch_deg"] = pitch
    manifest = work / "jobs.yaml"
    manifest.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
    out = work / "out"
    before, tmp_before = _snapshot(work, out), _tmp_zcomp_entries()
    r = _invoke(["composite", manifest, "--out", out], surface)
    _unchanged_outside(work, out, before, tmp_before)
    _check_out(out)
    if r.exit_code == 2:
        assert not out.exists()
    shutil.rmtree(work, ignore_errors=True)


# ============================================================================ plugins
# What the fuzz plugin's renderer does this example (set by the test, read by FuzzRenderer).
BEHAVIOUR: dict = {}
_raise = st.sampled_from(["ValueError", "RecursionError", "MemoryError", "KeyError", "SystemExit",
                          "NumericalError", "ZeroDivisionError", "OverflowError"])
_image = st.sampled_from(["ok", "nan", "inf", "negative", "huge", "shape", "dtype64", "uint8", "int", "list",
                          "none", "count", "channels", "scalar"])
_behaviour = st.fixed_dictionaries({"image": _image}, optional={
    "raise": _raise, "info": _values, "timings": _values,
    "shading_mask": st.sampled_from(["ok", "shape", "float", "none", "text"]),
    "debug_maps": st.dictionaries(st.one_of(_weird_text, st.sampled_from(["composite", "ok_map", "../x"])),
                                  st.sampled_from(["ok", "nan", "shape", "text"]), max_size=2)})


def _array(kind, like):
    h = like.shape[0]
    base = np.clip(like, 0, 1).astype(np.float32)
    return {"ok": base, "nan": np.full_like(base, np.nan), "inf": np.full_like(base, np.inf),
            "negative": base - 5.0, "huge": base + 3e38, "shape": base[: h // 2], "dtype64": base.astype(np.float64),
            "uint8": (base * 255).astype(np.uint8), "int": base.astype(np.int64), "list": base.tolist(),
            "none": None, "count": base, "channels": base[..., :1], "scalar": 0.5, "text": "x"}[kind]


class FuzzRendererImpl(Renderer):
    """A plugin renderer doing what ``BEHAVIOUR`` says (the registry imports it from
    this module by name)."""

    name = "fuzzplug"

    def settings(self) -> dict:
        return {"name": self.name}

    def render(self, requests, *, seed: int = 469):
        b = BEHAVIOUR
        if "raise" in b:
            exc = b["raise"]
            if exc == "SystemExit":
                raise SystemExit(0)
            if exc == "NumericalError":
                raise NumericalError("fuzz")
            raise {"ValueError": ValueError, "RecursionError": RecursionError, "MemoryError": MemoryError,
                   "KeyError": KeyError, "ZeroDivisionError": ZeroDivisionError,
                   "OverflowError": OverflowError}[exc]("fuzz")
        images = [_array(b["image"], req.maps.albedo) for req in requests]
        if b["image"] == "count":
            images = images[:1]
        sm = b.get("shading_mask")
        mask = None
        if sm is not None and sm != "none":
            known = np.asarray(requests[0].known, bool)
            mask = {"ok": ~known, "shape": (~known)[:2], "float": (~known).astype(np.float32), "text": "x"}[sm]
        debug = {k: _array(v, requests[0].maps.albedo) for k, v in (b.get("debug_maps") or {}).items()}
        return RenderOutput(images, info=b.get("info", {}), timings=b.get("timings", {}), shading_mask=mask,
                            debug_maps=debug)


class _EntryPoint:
    """An entry point whose ``load()`` does what the example says."""

    def __init__(self, name, what):
        self.name, self.value, self.what = name, f"fuzz:{name}", what

    def load(self):
        from zcomp_cli.renderers.registry import RendererEntry

        w = self.what
        if w == "exit":
            raise SystemExit(0)
        if w in ("ValueError", "RecursionError", "ImportError", "MemoryError"):
            raise {"ValueError": ValueError, "RecursionError": RecursionError, "ImportError": ImportError,
                   "MemoryError": MemoryError}[w]("fuzz plugin import")
        if w == "entry":
            return RendererEntry(__name__, "FuzzRendererImpl", "fuzz plugin")
        return {"none": None, "int": 7, "text": "x", "class": dict}[w]


@pytest.mark.fuzz
@pytest.mark.slow
@_settings("plugins")
@given(behaviour=_behaviour, eps=st.lists(st.tuples(st.sampled_from(["fuzzplug", "physical", "Bad Name", "other",
                                                                      "fuzzplug"]),
                                                     st.sampled_from(["exit", "ValueError", "RecursionError",
                                                                      "ImportError", "MemoryError", "entry", "none",
                                                                      "int", "text", "class"])),
                                           max_size=3))
def test_fuzz_plugins(behaviour, eps, tmp_path_factory, monkeypatch):
    import importlib.metadata

    from zcomp_cli.renderers import registry

    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group=None: [_EntryPoint(n, w) for n, w in eps] + [_EntryPoint("fuzzplug", "entry")])
    reg = registry.RendererRegistry(registry.BUILTIN_RENDERERS)
    table = reg._table()  # discovery never raises, whatever the plugins do
    assert table["physical"].source == "zcomp"  # a plugin never takes a built-in's name
    loadable = {n for n, w in eps if w == "entry"} | {"fuzzplug"}
    for n, w in eps:  # a plugin that cannot load, or loads as something else, is left out and listed
        if w != "entry" and n not in registry.BUILTIN_RENDERERS and n not in loadable:
            assert n not in table and any(repr(n) in p for p in reg.problems), (n, w, reg.problems)
    if "fuzzplug" not in table:  # the drawn ones took the name first (a repeat is left out)
        return
    r, work, out = _run_plugin(behaviour, reg, tmp_path_factory.mktemp("plug"), monkeypatch)
    assert r.exit_code in (0, 1), r.output
    ok = behaviour["image"] in ("ok", "dtype64") and "raise" not in behaviour
    if not ok:  # a plugin that broke the contract: its jobs failed, with a reason
        for j in _strict_json(out / "summary.json")["jobs"]:
            assert j["status"] == "failed" and j["reason"], j
    shutil.rmtree(work, ignore_errors=True)


def _run_plugin(behaviour: dict, reg, work: Path, monkeypatch):
    """``zcomp composite`` of the hostile project with the fuzz plugin as its renderer,
    doing ``behaviour``; returns (result, work, out) with the invariants checked."""
    from zcomp_cli.renderers import registry

    # the CLI's table (every module holds the one RENDERERS object) now has these plugins
    monkeypatch.setattr(registry.RENDERERS, "_all", reg._table())
    monkeypatch.setattr(registry.RENDERERS, "problems", reg.problems)
    BEHAVIOUR.clear()
    BEHAVIOUR.update(behaviour)
    make_project(work)
    doc = base_manifest()
    doc["defaults"]["renderer"] = "fuzzplug"  # (the CLI's --renderer choices were fixed when it was imported)
    (work / "jobs.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    out = work / "out"
    before, tmp_before = _snapshot(work, out), _tmp_zcomp_entries()
    r = _invoke(["composite", work / "jobs.yaml", "--out", out, "--debug"], "plugins")
    _unchanged_outside(work, out, before, tmp_before)
    _check_out(out)
    return r, work, out


@pytest.mark.parametrize("behaviour, words", [
    ({"image": "ok", "raise": "SystemExit"}, "called sys.exit(0)"),
    ({"image": "uint8"}, "as uint8 array: expected a float array of linear radiance"),
    ({"image": "count"}, "returned a list of 1 images for 2 requests"),
    ({"image": "none"}, "as null: expected a float array"),
])
def test_a_plugin_breaking_the_contract_in_render_fails_its_jobs(behaviour, words, tmp_path, monkeypatch):
    """Found by the fuzzer: a plugin whose render() called sys.exit(0) ended the batch
    with its jobs pending and exit 0; one returning 8-bit images (0..255) was composited
    as radiance and reported done; a wrong number of images was an 'internal error'."""
    import importlib.metadata

    from zcomp_cli.renderers import registry

    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group=None: [_EntryPoint("fuzzplug", "entry")])
    reg = registry.RendererRegistry(registry.BUILTIN_RENDERERS)
    r, _, out = _run_plugin(behaviour, reg, tmp_path, monkeypatch)
    assert r.exit_code == 1, r.output
    jobs = _strict_json(out / "summary.json")["jobs"]
    assert len(jobs) == 2 and all(j["status"] == "failed" and words in j["reason"] for j in jobs), jobs


# ============================================================================ issue 50's surfaces
def _tmp_left(before: set) -> set:
    """zcomp's temporaries of this process made since ``before``, less the Blender logs
    kept on purpose (an item failed: its reason names the log); those are removed."""
    import tempfile

    from zcomp_cli.blender.runner import KEEP_MARK

    left = set()
    for name in _tmp_zcomp_entries() - before:
        p = Path(tempfile.gettempdir()) / name
        try:
            kept = p.is_file() and KEEP_MARK in p.read_text(errors="replace")[-200:]
        except OSError:
            kept = False
        if kept:
            p.unlink(missing_ok=True)
        else:
            left.add(name)
    return left


# settings a user would write (they reach Blender), or hostile ones (refused with the field)
_cycles_plausible = st.fixed_dictionaries({}, optional={
    "samples": st.integers(1, 4), "max_bounces": st.integers(0, 4), "denoise": st.booleans(),
    "threads": st.integers(0, 2), "exposure": st.sampled_from(["light", "render"]),
    "world": st.sampled_from(["probe", "model"]), "sky_width": st.integers(8, 64), "probe_width": st.integers(8, 64),
    "world_map_resolution": st.integers(0, 64), "margin_px": st.integers(0, 8),
    "light": st.just({"march_steps": 4, "estimate_march_steps": 4, "n_light_candidates": 16})})
_cycles_hostile = st.fixed_dictionaries({}, optional={
    "samples": _numbers, "max_bounces": _numbers, "denoise": _values, "threads": _numbers,
    "exposure": st.sampled_from(["auto", 3]), "world": st.sampled_from(["x", ""]), "sky_width": _numbers,
    "probe_width": _numbers, "world_map_resolution": _numbers, "margin_px": _numbers, "item_timeout_s": _numbers,
    "light": _values, "bogus": _values})
_cycles_settings = st.one_of(_cycles_plausible, _cycles_plausible, _cycles_plausible, _cycles_hostile)


@pytest.mark.fuzz
@pytest.mark.slow
@pytest.mark.blender
@_settings("cycles")
@given(cfg=_cycles_settings, light=st.one_of(st.none(), _user_light),
       flag=st.one_of(st.none(), st.none(), st.integers(1, 4), _numbers))
def test_fuzz_cycles_inputs(light_project, cfg, light, flag, tmp_path_factory):
    work = tmp_path_factory.mktemp("cycles")
    shutil.copytree(light_project, work, dirs_exist_ok=True)
    doc = base_manifest()
    doc["defaults"]["renderer"] = {"name": "cycles", "denoise": False, **cfg}
    doc["jobs"] = doc["jobs"][:1]  # the ball: one Blender process, two passes
    if light is not None:
        doc["scenes"]["room"]["light"] = _with_probe_paths(light)
    manifest = work / "jobs.yaml"
    manifest.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
    out = work / "out"
    before, tmp_before = _snapshot(work, out), _tmp_zcomp_entries()
    extra = [] if flag is None else ["--renderer", "cycles", "--samples", flag]
    r = _invoke(["composite", manifest, "--out", out, *extra], "cycles")
    assert _snapshot(work, out) == before, "written outside the output"
    assert not _tmp_left(tmp_before), "temporary files left in /tmp"
    _check_out(out)
    if r.exit_code == 2:
        assert not out.exists()
    for j in (_strict_json(out / "summary.json")["jobs"] if (out / "summary.json").exists() else []):
        assert j["status"] == "done" or (j["reason"] and "crashed" not in j["reason"]), j
    shutil.rmtree(work, ignore_errors=True)


_preview_opts = st.fixed_dictionaries({}, optional={
    "--scene": st.lists(st.sampled_from(["room", "room", "nope", " room", "../room"]), min_size=1, max_size=3),
    "--pixel": _mostly(st.tuples(st.integers(0, 127), st.integers(48, 95)), st.tuples(_numbers, _numbers)),
    "--diameter": _mostly(_f(0.05, 0.4), st.one_of(_numbers, st.sampled_from([1e-9, 50.0, 1e3]))),
    "--samples": _mostly(st.integers(1, 4), st.sampled_from([0, 4097, -1, 10**9]))})


@pytest.fixture(scope="module")
def preview_project(tmp_path_factory):
    shared = tmp_path_factory.mktemp("fuzz_preview")
    make_project(shared, width=128, height=96)
    return shared


def _preview_state(out: Path, state: str, elsewhere: Path) -> None:
    (out / "preview").parent.mkdir(parents=True, exist_ok=True)
    if state == "linked":
        elsewhere.mkdir(exist_ok=True)
        (out / "preview").symlink_to(elsewhere)
    elif state in ("sheets", "fifo-sheet", "half-pair"):
        (out / "preview").mkdir()
        if state == "fifo-sheet":
            os.mkfifo(out / "preview" / "room.png")
        else:
            (out / "preview" / "room.png").write_bytes(b"an old sheet")
            if state == "sheets":
                (out / "preview" / "room.json").write_text("{}")


@pytest.mark.fuzz
@pytest.mark.slow
@pytest.mark.blender
@_settings("preview")
@given(opts=_preview_opts, state=st.sampled_from(["fresh", "fresh", "sheets", "linked", "fifo-sheet", "half-pair"]),
       overwrite=st.booleans(), depth=st.sampled_from(["ok", "ok", "1e30", "nan", "zeros", "negative"]))
def test_fuzz_preview_light(preview_project, opts, state, overwrite, depth, tmp_path_factory):
    from zcomp_cli.imageio import read_map, write_exr

    work = tmp_path_factory.mktemp("preview")
    shutil.copytree(preview_project, work, dirs_exist_ok=True)
    d = read_map(work / "scenes/depth.exr", channels=1)
    bad = {"1e30": np.float32(1e30), "nan": np.float32(np.nan), "zeros": np.float32(0), "negative": np.float32(-2)}
    if depth in bad:
        write_exr(work / "scenes/depth.exr", np.where(d > 0, bad[depth], d).astype(np.float32))
    out = work / "out"
    _preview_state(out, state, work / "elsewhere")
    args = ["preview-light", work / "jobs.yaml", "--out", out]
    for k, v in opts.items():
        args += [x for item in (v if k == "--scene" else [v]) for x in ((k, item) if k == "--scene" else
                                                                        (k, *([v] if k != "--pixel" else v)))]
    if overwrite:
        args.append("--overwrite")
    before, tmp_before = _snapshot(work, out), _tmp_zcomp_entries()
    _invoke(args, "preview")
    assert _snapshot(work, out) == before, "written outside the output"
    assert not _tmp_left(tmp_before), "temporary files left in /tmp"
    folder = out / "preview"
    if folder.is_dir() and not folder.is_symlink():
        names = {p.name for p in folder.iterdir()}
        assert not [n for n in names if n.startswith(".")], names  # no lock, no temporary
        for n in names:
            stem = n.rsplit(".", 1)[0]
            if (folder / n).is_file() and state == "fresh":
                assert {f"{stem}.png", f"{stem}.json"} <= names, names  # a sheet with its numbers
            if n.endswith(".json") and state != "sheets":
                _strict_json(folder / n)
    shutil.rmtree(work, ignore_errors=True)


BALLS = ["ball_float.tif", "ball_u16.png", "ball_ok.exr", "ball_nan.exr", "ball_tiny.exr", "ball_black.png"]


@pytest.fixture(scope="module")
def ball_project(light_project):
    """The lights' project with chrome-ball photographs in ``balls/``: a float TIFF, a
    16-bit PNG, an EXR, one with NaN, a 2 x 2 one, a black one."""
    import OpenImageIO as oiio

    from zcomp_cli.imageio import write_exr, write_png

    b = light_project / "balls"
    b.mkdir(exist_ok=True)
    yy, xx = np.mgrid[0:64, 0:64]
    ball = (np.where(((xx - 32) ** 2 + (yy - 32) ** 2 < 28 ** 2)[..., None], 0.3, 0.05) * np.ones(3)).astype(np.float32)
    ball[20:23, 40:43] = 80.0  # a sun on the ball, far above 1
    tif = oiio.ImageOutput.create(str(b / "ball_float.tif"))
    tif.open(str(b / "ball_float.tif"), oiio.ImageSpec(64, 64, 3, oiio.FLOAT))
    tif.write_image(ball)
    tif.close()
    write_png(b / "ball_u16.png", np.clip(ball, 0, 1), bits=16)
    write_exr(b / "ball_nan.exr", np.where(ball > 1, np.nan, ball).astype(np.float32))
    write_exr(b / "ball_tiny.exr", ball[:2, :2])
    write_exr(b / "ball_ok.exr", ball)
    write_png(b / "ball_black.png", np.zeros((64, 64, 3), np.float32))
    return light_project


@pytest.mark.fuzz
@pytest.mark.slow
@_settings("balls")
@given(image=st.sampled_from(BALLS[:3] * 3 + BALLS), center=_mostly(st.tuples(_f(26, 38), _f(26, 38)).map(list),
                                                    st.one_of(_vec(2), st.just([1e9, 0]), _values)),
       radius=_mostly(_f(8, 20), st.one_of(_numbers, _values)), extra=st.fixed_dictionaries({}, optional={
           "reflectance": _mostly(_f(0.05, 1), _numbers), "strength": _mostly(_f(0.1, 5), _numbers)}),
       unknown=st.one_of(st.just({}), st.just({}), st.just({}), st.just({"rotation_deg": 30})),
       renderer=st.sampled_from(["physical", "naive"]))
def test_fuzz_chrome_balls(ball_project, image, center, radius, extra, unknown, renderer, tmp_path_factory):
    cheap = {"name": "physical", "march_steps": 4, "estimate_march_steps": 4, "n_light_candidates": 16,
             "cone_samples": 2, "max_fit_pixels": 500}
    light = [{"type": "chrome_ball", "image": f"balls/{image}", "center": center, "radius": radius, **extra,
              **unknown}]
    _light_case(ball_project, light, cheap if renderer == "physical" else "naive", "balls", tmp_path_factory)


_page_text = st.one_of(_weird_text, st.sampled_from([
    "%DATA%", "%JS%", "%CSS%", "%HEAD%", "%TITLE%", "%PREVIEWS%", "%NONCE%", 'a" onload="x()', " onload=x() ",
    "</script><script>x()</script>", "<img src=x onerror=x()>", "caf\udce9", "\u2028", "y" * 100_000]),
    st.text(max_size=30))
_report_doc = st.one_of(st.just("ok"), st.just("deep"), st.just("fifo"), st.just("link-out"), _values)


@st.composite
def report_folders(draw):
    jobs = draw(st.lists(st.tuples(_page_text, st.sampled_from(["done", "failed", "skipped", "x"]), _page_text),
                         max_size=4))
    reports = draw(st.lists(_report_doc, max_size=3))
    summary = draw(st.one_of(st.just("ok"), st.just("deep"), st.just("fifo"), _values))
    ev = draw(st.one_of(st.none(), st.just("deep"), st.just("empty-csv"), st.just("huge-csv"), _values,
                        st.builds(lambda m: {"metrics": [m], "images": [{"name": "job0", m: 1.5}]}, _page_text)))
    previews = draw(st.lists(_page_text, max_size=3))
    return jobs, reports, summary, ev, previews


def _write_report_folder(out: Path, case, elsewhere: Path) -> None:
    from zcomp_cli.report.synthetic import tiny_png

    jobs, reports, summary, ev, previews = case
    out.mkdir(parents=True)
    deep = "[" * 50_000 + "]" * 50_000
    rows = [{"index": i, "name": n, "status": st_, "reason": r, "seconds": 0.1, "this_run": st_}
            for i, (n, st_, r) in enumerate(jobs)]
    if summary == "fifo":
        os.mkfifo(out / "summary.json")
    else:
        (out / "summary.json").write_text(deep if summary == "deep" else json.dumps(
            {"jobs": rows} if summary == "ok" else summary))
    for k, rep in enumerate(reports):
        d = out / f"job{k}"
        if rep == "link-out":
            elsewhere.mkdir(exist_ok=True)
            (elsewhere / "report.json").write_text('{"status": "done", "outputs": {}}')
            d.symlink_to(elsewhere)
            continue
        d.mkdir()
        (d / "composite.png").write_bytes(tiny_png((200, 100, 50)))
        if rep == "fifo":
            os.mkfifo(d / "report.json")
        else:
            doc = {"status": "done", "outputs": {}, "job": {"scene": "s", "object": "o"},
                   "roi": {"box": [1, 1, 8, 6]}, "scene": {"size": [16, 12]}} if rep == "ok" else rep
            (d / "report.json").write_text(deep if rep == "deep" else json.dumps(doc))
    if ev in ("empty-csv", "huge-csv"):
        (out / "eval.csv").write_text("" if ev == "empty-csv" else "name,pred,ref,psnr\njob0,a,b," + "9" * 200_000)
    elif ev is not None:
        (out / "eval.json").write_text(deep if ev == "deep" else json.dumps(ev))
    if previews:
        (out / "preview").mkdir()
        for name in previews:
            try:
                (out / "preview" / f"{name[:100]}.png").write_bytes(tiny_png((9, 9, 9)))
            except (OSError, ValueError, UnicodeEncodeError):  # not a file name on this system
                pass


@pytest.mark.fuzz
@pytest.mark.slow
@_settings("report")
@given(case=report_folders())
def test_fuzz_report_page(case, tmp_path_factory):
    from html.parser import HTMLParser

    work = tmp_path_factory.mktemp("report")
    out = work / "out"
    _write_report_folder(out, case, work / "elsewhere")
    before = _snapshot(work, work / "none")
    r = _invoke(["report", out, "--title", "t %DATA%"], "report")
    after = _snapshot(work, work / "none")
    changed = {p for p in set(before) | set(after) if before.get(p) != after.get(p)}
    mine = (str(out / "report.html"), str(out / "report_thumbs"))
    assert all(str(p) == mine[0] or str(p).startswith(mine[1]) for p in changed), changed
    page = out / "report.html"
    if r.exit_code == 0:
        text = page.read_bytes().decode("utf-8")  # valid UTF-8
        attrs, scripts = [], []

        class P(HTMLParser):
            def handle_starttag(self, tag, a):
                attrs.extend(k for k, _ in a)
                if tag == "script":
                    scripts.append(dict(a))

        P().feed(text)
        assert not [a for a in attrs if a.lower().startswith("on")], "an event handler in the page"
        assert len(scripts) == 2 and scripts[0].get("type") == "application/json" and scripts[1].get("nonce")
        assert len(text) < 5_000_000
    shutil.rmtree(work, ignore_errors=True)


@pytest.mark.fuzz
@pytest.mark.slow
def test_fuzz_surfaces_report(capsys):
    """Prints the counts of the fuzz runs above (for the closing note)."""
    with capsys.disabled():
        for k, v in STATS.items():
            print(f"\nfuzz {k} ({PROFILE}): {v['cases']} cases, exit codes {v['exit']}")
