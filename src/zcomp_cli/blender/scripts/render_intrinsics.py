"""Render object intrinsics passes with Cycles, one Blender process per batch.

Run by ``zcomp_cli.blender.runner`` as ``python render_intrinsics.py JOB.json``; never
imported by zcomp. Everything geometric is decided by the parent process
(``zcomp_cli.blender.intrinsics``): this script only places what it is told, renders,
and writes raw multilayer EXRs. The parent converts them (world normals, 1e10 depth,
premultiplied AOVs) with tested numpy functions.

Job file::

    {"common": {"samples": 16},
     "items": [{"id": str, "mesh": path, "format": "obj|gltf|ply|stl",
                "mesh_to_camera": 4x4, "footprint_to_camera": 4x4,
                "K": 3x3, "width": int, "height": int, "work_dir": path}, ...]}

Scene layout: the camera sits at the world origin with identity rotation, so Blender's
world frame *is* zcomp's camera frame (x right, y up, looking along -z). Every mesh is
imported so that Blender holds its raw file coordinates (Y-up, as zcomp reads meshes),
then parented to an empty carrying ``mesh_to_camera``.

Three renders per item, written to ``work_dir``:

* ``appearance.exr``: ``samples`` samples, default pixel filter -> anti-aliased alpha
  and the AOVs ``albedo`` (Principled base colour), ``roughness``, ``metallic``
  (premultiplied by coverage, as every film pass is);
* ``geometry.exr``: 1 sample through the pixel centre (filter width 0.01) -> exact
  z-depth and normals of the surface seen through each pixel centre. (Cycles' Z pass
  is not a coverage-weighted average: with several samples it holds a single sample's
  depth from anywhere in the filter footprint -- measured at 8 samples, the median
  silhouette pixel with alpha in (0.05, 0.95) reads the empty value 1e10 -- so depth
  cannot come from the anti-aliased render);
* ``footprint.exr``: the same, with the mesh flattened onto its support plane
  (``footprint_to_camera``) -> footprint z-depth.
"""

from __future__ import annotations

import sys
import time

_T0 = time.monotonic()

import bpy  # noqa: E402
from mathutils import Matrix  # noqa: E402

from zcomp_cli.blender.runner import serve_job_file  # noqa: E402
from _bpy_common import add_camera, import_mesh  # noqa: E402  (beside this script)

AOVS = (("albedo", "COLOR"), ("roughness", "VALUE"), ("metallic", "VALUE"))


def reset_scene() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _find_principled(nt):
    for n in nt.nodes:
        if n.type == "BSDF_PRINCIPLED":
            return n
    return None


def _socket_source(sock):
    """The output socket feeding ``sock``, or None when it is unlinked."""
    return sock.links[0].from_socket if sock.is_linked else None


def _add_aov(nt, name: str, source, default) -> None:
    node = nt.nodes.new("ShaderNodeOutputAOV")
    node.aov_name = name
    target = node.inputs["Color"] if isinstance(default, tuple) else node.inputs["Value"]
    if source is not None:
        nt.links.new(source, target)
    else:
        target.default_value = default


def _default_material(mesh) -> "bpy.types.Material":
    """A Principled material for a mesh without one: its first colour attribute
    (vertex colours) as base colour if it has one, else Blender's grey 0.8."""
    mat = bpy.data.materials.new("zcomp_default")
    nt = mat.node_tree  # Blender 5 materials always have a node tree
    bsdf = _find_principled(nt)
    if bsdf is None:
        bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
        out = next(n for n in nt.nodes if n.type == "OUTPUT_MATERIAL")
        nt.links.new(bsdf.outputs[0], out.inputs["Surface"])
    if len(mesh.color_attributes):
        attr = nt.nodes.new("ShaderNodeVertexColor")
        attr.layer_name = mesh.color_attributes[0].name
        nt.links.new(attr.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def setup_materials(objects) -> dict:
    """Add AOV outputs (base colour, roughness, metallic) to every material in use.
    Returns which optional maps carry information (non-default values or textures)."""
    flags = {"roughness": False, "metallic": False}
    done = set()
    for o in objects:
        if len(o.material_slots) == 0 or all(s.material is None for s in o.material_slots):
            o.data.materials.clear()
            o.data.materials.append(_default_material(o.data))
        for slot in o.material_slots:
            mat = slot.material
            if mat is None:
                slot.material = mat = _default_material(o.data)
            if mat.name in done:
                continue
            done.add(mat.name)
            nt = mat.node_tree
            if nt is None:  # legacy material without nodes: nothing to read but its colour
                mat.use_nodes = True
                nt = mat.node_tree
            bsdf = _find_principled(nt)
            if bsdf is not None:
                base = bsdf.inputs["Base Color"]
                _add_aov(nt, "albedo", _socket_source(base), tuple(base.default_value))
                for name, default in (("roughness", 0.5), ("metallic", 0.0)):
                    sock = bsdf.inputs[name.capitalize()]
                    src = _socket_source(sock)
                    _add_aov(nt, name, src, float(sock.default_value))
                    if src is not None or abs(float(sock.default_value) - default) > 1e-6:
                        flags[name] = True
            else:
                # Not a Principled material: the first colour input of any shader node,
                # else the viewport colour, is the best guess at an albedo.
                src, default = None, tuple(mat.diffuse_color)
                for n in nt.nodes:
                    sock = n.inputs.get("Color") if hasattr(n, "inputs") else None
                    if sock is not None and n.type.startswith("BSDF"):
                        src, default = _socket_source(sock), tuple(sock.default_value)
                        break
                _add_aov(nt, "albedo", src, default)
                _add_aov(nt, "roughness", None, 0.5)
                _add_aov(nt, "metallic", None, 0.0)
    return flags


def setup_render(item: dict, samples: int) -> None:
    scene = bpy.context.scene
    w, h = int(item["width"]), int(item["height"])
    bcam = item["camera"]  # derived from K by the parent (intrinsics.blender_camera_from_K)
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y, r.resolution_percentage = w, h, 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.film_transparent = True
    r.use_persistent_data = False
    c = scene.cycles
    c.device = "CPU"
    c.samples = samples
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.max_bounces = 0  # only first-hit passes are used; shading is irrelevant
    c.caustics_reflective = c.caustics_refractive = False
    c.seed = 0
    scene.world = bpy.data.worlds.new("zcomp_world")

    add_camera(scene, bcam, clip_end=1e6)

    vl = scene.view_layers[0]
    vl.use_pass_z = True
    vl.use_pass_normal = True
    vl.use_pass_combined = True
    for name, kind in AOVS:
        aov = vl.aovs.add()
        aov.name = name
        aov.type = kind

    im = r.image_settings
    im.media_type = "MULTI_LAYER_IMAGE"
    im.file_format = "OPEN_EXR_MULTILAYER"
    im.color_depth = "32"
    im.exr_codec = "ZIP"


def render_to(path: str, samples: int, filter_width: float) -> None:
    scene = bpy.context.scene
    scene.cycles.samples = samples
    scene.cycles.filter_width = filter_width
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)


def process(item: dict, common: dict) -> dict:
    reset_scene()
    samples = int(common.get("samples", 16))
    setup_render(item, samples)
    root, meshes = import_mesh(item["mesh"], item["format"])
    flags = setup_materials(meshes)
    root.matrix_world = Matrix(item["mesh_to_camera"])
    work = item["work_dir"].rstrip("/")
    files = {}
    files["appearance"] = f"{work}/appearance.exr"
    render_to(files["appearance"], samples, 1.5)
    # One sample through the pixel centre: depth and normals of exactly one surface
    # point per pixel (several samples would average depths across silhouettes).
    files["geometry"] = f"{work}/geometry.exr"
    render_to(files["geometry"], 1, 0.01)
    root.matrix_world = Matrix(item["footprint_to_camera"])
    files["footprint"] = f"{work}/footprint.exr"
    render_to(files["footprint"], 1, 0.01)
    return {"files": files, "has_roughness": flags["roughness"], "has_metallic": flags["metallic"]}


def main(job_path: str) -> int:
    return serve_job_file(job_path, process, started=_T0, blender_version=bpy.app.version_string)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
