"""The scene's own specular layer (scene.brdf.dielectric_offset, light.atoms.specular_roughness):
a floor's sheen, brighter toward grazing views, is not read as light."""

import numpy as np
import pytest

from zcomp_cli.maps import SceneMaps
from zcomp_cli.renderers.base import RenderRequest
from zcomp_cli.renderers.physical import PhysicalRenderer
from zcomp_cli.scene.brdf import DIELECTRIC_F0, dielectric_offset
from zcomp_cli.scene.lightmodel import LightModel, Sky
from zcomp_cli.testing import floor_scene, light_context


def test_dielectric_offset_known_values():
    mu = np.array([1.0, 0.7, 0.5, 0.3, 0.15, 0.05])
    for r in (0.2, 0.5, 0.9):
        g = dielectric_offset(mu, r, np.zeros((6, 3)))
        assert g.shape == (6, 3) and np.all(np.diff(g[:, 0]) > 0)  # brighter toward grazing
        assert g[0, 0] == pytest.approx(DIELECTRIC_F0, abs=0.025)  # facing: about the dielectric's F0
    # smoother layers rise faster toward grazing
    assert dielectric_offset([0.05], 0.2, [[0, 0, 0]])[0, 0] > 2 * dielectric_offset([0.05], 0.9, [[0, 0, 0]])[0, 0]
    # what the layer takes from the diffuse: nothing added to a white albedo, R (1 - a) to others
    a = np.array([[1.0, 0.5, 0.0]])
    g = dielectric_offset([0.3], 0.5, a)
    assert g[0, 0] == 0.0 and g[0, 1] == pytest.approx(0.5 * g[0, 2])


def test_dielectric_offset_extremes_stay_finite():
    mu = np.array([np.nan, np.inf, -np.inf, -0.5, 2.0, 0.0])
    a = np.array([[np.nan] * 3, [np.inf] * 3, [-1.0] * 3, [0.5] * 3, [2.0] * 3, [0.2] * 3])
    for r in (np.nan, -1.0, 0.0, 1.0, 7.0):
        g = dielectric_offset(mu, r, a)
        assert np.all(np.isfinite(g)) and np.all(g >= 0) and np.all(g <= 1)


def test_the_model_carries_the_layer_and_gives_it_back():
    sky = Sky(radiance_sh=np.zeros((9, 3)), ground=np.zeros(3), up=[0, 1, 0])
    pts = np.array([[0.0, -1.0, -2.0], [0.0, -1.0, -20.0]])  # a floor near, and far (grazing)
    nrm = np.array([[0.0, 1.0, 0.0]] * 2)
    alb = np.full((2, 3), 0.3)
    none = LightModel(sky=sky)
    assert np.all(none.albedo_offset(pts, nrm, alb) == 0)  # no layer: NaN roughness
    m = LightModel(sky=sky, specular_roughness=0.5)
    g = m.albedo_offset(pts, nrm, alb)
    assert 0 < g[0, 0] < g[1, 0]
    back = LightModel.from_dict(m.to_dict())
    assert back.specular_roughness == 0.5
    assert np.isnan(LightModel.from_dict(none.to_dict()).specular_roughness)
    assert m.to_info()["specular_roughness"] == 0.5 and none.to_info()["specular_roughness"] is None


def _sheen_plate(roughness):
    """A floor under a sun and a sky (floor_scene's shading, grey) whose image has a
    dielectric specular layer: image / albedo = shading (albedo + offset) / albedo."""
    s = floor_scene(120, 90, light_dir=(0.3, 1.0, 0.4), ambient=0.3, pitch_deg=-12.0, camera_height=1.0)
    pts = s.camera.unproject(s.depth).reshape(-1, 3).astype(np.float64)
    n = s.normals.reshape(-1, 3).astype(np.float64)
    ndv = -np.sum(n * pts, 1) / np.maximum(np.linalg.norm(pts, axis=1), 1e-12)
    a = s.albedo.reshape(-1, 3).astype(np.float64)
    g = dielectric_offset(ndv, roughness, a).reshape(s.albedo.shape)
    shading = (s.shading * (s.albedo + g) / np.maximum(s.albedo, 1e-6)).astype(np.float32)
    return s, shading


@pytest.mark.parametrize("roughness", [0.3, 0.6])
def test_a_floors_sheen_is_not_read_as_light(roughness, monkeypatch):
    """The light given (a sun), the exposure free: the fit's exposure is the photograph's
    whether or not its floor has a sheen, and the layer's roughness is read back. Read
    as light (the layer left out), the sheen raised the exposure by its mean share."""
    from zcomp_cli.light import atoms

    s, shading = _sheen_plate(roughness)
    known = s.depth > 0
    ctx = light_context({"direction": s.light_dir_cam.tolist(), "irradiance": 2.0})
    maps = SceneMaps(s.depth, s.normals, s.albedo)
    m = PhysicalRenderer().light(RenderRequest(maps, shading, known, s.camera, light=ctx))
    with_layer = m.fit.exposure
    monkeypatch.setattr(atoms, "specular_roughness", lambda *a, **k: float("nan"))
    without = PhysicalRenderer().light(RenderRequest(maps, shading, known, s.camera, light=ctx)).fit.exposure
    # the truth: the plate without its sheen, fitted as a Lambertian scene (the model exact)
    truth = PhysicalRenderer().light(RenderRequest(maps, s.shading, known, s.camera, light=ctx)).fit.exposure
    print(f"roughness {roughness}: exposure / truth {with_layer / truth:.3f} with the layer, {without / truth:.3f} "
          f"without; chosen roughness {m.specular_roughness}")
    assert m.specular_roughness == pytest.approx(roughness, abs=0.15)
    assert abs(np.log(with_layer / truth)) < 0.5 * abs(np.log(without / truth))
    assert abs(np.log(with_layer / truth)) < 0.05


def test_cycles_scene_draws_the_layer_as_the_camera_sees_it():
    """The path tracer's background mesh carries the same offset as the fit read: each
    vertex's colour is its albedo plus the layer's offset at its view angle, more on the
    far floor (grazing) than the near; none without a layer."""
    from zcomp_cli.renderers.cycles import scene as sc
    from zcomp_cli.scene.depthmesh import has_geometry

    s = floor_scene(64, 48, pitch_deg=-12.0, camera_height=1.0)
    valid = has_geometry(s.depth.astype(np.float64), s.normals.astype(np.float64))
    sky = Sky(radiance_sh=np.zeros((9, 3)), ground=np.zeros(3), up=s.up_cam)
    plain = sc.scene_arrays(s.depth, s.normals, s.albedo, valid, s.camera, LightModel(sky=sky))
    sheen = sc.scene_arrays(s.depth, s.normals, s.albedo, valid, s.camera,
                            LightModel(sky=sky, specular_roughness=0.4))
    assert np.array_equal(plain["vertices"], sheen["vertices"])
    extra = (sheen["colors"] - plain["colors"]).mean(1)
    dist = np.linalg.norm(plain["vertices"], axis=1)
    near, far = dist < np.percentile(dist, 25), dist > np.percentile(dist, 75)
    assert np.all(extra >= -1e-6) and extra[near].mean() > 0.01
    assert extra[far].mean() > 1.5 * extra[near].mean()
