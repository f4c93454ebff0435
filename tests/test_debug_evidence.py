"""A renderer's own debug maps (``RenderOutput.debug_maps``) and the physical renderer's
light evidence among them (issue 37: the cast-shadow evidence is "a soft mask with a
confidence, in the debug outputs").

The pipeline writes a renderer's maps as ``debug/<name>.exr`` with ``--debug`` only,
beside the background on ``light_evidence.png``; names and shapes are checked. The
physical renderer returns the evidence its light fit read (``evidence_maps``), which
``lightfit.fit_light`` fills its ``diagnostics`` dict with.
"""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import numpy as np
import pytest

from hostile_project import make_project, run_composite
from zcomp_cli.errors import RenderError
from zcomp_cli.imageio import read_map
from zcomp_cli.maps import SceneMaps
from zcomp_cli.pipeline.job import check_debug_maps
from zcomp_cli.pipeline.outputs import DEBUG_MAPS, MAPS_SHEET, foreign_entries, maps_sheet
from zcomp_cli.renderers.base import RenderOutput, RenderRequest
from zcomp_cli.renderers.physical import PhysicalRenderer
from zcomp_cli.light.evidence_maps import MAP_NAMES, LightEvidence, to_frame
from zcomp_cli.renderers.registry import RENDERERS
from zcomp_cli.testing import floor_scene

JOB = "000_room_ball"


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture
def naive_with_maps(monkeypatch):
    """The ``naive`` renderer returning debug maps (``maps(requests) -> dict``, settable:
    ``naive_with_maps.maps = ...``) whatever ``RenderRequest.debug`` says; ``seen``
    collects the requests' debug flags."""
    from zcomp_cli.renderers.naive import NaiveRenderer

    real = NaiveRenderer.render
    state = SimpleNamespace(seen=[], maps=None)

    def default(requests):
        H, W = np.shape(requests[0].known)
        return {"probe_known": np.asarray(requests[0].known, np.float32),
                "probe_rgb": np.dstack([np.linspace(0, 1, W)[None].repeat(H, 0)] * 3).astype(np.float32)}

    state.maps = default

    def render(self, requests, *, seed=469):
        out = real(self, requests, seed=seed)
        state.seen.extend(bool(r.debug) for r in requests)
        return dataclasses.replace(out, debug_maps=state.maps(requests))

    monkeypatch.setattr(NaiveRenderer, "render", render)
    return state


def _report(out):
    return json.loads((out / JOB / "report.json").read_text())


def _summary_reason(out):
    doc = json.loads((out / "summary.json").read_text())
    return next(j for j in doc["jobs"] if j["name"] == JOB)["reason"] or ""


# ----------------------------------------------------------------------------- pipeline
def test_renderer_maps_are_written_with_debug_and_not_without(tmp_path, naive_with_maps):
    make_project(tmp_path)
    out = tmp_path / "out"
    assert run_composite(tmp_path / "jobs.yaml", out, "--debug", "--jobs", "0").exit_code == 0
    assert naive_with_maps.seen and all(naive_with_maps.seen)  # the renderer is told
    job = out / JOB
    known = read_map(job / "debug/probe_known.exr")
    rgb = read_map(job / "debug/probe_rgb.exr", channels=3)
    assert known.shape == (24, 32) and set(np.unique(known)) <= {0.0, 1.0} and (known == 0).any()
    assert rgb.shape == (24, 32, 3) and np.allclose(rgb[0, :, 0], np.linspace(0, 1, 32), atol=1e-6)
    assert (job / MAPS_SHEET).is_file() and (job / "grid.png").is_file() and (job / "debug/f_bg.exr").is_file()
    outputs = _report(out)["outputs"]
    assert {"debug/probe_known.exr", "debug/probe_rgb.exr", MAPS_SHEET} <= set(outputs)

    naive_with_maps.seen.clear()
    plain = tmp_path / "plain"
    assert run_composite(tmp_path / "jobs.yaml", plain, "--jobs", "0").exit_code == 0
    assert naive_with_maps.seen and not any(naive_with_maps.seen)
    assert not (plain / JOB / "debug").exists() and not (plain / JOB / MAPS_SHEET).exists()
    assert not any(k.startswith("debug/") or k == MAPS_SHEET for k in _report(plain)["outputs"])


@pytest.mark.parametrize("name", ["../escape", "sub/dir", "sub\\dir", "/abs", ".hidden", "", "x.exr",
                                  "Upper", "a" * 65, "ratio", "f_bg", 3])
def test_debug_map_names_are_checked(name):
    with pytest.raises(RenderError, match="debug map named") as e:
        check_debug_maps({name: np.zeros((4, 5))}, (4, 5), "toon")
    assert repr(name) in str(e.value) and "toon" in str(e.value)


def test_good_names_and_shapes_pass():
    maps = {"shadow_evidence": np.zeros((4, 5)), "a-b_2": np.zeros((4, 5, 1)), "rgb": np.zeros((4, 5, 3), int),
            "rgba": np.full((4, 5, 4), np.nan)}
    got = check_debug_maps(maps, (4, 5), "toon")
    assert list(got) == list(maps) and all(a.dtype == np.float32 for a in got.values())
    assert check_debug_maps(None, (4, 5), "toon") == {} and check_debug_maps({}, (4, 5), "toon") == {}
    assert not set(DEBUG_MAPS) & set(MAP_NAMES)


@pytest.mark.parametrize("shape", [(5, 4), (4, 6), (4, 5, 2), (4, 5, 5), (4,), (4, 5, 3, 1), ()])
def test_debug_maps_of_another_shape_are_refused_by_name(shape):
    with pytest.raises(RenderError, match=r"debug map 'casters' of shape") as e:
        check_debug_maps({"fine": np.zeros((4, 5)), "casters": np.zeros(shape)}, (4, 5), "toon")
    assert "(4, 5)" in str(e.value)
    with pytest.raises(RenderError, match="'casters' that is not a numeric array"):
        check_debug_maps({"casters": [[1, 2], [3]]}, (4, 5), "toon")
    with pytest.raises(RenderError, match="mapping"):
        check_debug_maps([np.zeros((4, 5))], (4, 5), "toon")


def test_a_bad_map_fails_its_job_and_writes_nothing_outside(tmp_path, naive_with_maps):
    make_project(tmp_path)
    out = tmp_path / "out"
    naive_with_maps.maps = lambda reqs: {"../../escape": np.zeros(np.shape(reqs[0].known))}
    assert run_composite(tmp_path / "jobs.yaml", out, "--debug", "--jobs", "0").exit_code == 1
    assert "'../../escape'" in _summary_reason(out)
    assert not list(tmp_path.rglob("escape*"))
    naive_with_maps.maps = lambda reqs: {"shadow_ratio": np.zeros((3, 3))}
    assert run_composite(tmp_path / "jobs.yaml", out, "--debug", "--jobs", "0", "--overwrite").exit_code == 1
    assert "debug map 'shadow_ratio' of shape (3, 3)" in _summary_reason(out)
    # without --debug the maps are not looked at
    assert run_composite(tmp_path / "jobs.yaml", out, "--jobs", "0", "--overwrite").exit_code == 0


def test_job_folders_holding_renderer_maps_are_zcomps(tmp_path, naive_with_maps, monkeypatch):
    make_project(tmp_path)
    out = tmp_path / "out"
    assert run_composite(tmp_path / "jobs.yaml", out, "--debug", "--jobs", "0").exit_code == 0
    job = out / JOB
    # the report records them: a re-run may write there
    assert foreign_entries(job) == []
    assert run_composite(tmp_path / "jobs.yaml", out, "--debug", "--jobs", "0", "--overwrite").exit_code == 0
    # a run killed before its report: maps the renderers declare are still zcomp's ...
    (job / "report.json").unlink()
    (job / "debug/shadow_evidence.exr").write_bytes(b"x")
    assert foreign_entries(job) == ["debug/probe_known.exr", "debug/probe_rgb.exr"]
    table = RENDERERS._table()
    monkeypatch.setitem(table, "naive", dataclasses.replace(table["naive"], debug_maps=("probe_known", "probe_rgb")))
    assert foreign_entries(job) == []
    # ... anything else is not
    (job / "debug/notes.txt").write_text("mine")
    assert foreign_entries(job) == ["debug/notes.txt"]


def test_maps_an_earlier_run_left_are_removed(tmp_path, naive_with_maps, monkeypatch):
    make_project(tmp_path)
    out = tmp_path / "out"
    naive_with_maps.maps = lambda reqs: {"shadow_evidence": np.ones(np.shape(reqs[0].known))}
    assert run_composite(tmp_path / "jobs.yaml", out, "--debug", "--jobs", "0").exit_code == 0
    assert (out / JOB / "debug/shadow_evidence.exr").is_file() and (out / JOB / MAPS_SHEET).is_file()
    naive_with_maps.maps = lambda reqs: {}
    assert run_composite(tmp_path / "jobs.yaml", out, "--debug", "--jobs", "0", "--overwrite").exit_code == 0
    assert not (out / JOB / "debug/shadow_evidence.exr").exists() and not (out / JOB / MAPS_SHEET).exists()
    assert (out / JOB / "debug/f_bg.exr").is_file()
    assert "debug/shadow_evidence.exr" not in _report(out)["outputs"]


def test_the_sheet_shows_the_maps_beside_the_background():
    H, W = 30, 40
    bg = np.full((H, W, 3), 0.18, np.float32)
    ratio = np.full((H, W), 0.5, np.float32)
    ratio[:20] = np.nan
    maps = {"a": np.zeros((H, W)), "b": np.ones((H, W, 1)), "ratio": ratio, "rgb": np.ones((H, W, 3))}
    sheet = maps_sheet(bg, maps)
    assert sheet.shape == (2 * H, 3 * W, 3) and sheet.dtype == np.float32
    assert 0.0 <= sheet.min() and sheet.max() <= 1.0
    r0, c0 = H, 0  # "ratio": the 4th tile, second row
    assert np.allclose(sheet[r0 + 25, c0 + 20], 0.5)
    from zcomp_cli.pipeline.outputs import NAN_COLOUR

    assert np.allclose(sheet[r0 + 17, c0 + 20], NAN_COLOUR)  # NaN: no value (below the label)
    assert np.allclose(sheet[2 * H - 1, 3 * W - 1], 0.0)  # the empty slot


def test_the_physical_entry_declares_its_maps():
    assert RENDERERS["physical"].debug_maps == MAP_NAMES


# ----------------------------------------------------------------------------- evidence maps
def test_to_frame_enlarges_nearest_and_shrinks_by_area():
    g = np.arange(12, dtype=np.float32).reshape(3, 4)
    g[0, 0] = np.nan
    up = to_frame(g, (6, 8))
    assert up.shape == (6, 8) and up.dtype == np.float32
    for y in range(6):
        for x in range(8):
            v, want = up[y, x], g[y // 2, x // 2]
            assert (np.isnan(v) and np.isnan(want)) or v == want
    # a grid that does not divide the frame: each pixel takes the cell holding its centre
    odd = to_frame(np.array([[0.0, 1.0, 2.0]], np.float32), (1, 7))
    assert odd.tolist() == [[0, 0, 1, 1, 1, 2, 2]]
    assert np.array_equal(to_frame(g, (3, 4)), g, equal_nan=True) and to_frame(g, (3, 4)) is not g
    down = to_frame(np.array([[np.nan, 1.0], [3.0, 5.0]], np.float32), (1, 1))
    assert np.allclose(down, 3.0)  # the mean of the values there (NaN left out)
    assert np.isnan(to_frame(np.full((2, 2), np.nan, np.float32), (1, 1))).all()


def _fake_fit(h=3, w=4):
    ratio = np.full((h, w), np.nan)
    ratio[1:] = 1.0
    ratio[1, 1:3] = (0.5, 0.7)
    ratio[2, 2] = 0.6
    tied = np.zeros((h, w), bool)
    tied[1, 1:3] = True
    weight = np.where(np.isfinite(ratio), 1.0, 0.0)
    weight[2, 2] = 0.0  # a dark region tied to nothing
    ev = SimpleNamespace(ratio=ratio, weight=weight, soft_mask=np.where(tied, 0.8, 0.0))
    support = np.zeros((h, w), bool)
    support[1:] = True
    casters = np.zeros((h, w), bool)
    casters[0, 1:3] = True
    return ev, SimpleNamespace(shape=(h, w), support=support, casters=casters)


def test_light_evidence_from_the_fit():
    ev, mesh = _fake_fit()
    le = LightEvidence.from_diagnostics({"evidence": ev, "mesh": mesh})
    assert le is not None and le.shape == (3, 4)
    maps = le.maps((6, 8))
    assert list(maps) == list(MAP_NAMES)
    assert all(m.shape == (6, 8) and m.dtype == np.float32 for m in maps.values())
    assert np.allclose(maps["casters"][0:2, 2:6], 1.0) and np.allclose(maps["casters"][2:, :], 0.5)
    assert np.allclose(maps["casters"][0:2, 0:2], 0.0)
    assert np.allclose(maps["shadow_evidence"][2:4, 2:6], 0.8) and maps["shadow_evidence"][4:].max() == 0
    assert maps["shadow_confidence"][4, 4] == 0 and maps["shadow_confidence"][4, 0] == 1
    assert np.isnan(maps["shadow_ratio"][:2]).all() and maps["shadow_ratio"][2, 2] == pytest.approx(0.5)
    assert LightEvidence.from_diagnostics({}) is None
    assert LightEvidence.from_diagnostics({"evidence": ev}) is None
    assert LightEvidence.from_fit(ev, SimpleNamespace(shape=(2, 4))) is None  # another grid


# ----------------------------------------------------------------------------- physical renderer
LIGHT = (0.7, 1.0, 0.2)


@pytest.fixture(scope="module")
def boxed():
    return floor_scene(112, 84, with_box=True, light_dir=LIGHT, ambient=0.3, box_center=(-0.4, -3.2))


def _requests(s, debug, key="boxed"):
    known = np.ones(s.depth.shape, bool)
    known[50:70, 60:90] = False
    maps = SceneMaps(s.depth, s.normals, s.albedo)
    return [RenderRequest(maps, s.shading, known, s.camera, scene_key=key, debug=debug) for _ in range(2)]


def test_the_physical_renderer_returns_the_light_evidence(boxed):
    # a shadow grid half the frame's size: the maps come back at the frame's
    r = PhysicalRenderer(shadow_resolution=56, n_light_candidates=64)
    out = r.render(_requests(boxed, debug=True), seed=3)
    maps = out.debug_maps
    assert list(maps) == list(MAP_NAMES)
    assert all(m.shape == (84, 112) and m.dtype == np.float32 for m in maps.values())
    ev, conf, ratio, cast = (maps[n] for n in MAP_NAMES)
    assert 0 <= ev.min() and ev.max() <= 1 and set(np.unique(conf)) <= {0.0, 1.0}
    assert {0.5, 1.0} <= set(np.unique(cast)) <= {0.0, 0.5, 1.0}
    box = (boxed.depth > 0) & (boxed.normals @ boxed.up_cam < 0.9)
    assert (cast[box] == 1).mean() > 0.8  # the box is the caster
    assert (cast[boxed.depth > 0] == 0.5).mean() > 0.5  # the floor the support
    # the box's shadow on the floor: tied evidence where the scene is in shadow
    shadow = (boxed.visibility < 0.5) & ~box & (boxed.depth > 0)
    assert (ev[shadow] > 0.5).mean() > 0.3 and (ev[~shadow & ~box] > 0.5).mean() < 0.05
    assert np.isnan(ratio[cast != 0.5]).all() and np.nanmedian(ratio[shadow]) < 0.8
    assert check_debug_maps(maps, (84, 112), "physical").keys() == maps.keys()
    # the same scene without --debug: no maps (the evidence stays cached for the scene)
    assert r.render(_requests(boxed, debug=False), seed=3).debug_maps == {}
    assert r.render(_requests(boxed, debug=True), seed=3).debug_maps.keys() == maps.keys()


def test_the_renderer_reads_the_evidence_of_the_fitted_light(boxed):
    """The hook: the evidence the request's fitted light holds (``FittedLight.evidence``,
    the light stage's) is what ``render`` returns; a fit that says nothing (a given
    light) gives no maps."""
    import dataclasses

    r = PhysicalRenderer(n_light_candidates=32)
    reqs = _requests(boxed, debug=True, key="kept")
    fitted = r.fitted_light(reqs[0], 3)
    assert fitted.evidence is not None
    ev, mesh = _fake_fit(42, 56)
    swapped = [dataclasses.replace(q, fitted_light=dataclasses.replace(fitted, evidence=LightEvidence.from_fit(ev, mesh)))
               for q in reqs]
    maps = r.render(swapped, seed=3).debug_maps
    assert list(maps) == list(MAP_NAMES) and maps["casters"].shape == (84, 112)
    assert np.allclose(maps["casters"][:2], [[0, 0, 1, 1, 1, 1] + [0] * 106] * 2)
    none = [dataclasses.replace(q, fitted_light=dataclasses.replace(fitted, evidence=None)) for q in reqs]
    assert r.render(none, seed=3).debug_maps == {}


def test_a_composite_with_debug_writes_the_light_evidence(tmp_path):
    make_project(tmp_path)
    out = tmp_path / "out"
    r = run_composite(tmp_path / "jobs.yaml", out, "--renderer", "physical", "--debug", "--jobs", "0")
    assert r.exit_code == 0, r.output
    job = out / JOB
    for name in MAP_NAMES:
        m = read_map(job / "debug" / f"{name}.exr")
        assert m.shape == (24, 32), name
    assert (job / MAPS_SHEET).is_file()
    cast = read_map(job / "debug/casters.exr")
    assert (cast == 0.5).mean() > 0.3  # the floor
    assert set(f"debug/{n}.exr" for n in MAP_NAMES) <= set(_report(out)["outputs"])
