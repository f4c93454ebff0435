"""The manifest light's conventions against Blender itself (DESIGN.md section 8: "test
any convention against Blender itself, and do not trust a formula alone"): Cycles'
units for the world, a sun and the lamps; and a probe under Blender's world mapping,
whose shadow zcomp must cast the same way.

Blender runs in a subprocess (as zcomp's own scripts do): a small bpy script written by
the test, rendering 32 x 32 or 96 x 72 pixels with Cycles on the CPU.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytestmark = pytest.mark.blender

_COMMON = r'''
import bpy, json, math, sys
import numpy as np

def reset(samples, bounces, w, h):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = samples
    sc.cycles.use_denoising = False
    sc.cycles.max_bounces = bounces
    sc.cycles.seed = 0
    sc.render.resolution_x, sc.render.resolution_y = w, h
    sc.render.resolution_percentage = 100
    sc.view_settings.view_transform = "Standard"
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"
    return sc

def world(sc, strength, image=None):
    wd = bpy.data.worlds.new("w")
    sc.world = wd
    wd.use_nodes = True
    nt = wd.node_tree
    bg = nt.nodes["Background"]
    bg.inputs["Strength"].default_value = strength
    bg.inputs["Color"].default_value = (1, 1, 1, 1)
    if image:
        env = nt.nodes.new("ShaderNodeTexEnvironment")
        env.image = bpy.data.images.load(image)
        nt.links.new(env.outputs["Color"], bg.inputs["Color"])

def white_floor(size=200.0):
    bpy.ops.mesh.primitive_plane_add(size=size)
    m = bpy.data.materials.new("m")
    m.use_nodes = True
    p = m.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (1, 1, 1, 1)
    p.inputs["Roughness"].default_value = 1.0
    for nm in ("Specular IOR Level", "Specular"):
        if nm in p.inputs:
            p.inputs[nm].default_value = 0.0
    bpy.context.object.data.materials.append(m)
    return m

def camera(sc, loc, rot_deg, fov_deg=50.0):
    cam = bpy.data.cameras.new("c")
    cam.sensor_fit = "HORIZONTAL"
    cam.angle = math.radians(fov_deg)
    co = bpy.data.objects.new("c", cam)
    sc.collection.objects.link(co)
    co.location = loc
    co.rotation_euler = tuple(math.radians(a) for a in rot_deg)
    sc.camera = co

def render(sc, path):
    sc.render.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path)
    w, h = img.size
    return np.array(img.pixels[:], dtype=np.float32).reshape(h, w, 4)[::-1, :, :3]
'''


def _run(tmp_path, body: str) -> dict:
    script = tmp_path / "scene.py"
    out = tmp_path / "out.json"
    script.write_text(_COMMON + textwrap.dedent(body).replace("OUT_JSON", repr(str(out)))
                      .replace("TMP", repr(str(tmp_path))))
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return json.loads(out.read_text())


def test_cycles_light_units_are_zcomps(tmp_path):
    """A white floor seen from above: a uniform world of radiance 1, a sun of strength
    1 at the zenith, a point lamp and an area lamp of 100 W two metres up give what
    ``known_light``'s units say."""
    res = _run(tmp_path, r'''
        out = {}
        for kind in ("world", "sun", "point", "area"):
            sc = reset(64, 1 if kind == "world" else 0, 32, 32)
            world(sc, 1.0 if kind == "world" else 0.0)
            white_floor()
            camera(sc, (0, 0, 1), (0, 0, 0))
            if kind == "sun":
                l = bpy.data.lights.new("s", "SUN"); l.energy = 1.0; l.angle = 0.0
                o = bpy.data.objects.new("s", l); sc.collection.objects.link(o)
            elif kind == "point":
                l = bpy.data.lights.new("p", "POINT"); l.energy = 100.0; l.shadow_soft_size = 0.0
                o = bpy.data.objects.new("p", l); sc.collection.objects.link(o); o.location = (0, 0, 2)
            elif kind == "area":
                l = bpy.data.lights.new("a", "AREA"); l.energy = 100.0; l.shape = "SQUARE"; l.size = 0.1
                o = bpy.data.objects.new("a", l); sc.collection.objects.link(o); o.location = (0, 0, 2)
            a = render(sc, TMP + f"/{kind}.exr")
            out[kind] = float(a[12:20, 12:20, 0].mean())
        json.dump(out, open(OUT_JSON, "w"))
    ''')
    from zcomp_cli.light.fit import LAMP_SHADING_PER_WATT, SUN_SHADING_PER_IRRADIANCE

    assert res["world"] == pytest.approx(1.0, rel=0.03)
    assert res["sun"] == pytest.approx(SUN_SHADING_PER_IRRADIANCE, rel=0.03)
    assert res["point"] == pytest.approx(100.0 * LAMP_SHADING_PER_WATT / 4.0, rel=0.03)  # r = 2 m
    # a one-sided panel: four times the sphere's on its axis (lightmodel.Lamp's profile)
    assert res["area"] == pytest.approx(4.0 * 100.0 * LAMP_SHADING_PER_WATT / 4.0, rel=0.05)


def test_a_probe_under_blenders_world_mapping_casts_zcomps_shadow(tmp_path):
    """A probe holding a small sun lights a floor and a thin pole in Cycles (Blender's
    own world mapping, the camera turned and pitched); zcomp, given the same probe with
    ``convention: blender`` and the camera's Z rotation, puts the sun where Blender put
    it, and the pole's shadow runs the same way within 3 degrees."""
    from zcomp_cli.camera import Camera
    from zcomp_cli.imageio import write_exr
    from zcomp_cli.maps import SceneMaps
    from zcomp_cli.renderers.base import RenderRequest
    from zcomp_cli.renderers.physical import PhysicalRenderer
    from zcomp_cli.testing import light_context
    from zcomp_cli.worldframe import ground_frame, up_from_pitch_roll

    W, H, fov = 96, 72, 60.0
    psi, pitch, height = 35.0, -35.0, 1.6  # the camera's Z rotation; looking down 35 deg
    sun_phi, sun_el = 200.0, 40.0  # Blender world azimuth atan2(y, x) and elevation, degrees
    # the probe: a 2-deg sun over a dim sky, in Blender's equirectangular layout
    ph, pw = 128, 256
    v, u = np.mgrid[0:ph, 0:pw]
    phi = (0.5 - (u + 0.5) / pw) * 2 * math.pi
    el = (0.5 - (v + 0.5) / ph) * math.pi
    d = np.stack([np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.sin(el)], -1)
    s = np.array([math.cos(math.radians(sun_el)) * math.cos(math.radians(sun_phi)),
                  math.cos(math.radians(sun_el)) * math.sin(math.radians(sun_phi)), math.sin(math.radians(sun_el))])
    img = np.full((ph, pw, 3), 0.02, np.float32)
    img[d @ s > math.cos(math.radians(2.0))] = 2000.0
    probe = tmp_path / "probe.exr"
    write_exr(probe, img)
    # the pole stands 3 m ahead of the camera on the ground
    fwd = np.array([-math.sin(math.radians(psi)), math.cos(math.radians(psi)), 0.0])
    base = 3.0 * fwd
    res = _run(tmp_path, rf'''
        sc = reset(32, 2, {W}, {H})
        world(sc, 1.0, {str(probe)!r})
        white_floor()
        bpy.ops.mesh.primitive_cylinder_add(radius=0.06, depth=1.0, location=({base[0]}, {base[1]}, 0.5))
        camera(sc, (0, 0, {height}), ({90.0 + pitch}, 0, {psi}), fov_deg={fov})
        a = render(sc, TMP + "/probe_scene.exr")
        np.save(TMP + "/img.npy", a)
        json.dump({{"ok": True}}, open(OUT_JSON, "w"))
    ''')
    assert res["ok"]
    a = np.load(tmp_path / "img.npy")
    cam = Camera.from_fov(fov, W, H)
    up = up_from_pitch_roll(pitch, 0.0)
    # the floor's exact maps in the camera frame
    rays = cam.pixel_rays()
    t = -height / (rays @ up)
    depth = np.where(t > 0, t, 0.0).astype(np.float32)
    normals = np.where(depth[..., None] > 0, up, 0.0).astype(np.float32)
    albedo = np.repeat(np.where(depth[..., None] > 0, 0.8, 0.0), 3, -1).astype(np.float32)
    shading = np.repeat(np.where(depth[..., None] > 0, 1.0, 0.0), 3, -1).astype(np.float32)
    req = RenderRequest(SceneMaps(depth, normals, albedo), shading, depth > 0, cam,
                        light=light_context({"type": "probe", "hdr": str(probe), "convention": "blender",
                                             "rotation_deg": psi}, pitch_deg=pitch))
    model = PhysicalRenderer().light(req)
    l = model.suns[0].direction
    # the true sun in the camera frame: Blender world -> camera (right, up, forward)
    right_w = np.cross(fwd, [0, 0, 1.0])
    r_c, u_c, f_c = ground_frame(up)
    l_true = (s @ right_w) * r_c + s[2] * u_c + (s @ fwd) * f_c
    assert math.degrees(math.acos(np.clip(l @ l_true, -1, 1))) < 3.0
    # Blender's shadow of the pole: the dark floor pixels beyond its base, on the ground
    lum = a @ np.array([0.299, 0.587, 0.114])
    floor = depth > 0
    dark = floor & (lum < 0.85 * np.median(lum[floor]))
    P = cam.unproject(depth)
    base_c = 3.0 * f_c - height * u_c  # the pole's base, camera frame
    # the pole's own pixels stand above its base in the image: not its shadow
    (bx, by), _ = cam.project(base_c[None])[0][0], None
    rows, cols = np.mgrid[0:H, 0:W]
    dark &= ~((np.abs(cols + 0.5 - bx) < 4) & (rows + 0.5 < by))
    rel = P[dark] - base_c
    rel = rel - (rel @ u_c)[:, None] * u_c
    far = np.linalg.norm(rel, axis=1) > 0.1
    assert far.sum() > 10
    seen = rel[far].mean(0)
    seen /= np.linalg.norm(seen)
    want = -(l - (l @ u_c) * u_c)
    want /= np.linalg.norm(want)
    assert math.degrees(math.acos(np.clip(seen @ want, -1, 1))) < 3.0
