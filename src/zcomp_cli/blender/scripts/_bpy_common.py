"""bpy helpers shared by the Blender scripts (runs inside bpy only).

``add_camera`` puts zcomp's pinhole camera at the world origin with identity rotation,
so Blender's world frame IS zcomp's camera frame. In ``import_mesh`` every format is imported so that, in the frame of a new empty root object, each vertex
has its file's own coordinates (metres, Y-up as zcomp reads meshes); the parent then
places the root with one matrix computed in numpy (``Pose.object_to_camera``)."""

from __future__ import annotations

import bpy
from mathutils import Matrix

# Blender's glTF importer turns glTF's +Y up into Blender's +Z up: (x, y, z) -> (x, -z, y).
# This undoes it, so imported coordinates are the file's own (Y-up) coordinates again.
GLTF_TO_FILE = Matrix.Rotation(-1.5707963267948966, 4, "X")
# Blender's own axes are forward +Y, up +Z: importing OBJ/PLY/STL with these options
# applies no axis conversion at all, i.e. keeps the file's coordinates.
NO_CONVERSION = {"forward_axis": "Y", "up_axis": "Z"}


def import_mesh(path: str, fmt: str, root_name: str = "zcomp_root"):
    """Import ``path`` under a new empty ``root_name``. Returns (root, mesh objects).
    Cameras, lights and other non-geometry a file may carry are removed."""
    before = set(bpy.data.objects)
    if fmt == "gltf":
        bpy.ops.import_scene.gltf(filepath=path, import_shading="NORMALS")
    elif fmt == "obj":
        bpy.ops.wm.obj_import(filepath=path, global_scale=1.0, **NO_CONVERSION)
    elif fmt == "ply":
        bpy.ops.wm.ply_import(filepath=path, global_scale=1.0, import_colors="SRGB", **NO_CONVERSION)
    elif fmt == "stl":
        bpy.ops.wm.stl_import(filepath=path, global_scale=1.0, **NO_CONVERSION)
    else:
        raise ValueError(f"unknown mesh format {fmt!r}")
    new = [o for o in bpy.data.objects if o not in before]
    # Cameras and lights a glTF may carry have no business here (armatures and empties
    # stay: meshes hang from them).
    for o in [o for o in new if o.type in ("CAMERA", "LIGHT", "LIGHT_PROBE", "SPEAKER")]:
        new.remove(o)
        bpy.data.objects.remove(o, do_unlink=True)
    if not any(o.type == "MESH" for o in new):
        raise ValueError("the importer produced no mesh objects")
    root = bpy.data.objects.new(root_name, None)
    bpy.context.scene.collection.objects.link(root)
    fix = GLTF_TO_FILE if fmt == "gltf" else Matrix.Identity(4)
    for o in new:
        if o.parent is None:
            mw = o.matrix_world.copy()
            o.parent = root
            o.matrix_parent_inverse = Matrix.Identity(4)
            o.matrix_basis = fix @ mw
    return root, [o for o in new if o.type == "MESH"]


def add_camera(scene, bcam: dict, *, clip_end: float = 1e6):
    """Add the scene camera from ``zcomp_cli.blender.intrinsics.blender_camera_from_K``
    settings (lens, sensor width, shifts), at the origin with identity rotation."""
    cam_data = bpy.data.cameras.new("zcomp_cam")
    cam_data.type = "PERSP"
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = float(bcam["sensor_width_mm"])
    cam_data.lens = float(bcam["lens_mm"])
    cam_data.shift_x = float(bcam["shift_x"])
    cam_data.shift_y = float(bcam["shift_y"])
    cam_data.clip_start = 1e-3
    cam_data.clip_end = clip_end
    cam = bpy.data.objects.new("zcomp_cam", cam_data)
    cam.matrix_world = Matrix.Identity(4)
    scene.collection.objects.link(cam)
    scene.camera = cam
    return cam


def multilayer_exr_output(render, codec: str = "ZIP") -> None:
    """Write renders as 32-bit float multilayer OpenEXR -- the raw passes zcomp converts
    with numpy (bpy 5 has no compositor node tree to do it here). ``codec``: ``NONE`` for
    scratch files the parent reads once (compression costs more time than it saves)."""
    im = render.image_settings
    if hasattr(im, "media_type"):
        im.media_type = "MULTI_LAYER_IMAGE"
    im.file_format = "OPEN_EXR_MULTILAYER"
    im.color_depth = "32"
    im.exr_codec = codec


def node_tree(owner):
    """The node tree of a world or material, its nodes switched on (older Blender has
    ``use_nodes``; in newer ones the tree is always on and the flag may refuse a write)."""
    if hasattr(owner, "use_nodes"):
        try:
            owner.use_nodes = True
        except Exception:  # always-on node trees in newer Blender
            pass
    return owner.node_tree


def principled_bsdf(mat):
    """The material's Principled BSDF node, made and wired to its output when it has none."""
    nt = node_tree(mat)
    bsdf = next((n for n in nt.nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is None:
        bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
        out = next((n for n in nt.nodes if n.type == "OUTPUT_MATERIAL"), None) \
            or nt.nodes.new("ShaderNodeOutputMaterial")
        nt.links.new(bsdf.outputs[0], out.inputs["Surface"])
    return bsdf
