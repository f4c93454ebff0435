"""The physical renderer's settings and constants (renderers/physical/settings.py, with the
light stage's light/config.py and the scene's scene/config.py, declared through
zcomp_cli.knobs): every field declared once, each with its provenance and range; nested
configs built from mappings (what a calibration script does), checked; the whole config
in the renderer's report, and taken back."""

import dataclasses

import numpy as np
import pytest

from zcomp_cli.errors import UsageError
from zcomp_cli.light.config import SearchConfig
from zcomp_cli.renderers.physical.settings import DEFAULTS, KINDS, PhysicalSettings, knob, provenance


def test_every_field_says_where_it_comes_from():
    rows = provenance()
    assert len(rows) > 50
    names = [r["name"] for r in rows]
    assert len(names) == len(set(names))
    for r in rows:
        assert r["kind"] in KINDS, r
        assert isinstance(r["why"], str) and len(r["why"].split()) >= 3, r
    # the fitted ones name the script that fits them
    fitted = [r for r in rows if r["kind"] == "fitted"]
    assert {"light.search.temperature", "light.search.prior_sky_share"} <= {r["name"] for r in fitted}
    assert all("fit_light_constants" in r["why"] for r in fitted), fitted


def test_a_field_without_provenance_fails():
    with pytest.raises(ValueError, match="unknown provenance kind"):
        knob(1.0, "magic", "because")
    with pytest.raises(ValueError, match="says why"):
        knob(1.0, "heuristic", " ")

    @dataclasses.dataclass(frozen=True)
    class Bare:
        x: float = 1.0

    # provenance() of a config holding a bare field shows it without a kind: the test
    # above fails on it
    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Holder(PhysicalSettings):
        extra: Bare = dataclasses.field(default_factory=Bare)

    rows = provenance(Holder())
    assert any(r["name"] == "extra.x" and r["kind"] is None for r in rows)


def test_nested_configs_from_mappings_and_their_errors():
    # the light's settings beside the renderer's own go into its light config
    s = PhysicalSettings.from_kwargs(search={"temperature": 20, "radii_deg": [0, 2, 4]}, n_light_candidates=64)
    lc = s.light
    assert isinstance(lc.search, SearchConfig) and lc.search.temperature == 20.0 and lc.search.radii_deg == (0.0, 2.0, 4.0)
    assert lc.search.lamp_top == DEFAULTS.light.search.lamp_top and lc.n_light_candidates == 64
    assert PhysicalSettings.from_kwargs(light={"search": {"temperature": 20}}).light.search.temperature == 20.0
    with pytest.raises(UsageError, match="search: unknown field"):
        PhysicalSettings.from_kwargs(search={"temprature": 20})
    with pytest.raises(UsageError, match="search.temperature"):
        PhysicalSettings.from_kwargs(search={"temperature": float("nan")})
    with pytest.raises(UsageError, match="search.lamp_top: expected a positive integer"):
        PhysicalSettings.from_kwargs(search={"lamp_top": 2.5})
    with pytest.raises(UsageError, match="expected a mapping"):
        PhysicalSettings.from_kwargs(mesh=3)
    with pytest.raises(UsageError, match="unknown physical renderer setting"):
        PhysicalSettings.from_kwargs(temperature=3)
    with pytest.raises(UsageError, match="given both"):
        PhysicalSettings.from_kwargs(search={"temperature": 2}, light={"search": {"temperature": 3}})
    # a value the fit takes is a value the settings take: 0 is the fitted prior power
    assert PhysicalSettings.from_kwargs(search={"elevation_prior_power": 0}).light.search.elevation_prior_power == 0
    with pytest.raises(UsageError, match="elevation_prior_power"):
        PhysicalSettings.from_kwargs(search={"elevation_prior_power": -1})


def test_the_whole_config_goes_into_the_report():
    from zcomp_cli.maps import SceneMaps
    from zcomp_cli.renderers.base import RenderRequest
    from zcomp_cli.renderers.physical import PhysicalRenderer
    from zcomp_cli.testing import floor_scene

    s = floor_scene(64, 48, with_box=True, light_dir=(0.7, 1.0, 0.2), ambient=0.3, box_center=(-0.4, -3.2))
    known = np.ones(s.depth.shape, bool)
    known[20:30, 20:40] = False
    req = RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known, s.camera)
    r = PhysicalRenderer(search={"temperature": 7.0})
    out = r.render([req, req])
    cfg = out.info["settings"]
    light = cfg["light"]
    assert light["search"]["temperature"] == 7.0 and light["mesh"]["step_share"] == DEFAULTS.light.mesh.step_share
    assert light["solver"]["huber_c"] == DEFAULTS.light.solver.huber_c and cfg["name"] == "physical"


def test_a_config_changes_the_estimate():
    """The configs are what the estimate reads: a different temperature spreads the
    posterior (the stated uncertainty grows)."""
    from zcomp_cli.scene.frame import scene_up
    from zcomp_cli.testing import estimate_light, floor_scene

    s = floor_scene(96, 72, with_box=True, light_dir=(0.7, 1.0, 0.2), ambient=0.3, box_center=(-0.4, -3.2))
    known = s.depth > 0
    up, uf = scene_up(None, s.normals, known)
    cold = estimate_light(s.depth, s.normals, s.shading, known, s.albedo, s.camera, up=up, with_fit=True,
                          cfg=PhysicalSettings.from_kwargs(search={"temperature": 1.0}).light).posterior
    hot = estimate_light(s.depth, s.normals, s.shading, known, s.albedo, s.camera, up=up, with_fit=True,
                         cfg=PhysicalSettings.from_kwargs(search={"temperature": 1000.0}).light).posterior
    assert hot.rms_angle_deg() > cold.rms_angle_deg() + 5.0


def test_the_synthesis_configs_from_mappings_and_their_checks():
    from zcomp_cli.renderers.physical.settings import TransportConfig
    from zcomp_cli.renderers.physical.softshadow import blur_reach

    s = PhysicalSettings.from_kwargs(transport={"sky_bounce": 0.25, "penumbra_levels_px": [0, 2, 8]},
                                     probe={"max_sources": 1}, gloss={"gloss_roughness": [0.1, 0.5, 1]})
    assert s.transport.sky_bounce == 0.25 and s.transport.penumbra_levels_px == (0.0, 2.0, 8.0)
    assert s.transport.max_penumbra_px == 8.0 and s.light.probe.max_sources == 1
    assert s.gloss.gloss_roughness == (0.1, 0.5, 1.0) and s.light.march.sky_steps == DEFAULTS.light.march.sky_steps
    assert PhysicalSettings.from_kwargs(transport={"sky_bounce": 0}).transport.sky_bounce == 0.0
    with pytest.raises(UsageError, match="penumbra_levels_px"):
        PhysicalSettings.from_kwargs(transport={"penumbra_levels_px": [1, 2]})
    with pytest.raises(UsageError, match="penumbra_levels_px"):
        PhysicalSettings.from_kwargs(transport={"penumbra_levels_px": [0, 4, 2]})
    with pytest.raises(UsageError, match="gloss_roughness"):
        PhysicalSettings.from_kwargs(gloss={"gloss_roughness": [0.5]})
    with pytest.raises(UsageError, match="march.sky_directions: expected a positive integer"):
        PhysicalSettings.from_kwargs(march={"sky_directions": 2.5})
    # the derived sizes: a shadow's window holds what its widest blur and the blocker
    # search read; the edge fade is the sky blur's multiple
    for t in (DEFAULTS.transport, s.transport, TransportConfig(blocker_search_px=40)):
        assert t.window_margin_px >= max(blur_reach(t.max_penumbra_px), blur_reach(t.blocker_search_px))
    assert DEFAULTS.transport.window_margin_px == 48 and DEFAULTS.transport.edge_fade_px == 6.0


def test_the_synthesis_reads_its_configs():
    """The transport and probe configs are what the synthesis reads: a different bounce
    changes the shaded pixels (and only them), a probe split keeps at most
    ``max_sources``, another BRDF table another environment BRDF."""
    from zcomp_cli.maps import SceneMaps
    from zcomp_cli.renderers.base import RenderRequest
    from zcomp_cli.renderers.physical import PhysicalRenderer
    from zcomp_cli.renderers.physical.gloss import env_brdf
    from zcomp_cli.renderers.physical.settings import GlossConfig
    from zcomp_cli.scene.config import ProbeConfig
    from zcomp_cli.scene.probe import split_probe
    from zcomp_cli.testing import floor_scene
    from zcomp_cli.worldframe import ground_frame

    s = floor_scene(64, 48, with_box=True, light_dir=(0.7, 1.0, 0.2), ambient=0.3, box_center=(-0.4, -3.2))
    known = np.ones(s.depth.shape, bool)
    known[20:30, 20:40] = False
    req = RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known, s.camera)
    a = PhysicalRenderer().render([req]).images[0]
    b = PhysicalRenderer(transport={"sky_bounce": 0.9}).render([req]).images[0]
    assert np.array_equal(a[known], b[known]) and not np.array_equal(a[~known], b[~known])

    img = np.full((32, 64, 3), 0.2)
    img[6:8, 10:12] = 400.0
    img[6:8, 40:42] = 300.0
    frame = ground_frame(np.array([0.0, 1.0, 0.0]))
    assert len(split_probe(img, frame).sources) == 2
    assert len(split_probe(img, frame, cfg=ProbeConfig(max_sources=1)).sources) == 1
    r, ndv = np.array([0.37]), np.array([0.41])
    fine = env_brdf(r, ndv, GlossConfig(env_lut_size=64))
    assert np.allclose(fine, env_brdf(r, ndv), atol=0.02) and not np.array_equal(fine, env_brdf(r, ndv))


def test_no_bare_constant_in_the_scene_the_light_or_the_physical_renderer():
    """The scene's, the light stage's and the physical renderer's modules declare no
    tunable number of their own: a module-level UPPER_CASE name bound to a number (or a
    tuple of numbers) is a knob without provenance, unless listed here with the reason
    it is not a knob."""
    import ast
    import pathlib

    import zcomp_cli.light as light_pkg
    import zcomp_cli.renderers.physical as pkg
    import zcomp_cli.scene as scene_pkg

    not_knobs = {
        ("fit", "SUN_SHADING_PER_IRRADIANCE"): "a unit conversion (shading = irradiance / pi)",
        ("fit", "LAMP_SHADING_PER_WATT"): "a unit conversion (W to shading at 1 m)",
        ("sh", "N_COEFFS"): "the order-2 SH basis's size",
        ("sh", "_A_OVER_PI"): "Ramamoorthi and Hanrahan's irradiance factors",
        ("sampling", "GOLDEN_ANGLE"): "a mathematical constant",
        ("raycast", "RAY_CHUNK"): "a memory bound: the results do not depend on it",
        ("raycast", "_FAR"): "Embree's no-hit distance",
        ("raycast", "MIN_THREAD_RAYS"): "a speed bound: the results do not depend on it",
        ("atoms", "_PIXEL_BLOCK"): "a speed bound (the cache): the results do not depend on it",
        ("evidence_maps", "CASTER_VALUE"): "the debug map's encoding",
        ("evidence_maps", "SUPPORT_VALUE"): "the debug map's encoding",
        ("lightparams", "SUN_RADIUS_DEG"): "the Sun's angular radius (physical)",
        ("lightparams", "LAMP_RADIUS_M"): "a household bulb's radius (physical)",
        ("lightparams", "MAX_RADIUS_DEG"): "the widest light drawn as one: the manifest's, the settings' bound",
        ("lightparams", "WHITE"): "a colour multiplier of 1",
        ("stage", "FORMAT"): "the cache's format number",
        ("stage", "KEEP_IN_MEMORY"): "a memory bound: the results do not depend on it",
        ("probe", "KEEP_SPLIT"): "a memory bound: the results do not depend on it",
        ("gloss", "KEEP_PREFILTERED"): "a memory bound: the results do not depend on it",
        ("brdf", "DIELECTRIC_IOR"): "the Principled BSDF's IOR, which the benchmark's objects and Cycles use",
        ("written", "MAX_PITCH_DEG"): "the manifest's range of pitch_deg",
    }

    def numeric(node):
        if isinstance(node, ast.Constant):
            return isinstance(node.value, (int, float)) and not isinstance(node.value, bool)
        if isinstance(node, (ast.Tuple, ast.List)):
            return bool(node.elts) and all(numeric(e) for e in node.elts)
        if isinstance(node, ast.BinOp):
            return numeric(node.left) and numeric(node.right)
        if isinstance(node, ast.UnaryOp):
            return numeric(node.operand)
        return False

    bare = []
    for p in (pkg, light_pkg, scene_pkg):
        for path in sorted(pathlib.Path(p.__file__).parent.glob("*.py")):
            for node in ast.parse(path.read_text()).body:
                targets = node.targets if isinstance(node, ast.Assign) else (
                    [node.target] if isinstance(node, ast.AnnAssign) and node.value is not None else [])
                for t in targets:
                    if (isinstance(t, ast.Name) and t.id.lstrip("_").isupper() and numeric(node.value)
                            and (path.stem, t.id) not in not_knobs):
                        bare.append(f"{path.stem}.{t.id}")
    assert not bare, f"module constants without provenance (move them into a config): {bare}"
