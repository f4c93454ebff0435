"""The ``cycles`` renderer's transport: render one request's scene with Cycles.

Run in a ``blender.runner.BlenderSession`` (``python render_cycles.py -``: one process
serves a worker's every job); never imported by zcomp. The parent
(``zcomp_cli.renderers.cycles``) decides everything in the camera frame and writes the
arrays to an ``.npz``; this script only builds what it is told and renders it.

Item::

    {"id": str, "out": path of the EXR to write, "arrays": path of the .npz,
     "mesh_key": str (the scene mesh's content key: a process keeps the last few built;
                 null: no scene mesh, the object alone), "transparent"?: bool (film),
     "width", "height", "camera": {lens_mm, sensor_width_mm, shift_x, shift_y},
     "border": [x0, y0, x1, y1] (pixels, rows from the top, half-open) -- the window rendered,
     "samples", "seed", "denoise", "max_bounces", "threads", "light_passes": bool (also
     Cycles' diffuse, glossy, emission and environment passes),
     "world": {"image": path of an EXR, "rows": 3x3, "map_resolution"?: int (0: Cycles'
              automatic importance map)} -- the env map, looked up at
              ``rows @ d`` for a camera-frame direction d in Blender's equirectangular layout,
     "lamps": [{"kind": "SUN"|"POINT"|"AREA", "direction" (3,) the way it shines,
                "position"?, "energy", "color", "angle_rad"?, "radius"?, "size"?}],
     "object": null | {"mesh": path, "format": str, "matrix": 4x4} (the object's own file
               and materials) | {"arrays": true, "color", "roughness", "metallic"}
               (vertices ``object_vertices`` and faces ``object_faces`` in the .npz)}

The .npz holds ``vertices`` (V, 3) float32, ``faces`` (F, 3) int32, ``colors`` (V, 3)
linear diffuse colour per vertex.

The camera sits at the world origin with identity rotation: Blender's world frame IS
zcomp's camera frame. Writes ``out`` (a multilayer EXR, pass Combined: linear radiance
of the window, cropped).
"""

from __future__ import annotations

import os
import sys
import time

_T0 = time.monotonic()

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from mathutils import Matrix, Vector  # noqa: E402

from zcomp_cli.blender.runner import serve_job_file  # noqa: E402
from _bpy_common import (add_camera, import_mesh, multilayer_exr_output, node_tree,  # noqa: E402
                         principled_bsdf)  # (beside this script)

SCENE_MESH = "zcomp_scene_mesh"
# scene meshes kept between items, by content key (a job's background and composite
# passes alternate: two per job; more for the scenes a worker's jobs interleave)
KEEP_MESHES = 4
_meshes: dict = {}  # content key -> mesh name, oldest first
# Cycles' light passes written with ``light_passes`` (the job's --aovs)
LIGHT_PASSES = ("use_pass_diffuse_direct", "use_pass_diffuse_indirect", "use_pass_diffuse_color",
                "use_pass_glossy_direct", "use_pass_glossy_indirect", "use_pass_glossy_color",
                "use_pass_emit", "use_pass_environment")


def reset_keeping_scene_meshes() -> None:
    """Remove every object, light, camera, image, world and collection, and every mesh
    and material but the scene meshes kept by content key (``KEEP_MESHES``)."""
    kept = set(_meshes.values())
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o, do_unlink=True)
    for coll in (bpy.data.lights, bpy.data.cameras, bpy.data.images, bpy.data.worlds):
        for d in list(coll):
            coll.remove(d)
    for m in list(bpy.data.meshes):
        if m.name not in kept:
            bpy.data.meshes.remove(m)
    for m in list(bpy.data.materials):
        if m.name != SCENE_MESH + "_mat":
            bpy.data.materials.remove(m)
    for c in list(bpy.data.collections):
        bpy.data.collections.remove(c)


def _scene_material():
    mat = bpy.data.materials.get(SCENE_MESH + "_mat")
    if mat is not None:
        return mat
    mat = bpy.data.materials.new(SCENE_MESH + "_mat")
    nt = node_tree(mat)
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "albedo"
    diff = nt.nodes.new("ShaderNodeBsdfDiffuse")
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(attr.outputs["Color"], diff.inputs["Color"])
    nt.links.new(diff.outputs[0], out.inputs["Surface"])
    return mat


def scene_mesh(arrays, key: str):
    """The background's mesh: per-vertex diffuse colour (``colors``), one material; built
    once per content ``key`` while kept."""
    name = _meshes.get(key)
    if name is not None and name in bpy.data.meshes:
        mesh = bpy.data.meshes[name]
        _meshes[key] = _meshes.pop(key)  # most recently used last
    else:
        V = np.ascontiguousarray(arrays["vertices"], np.float32)
        F = np.ascontiguousarray(arrays["faces"], np.int32)
        mesh = bpy.data.meshes.new(f"{SCENE_MESH}_{key[:16]}")
        mesh.vertices.add(len(V))
        mesh.vertices.foreach_set("co", V.ravel())
        mesh.loops.add(3 * len(F))
        mesh.loops.foreach_set("vertex_index", F.ravel())
        mesh.polygons.add(len(F))
        mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * len(F), 3, dtype=np.int32))
        mesh.polygons.foreach_set("loop_total", np.full(len(F), 3, np.int32))
        mesh.update(calc_edges=True)
        mesh.validate(clean_customdata=False)
        col = mesh.color_attributes.new("albedo", "FLOAT_COLOR", "POINT")
        C = np.ones((len(mesh.vertices), 4), np.float32)
        C[:, :3] = np.asarray(arrays["colors"], np.float32)[: len(mesh.vertices)]
        col.data.foreach_set("color", C.ravel())
        mesh.materials.append(_scene_material())
        _meshes[key] = mesh.name
        while len(_meshes) > KEEP_MESHES:
            old = _meshes.pop(next(iter(_meshes)))
            if old in bpy.data.meshes:
                bpy.data.meshes.remove(bpy.data.meshes[old])
    obj = bpy.data.objects.new(SCENE_MESH, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def world(desc: dict) -> None:
    """The world: the EXR ``desc["image"]`` looked up at ``rows @ d`` (an image made from
    pixels in bpy is not what Cycles reads: it reloads generated images)."""
    rows = desc["rows"]
    im = bpy.data.images.load(desc["image"], check_existing=False)
    wd = bpy.data.worlds.new("zcomp_world")
    nt = node_tree(wd)
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    coord = nt.nodes.new("ShaderNodeTexCoord")
    comb = nt.nodes.new("ShaderNodeCombineXYZ")
    for k, axis in enumerate("XYZ"):
        dot = nt.nodes.new("ShaderNodeVectorMath")
        dot.operation = "DOT_PRODUCT"
        dot.inputs[1].default_value = tuple(float(x) for x in rows[k])
        # "Generated" of a world is the view direction in world (= camera) space.
        nt.links.new(coord.outputs["Generated"], dot.inputs[0])
        nt.links.new(dot.outputs["Value"], comb.inputs[axis])
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = im
    env.interpolation = "Linear"
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = 1.0
    out = nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(comb.outputs["Vector"], env.inputs["Vector"])
    nt.links.new(env.outputs["Color"], bg.inputs["Color"])
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    res = int(desc.get("map_resolution") or 0)
    if res > 0:  # the importance map's resolution (else Cycles' automatic: the image's)
        wd.cycles.sampling_method = "MANUAL"
        wd.cycles.sample_map_resolution = res
    bpy.context.scene.world = wd


def add_lamp(i: int, desc: dict) -> None:
    kind = desc["kind"]
    light = bpy.data.lights.new(f"lamp_{i}", type=kind)
    light.energy = float(desc["energy"])
    light.color = tuple(desc["color"])
    if not desc.get("shadow", True) and hasattr(light, "use_shadow"):
        light.use_shadow = False  # the light's direction is not fixed: it casts no shadow
    if kind == "SUN":
        light.angle = float(desc["angle_rad"])
    elif kind == "POINT":
        light.shadow_soft_size = float(desc["radius"])
    else:
        light.shape = "DISK"
        light.size = float(desc["size"])
    obj = bpy.data.objects.new(f"lamp_{i}", light)
    # A Blender light shines along its local -Z.
    obj.rotation_mode = "QUATERNION"
    obj.rotation_quaternion = Vector(desc["direction"]).to_track_quat("-Z", "Y")
    if "position" in desc:
        obj.location = tuple(desc["position"])
    bpy.context.scene.collection.objects.link(obj)


def add_object(desc: dict, arrays) -> None:
    if desc.get("arrays"):
        V = np.ascontiguousarray(arrays["object_vertices"], np.float32)
        F = np.ascontiguousarray(arrays["object_faces"], np.int32)
        mesh = bpy.data.meshes.new("zcomp_object")
        mesh.from_pydata(V.tolist(), [], F.tolist())
        mesh.update()
        mat = bpy.data.materials.new("zcomp_object_mat")
        bsdf = principled_bsdf(mat)
        bsdf.inputs["Base Color"].default_value = (*desc["color"], 1.0)
        bsdf.inputs["Roughness"].default_value = float(desc["roughness"])
        bsdf.inputs["Metallic"].default_value = float(desc["metallic"])
        mesh.materials.append(mat)
        obj = bpy.data.objects.new("zcomp_object", mesh)
        bpy.context.scene.collection.objects.link(obj)
        return
    root, _ = import_mesh(desc["mesh"], desc["format"], "zcomp_object")
    root.matrix_world = Matrix(desc["matrix"])


def setup_render(item: dict) -> None:
    scene = bpy.context.scene
    r = scene.render
    r.engine = "CYCLES"
    W, H = int(item["width"]), int(item["height"])
    r.resolution_x, r.resolution_y = W, H
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.film_transparent = bool(item.get("transparent"))
    threads = int(item.get("threads", 0))
    r.threads_mode = "FIXED" if threads > 0 else "AUTO"
    if threads > 0:
        r.threads = threads
    x0, y0, x1, y1 = (int(v) for v in item["border"])
    r.use_border = True
    r.use_crop_to_border = True
    r.border_min_x, r.border_max_x = x0 / W, x1 / W
    r.border_min_y, r.border_max_y = 1.0 - y1 / H, 1.0 - y0 / H
    c = scene.cycles
    c.device = "CPU"
    c.use_adaptive_sampling = False  # a fixed sample count keeps the two passes' noise aligned
    c.seed = int(item["seed"])
    c.samples = int(item["samples"])
    c.max_bounces = int(item["max_bounces"])
    c.caustics_reflective = c.caustics_refractive = False
    c.filter_width = 1.5
    c.use_denoising = bool(item["denoise"])
    if item["denoise"]:
        c.denoiser = "OPENIMAGEDENOISE"
    scene.view_settings.view_transform = "Standard"
    clip_start, clip_end = item.get("clip") or (1e-3, 1e4)  # (the renderer's clip_range)
    cam = add_camera(scene, item["camera"], clip_end=float(clip_end))
    cam.data.clip_start = float(clip_start)
    vl = scene.view_layers[0]
    vl.use_pass_combined = True
    light_passes = bool(item.get("light_passes"))
    for p in LIGHT_PASSES:
        setattr(vl, p, light_passes)
    multilayer_exr_output(r, codec="NONE")  # a scratch file, read once


def process(item: dict, common: dict) -> dict:
    t = time.monotonic()
    reset_keeping_scene_meshes()
    arrays = np.load(item["arrays"])
    setup_render(item)
    if item.get("mesh_key"):
        scene_mesh(arrays, str(item["mesh_key"]))
    world(item["world"])
    for i, lp in enumerate(item.get("lamps", [])):
        add_lamp(i, lp)
    if item.get("object"):
        add_object(item["object"], arrays)
    built = time.monotonic() - t
    out = item["out"]
    os.makedirs(os.path.dirname(out), exist_ok=True)
    bpy.context.scene.render.filepath = out
    t = time.monotonic()
    bpy.ops.render.render(write_still=True)
    return {"file": out, "build_s": built, "render_s": time.monotonic() - t}


def main(job_path: str) -> int:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return serve_job_file(job_path, process, started=_T0, blender_version=bpy.app.version_string)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
