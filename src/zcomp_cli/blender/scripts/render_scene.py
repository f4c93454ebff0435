"""Render whole scenes (HDR-lit floor, walls, boxes, lamps, optionally an inserted object)
with Cycles, one Blender process per batch.

Run by ``zcomp_cli.blender.runner`` as ``python render_scene.py JOB.json``; never
imported by zcomp. The parent (``zcomp_cli.benchsuite``) decides all geometry in the
camera frame and converts the raw passes with tested numpy functions; this script only
builds what it is told, renders, and writes multilayer EXRs (no compositor: bpy 5 has
no ``scene.node_tree``).

Job file::

    {"common": {"threads": int (0 = auto)},
     "items": [{"id": str, "out_dir": path, "samples": int, "seed": int,
                "denoise": bool, "max_bounces": int,
                "scene": {"width", "height", "camera": {lens_mm, sensor_width_mm, shift_x,
                          shift_y}, "hdr": name or path, "hdr_strength",
                          "hdr_euler_xyz": [ax, ay, az] (camera -> env map directions),
                          "meshes": [{name, vertices, faces, uv, material}],
                          "lamps": [{kind, direction, strength, angle_deg, size,
                                     color, position?}]},
                "object": null | {"mesh": path, "format": "gltf|obj|ply|stl",
                                  "mesh_to_camera": 4x4}}, ...]}

The camera sits at the world origin with identity rotation: Blender's world frame IS
zcomp's camera frame (x right, y up, looking along -z).

Two renders per item, written to ``out_dir``:

* ``beauty.exr``: ``samples`` samples with the item's seed (same seed for a background
  and its ground truth, so their noise agrees away from the object), optional
  denoising -> passes Combined (linear radiance), the AOV ``albedo`` (Principled
  base colour) and Diffuse Color;
* ``geometry.exr``: 1 sample through each pixel centre (filter width 0.01), no bounces
  -> exact Depth (z-depth, 1e10 on empty pixels) and Normal (world = camera frame).
"""

from __future__ import annotations

import math
import os
import sys
import time

_T0 = time.monotonic()

import bpy  # noqa: E402
from mathutils import Matrix, Vector  # noqa: E402

from zcomp_cli.blender.runner import serve_job_file  # noqa: E402
from _bpy_common import (add_camera, import_mesh, multilayer_exr_output, node_tree,  # noqa: E402
                         principled_bsdf)  # (beside this script)



def reset() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def hdr_path(name: str) -> str:
    """A bundled studio-light HDR by name, or a path as given."""
    if os.path.sep in name or name.lower().endswith((".exr", ".hdr")):
        path = name
    else:
        folder = bpy.utils.system_resource("DATAFILES", path="studiolights/world")
        path = os.path.join(folder, f"{name}.exr")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"HDR environment map not found: {path}")
    return path


def setup_world(scene_desc: dict) -> None:
    world = bpy.data.worlds.new("zcomp_world")
    nt = node_tree(world)
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    coord = nt.nodes.new("ShaderNodeTexCoord")
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.vector_type = "VECTOR"
    mapping.inputs["Rotation"].default_value = tuple(scene_desc["hdr_euler_xyz"])
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(hdr_path(scene_desc["hdr"]), check_existing=True)
    env.interpolation = "Linear"
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = float(scene_desc["hdr_strength"])
    out = nt.nodes.new("ShaderNodeOutputWorld")
    # "Generated" of a world is the view direction in world (= camera) space.
    nt.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
    nt.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    nt.links.new(env.outputs["Color"], bg.inputs["Color"])
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    bpy.context.scene.world = world


def make_material(name: str, desc: dict):
    mat = bpy.data.materials.new(name)
    bsdf = principled_bsdf(mat)
    nt = mat.node_tree
    bsdf.inputs["Base Color"].default_value = (*desc["color"], 1.0)
    bsdf.inputs["Roughness"].default_value = float(desc["roughness"])
    bsdf.inputs["Metallic"].default_value = 0.0
    if desc.get("checker_color") is not None:
        coord = nt.nodes.new("ShaderNodeTexCoord")
        checker = nt.nodes.new("ShaderNodeTexChecker")
        checker.inputs["Color1"].default_value = (*desc["color"], 1.0)
        checker.inputs["Color2"].default_value = (*desc["checker_color"], 1.0)
        # UVs are metres along the surface; the checker's squares are 1/scale wide.
        checker.inputs["Scale"].default_value = 1.0 / float(desc["checker_size"])
        nt.links.new(coord.outputs["UV"], checker.inputs["Vector"])
        nt.links.new(checker.outputs["Color"], bsdf.inputs["Base Color"])
    _albedo_aov(nt, bsdf)
    return mat


def _albedo_aov(nt, bsdf) -> None:
    """Write the Principled base colour to the ``albedo`` AOV: the same definition of
    albedo as the object intrinsics (the DiffCol pass would also fold in the specular
    layer's Fresnel loss, a few percent darker)."""
    aov = nt.nodes.new("ShaderNodeOutputAOV")
    aov.aov_name = "albedo"
    base = bsdf.inputs["Base Color"]
    if base.is_linked:
        nt.links.new(base.links[0].from_socket, aov.inputs["Color"])
    else:
        aov.inputs["Color"].default_value = tuple(base.default_value)


def add_albedo_aovs() -> None:
    """Give every material of an imported object the ``albedo`` AOV (its Principled
    base colour; Blender's grey 0.8 default for a mesh without material)."""
    for mat in bpy.data.materials:
        nt = mat.node_tree
        if nt is None or any(n.type == "OUTPUT_AOV" for n in nt.nodes):
            continue
        bsdf = next((n for n in nt.nodes if n.type == "BSDF_PRINCIPLED"), None)
        if bsdf is not None:
            _albedo_aov(nt, bsdf)


def add_mesh(desc: dict) -> None:
    mesh = bpy.data.meshes.new(desc["name"])
    mesh.from_pydata([tuple(v) for v in desc["vertices"]], [], [tuple(f) for f in desc["faces"]])
    mesh.update()
    uv_layer = mesh.uv_layers.new(name="UVMap")
    uvs = desc["uv"]
    for loop in mesh.loops:
        uv_layer.data[loop.index].uv = tuple(uvs[loop.vertex_index])
    mesh.materials.append(make_material(desc["name"] + "_mat", desc["material"]))
    obj = bpy.data.objects.new(desc["name"], mesh)
    bpy.context.scene.collection.objects.link(obj)


def add_lamp(i: int, desc: dict) -> None:
    kind = desc["kind"]
    light = bpy.data.lights.new(f"lamp_{i}", type=kind)
    light.energy = float(desc["strength"])
    light.color = tuple(desc["color"])
    if kind == "SUN":
        light.angle = math.radians(float(desc["angle_deg"]))
    else:
        light.shape = "SQUARE"
        light.size = float(desc["size"])
    obj = bpy.data.objects.new(f"lamp_{i}", light)
    # A Blender light shines along its local -Z.
    quat = Vector(desc["direction"]).to_track_quat("-Z", "Y")
    obj.rotation_mode = "QUATERNION"
    obj.rotation_quaternion = quat
    if "position" in desc:
        obj.location = tuple(desc["position"])
    bpy.context.scene.collection.objects.link(obj)


def add_object(desc: dict) -> None:
    root, _ = import_mesh(desc["mesh"], desc["format"], "zcomp_object")
    root.matrix_world = Matrix(desc["mesh_to_camera"])


def setup_render(item: dict, common: dict) -> None:
    scene = bpy.context.scene
    desc = item["scene"]
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y = int(desc["width"]), int(desc["height"])
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.film_transparent = False
    threads = int(common.get("threads", 0))
    if threads > 0:
        r.threads_mode = "FIXED"
        r.threads = threads
    c = scene.cycles
    c.device = "CPU"
    c.use_adaptive_sampling = False  # a fixed sample count keeps bg and GT noise aligned
    c.seed = int(item.get("seed", 0))
    c.max_bounces = int(item.get("max_bounces", 8))
    c.caustics_reflective = c.caustics_refractive = False
    scene.view_settings.view_transform = "Standard"

    cam_desc = desc["camera"]
    add_camera(scene, cam_desc, clip_end=1e4)

    vl = scene.view_layers[0]
    vl.use_pass_combined = True
    vl.use_pass_z = True
    vl.use_pass_normal = True
    vl.use_pass_diffuse_color = True
    aov = vl.aovs.add()
    aov.name = "albedo"
    aov.type = "COLOR"

    multilayer_exr_output(r)


def render_to(path: str, *, samples: int, filter_width: float, denoise: bool, max_bounces: int) -> None:
    scene = bpy.context.scene
    c = scene.cycles
    c.samples = samples
    c.filter_width = filter_width
    c.use_denoising = bool(denoise)
    if denoise:
        c.denoiser = "OPENIMAGEDENOISE"
    c.max_bounces = max_bounces
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)


def process(item: dict, common: dict) -> dict:
    reset()
    setup_render(item, common)
    desc = item["scene"]
    setup_world(desc)
    for m in desc["meshes"]:
        add_mesh(m)
    for i, lp in enumerate(desc.get("lamps", [])):
        add_lamp(i, lp)
    if item.get("object"):
        add_object(item["object"])
        add_albedo_aovs()
    out = item["out_dir"].rstrip("/")
    os.makedirs(out, exist_ok=True)
    files = {"beauty": f"{out}/beauty.exr", "geometry": f"{out}/geometry.exr"}
    render_to(files["beauty"], samples=int(item.get("samples", 16)), filter_width=1.5,
              denoise=bool(item.get("denoise", False)), max_bounces=int(item.get("max_bounces", 8)))
    # One sample through the pixel centre: one surface point per pixel, so depth is
    # never averaged across a silhouette.
    render_to(files["geometry"], samples=1, filter_width=0.01, denoise=False, max_bounces=0)
    return {"files": files}


def main(job_path: str) -> int:
    return serve_job_file(job_path, process, started=_T0, blender_version=bpy.app.version_string)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
