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
                "width": int, "height": int, "work_dir": path, "mesh_radius": float,
                "camera": {lens_mm, sensor_width_mm, shift_x, shift_y}  (from K: blender_camera_from_K),
                "borders": {"appearance"|"geometry"|"footprint": [x0, x1, y0, y1] | None}}, ...]}

Scene layout: Blender's world frame is the mesh's own frame (Y-up file coordinates)
scaled by the pose's uniform scale; the camera moves to the inverse of the pose's rigid
part, so what it sees is exactly zcomp's camera frame (x right, y up, looking along
-z). A flattened linked copy of the mesh (the footprint) stands far away, beyond the
far clip of the other renders. Only the camera moves between renders and poses of one
mesh, so Cycles' persistent data (BVH, shaders) is reused; items are sorted by mesh by
the parent. Meshes this cannot hold (modifiers, e.g. skinning) fall back to a camera at
the origin and a moving mesh root.

Three renders per item, each sampling only the object's pixel window (``borders``,
computed by the parent; the EXR holds the window, the parent pastes it back), surfaces
drawn as plain white emission (every pass read is a first-hit one), written without
compression to ``work_dir``:

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
import numpy as np  # noqa: E402
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


def _coverage_surface(nt, bsdf) -> None:
    """Replace the material's surface by plain white emission (through the material's
    own alpha, when it has one). Every pass zcomp reads -- alpha, Z, normals, AOVs -- is
    a first-hit quantity, so BSDF evaluation and light sampling are pure cost."""
    out = next((n for n in nt.nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output), None)
    if out is None:
        out = nt.nodes.new("ShaderNodeOutputMaterial")
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    em.inputs["Strength"].default_value = 1.0
    surface = em.outputs[0]
    alpha = bsdf.inputs.get("Alpha") if bsdf is not None else None
    if alpha is not None and (alpha.is_linked or float(alpha.default_value) < 1.0):
        mix = nt.nodes.new("ShaderNodeMixShader")
        src = _socket_source(alpha)
        if src is not None:
            nt.links.new(src, mix.inputs["Fac"])
        else:
            mix.inputs["Fac"].default_value = float(alpha.default_value)
        nt.links.new(nt.nodes.new("ShaderNodeBsdfTransparent").outputs[0], mix.inputs[1])
        nt.links.new(em.outputs[0], mix.inputs[2])
        surface = mix.outputs[0]
    nt.links.new(surface, out.inputs["Surface"])


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
            _coverage_surface(nt, bsdf)
    return flags


# What this process has set up, kept between items: consecutive items of one mesh
# (poses of one object, sorted together by the parent) reuse the imported mesh, its
# materials and Cycles' persistent scene data (BVH, shaders).
_STATE: dict = {"mesh_key": None, "root": None, "flags": None, "fp_root": None, "offset": 0.0,
                "S": None, "off": None}


def _similarity(M):
    """(s, R, t) when the 4x4 ``M`` is ``[s R | t]`` (uniform scale, rotation), else None."""
    M = np.asarray(M, dtype=np.float64)
    A = M[:3, :3]
    s = float(np.cbrt(np.linalg.det(A)))
    if not np.isfinite(s) or s <= 0 or np.abs(M[3] - [0, 0, 0, 1]).max() > 1e-9:
        return None
    R = A / s
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6:
        return None
    return s, R, M[:3, 3]


def _static_copy_ok(root) -> bool:
    """A second, flattened copy of the mesh can stand in for the footprint when every
    object under the root is a plain mesh (no modifiers: armature skinning would follow
    the original's bones)."""
    objs = [o for o in bpy.data.objects if o is not root and o.type != "CAMERA"]
    return all(o.type in ("MESH", "EMPTY") and len(o.modifiers) == 0 for o in objs)


def _make_footprint_copy(root, meshes):
    """Linked copies (shared mesh data) of ``meshes``, under a new empty, holding the
    same root-relative transforms."""
    bpy.context.view_layer.update()
    fp_root = bpy.data.objects.new("zcomp_fp_root", None)
    bpy.context.scene.collection.objects.link(fp_root)
    inv = root.matrix_world.inverted()
    for o in meshes:
        c = bpy.data.objects.new(o.name + "_fp", o.data)
        bpy.context.scene.collection.objects.link(c)
        c.parent = fp_root
        c.matrix_parent_inverse = Matrix.Identity(4)
        c.matrix_basis = inv @ o.matrix_world
    return fp_root


def _mat(a) -> "Matrix":
    return Matrix([list(map(float, row)) for row in np.asarray(a)])


def setup_scene(flags: dict) -> None:
    """Render settings that do not depend on the item (once per imported mesh)."""
    scene = bpy.context.scene
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.film_transparent = True
    # Keep Cycles' synced scene (object BVHs, compiled shaders) between renders: moving
    # the root between the appearance, geometry and footprint renders and between
    # poses then only rebuilds the top-level BVH.
    r.use_persistent_data = True
    c = scene.cycles
    c.device = "CPU"
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.max_bounces = 0  # only first-hit passes are used; shading is irrelevant
    c.caustics_reflective = c.caustics_refractive = False
    c.seed = 0
    scene.world = None  # no world: no background light to sample

    vl = scene.view_layers[0]
    vl.use_pass_z = True
    vl.use_pass_normal = True
    vl.use_pass_combined = True
    for name, kind in AOVS:
        # A constant roughness/metallic map carries nothing: no AOV, no shader work.
        if name in flags and not flags[name]:
            continue
        aov = vl.aovs.add()
        aov.name = name
        aov.type = kind

    im = r.image_settings
    im.media_type = "MULTI_LAYER_IMAGE"
    im.file_format = "OPEN_EXR_MULTILAYER"
    im.color_depth = "32"
    # Scratch files read once by the parent on the same machine: compression costs
    # more time than the bytes it saves.
    im.exr_codec = "NONE"


def setup_camera(item: dict) -> None:
    scene = bpy.context.scene
    r = scene.render
    r.resolution_x, r.resolution_y = int(item["width"]), int(item["height"])
    bcam = item["camera"]  # derived from K by the parent (intrinsics.blender_camera_from_K)
    if scene.camera is None:
        add_camera(scene, bcam, clip_end=1e6)
        return
    cd = scene.camera.data
    cd.sensor_width = float(bcam["sensor_width_mm"])
    cd.lens = float(bcam["lens_mm"])
    cd.shift_x = float(bcam["shift_x"])
    cd.shift_y = float(bcam["shift_y"])


def render_to(path: str, samples: int, filter_width: float, box=None) -> None:
    """Render the scene to ``path`` (every pass: switching passes between renders makes
    Cycles sync the whole scene again, which costs more than writing them). ``box``: ``[x0, x1, y0, y1]`` pixels (top-left origin, ends
    exclusive) -- only that window is sampled and written (the parent pastes it back)."""
    scene = bpy.context.scene
    scene.cycles.samples = samples
    scene.cycles.filter_width = filter_width
    r = scene.render
    r.use_border = r.use_crop_to_border = box is not None
    if box is not None:
        W, H = r.resolution_x, r.resolution_y
        x0, x1, y0, y1 = (int(v) for v in box)
        # Blender truncates border * size to whole pixels (y from the bottom): a quarter
        # pixel past each integer makes that exact whatever the rounding.
        r.border_min_x, r.border_max_x = (x0 + 0.25) / W, (x1 + 0.25) / W
        r.border_min_y, r.border_max_y = (H - y1 + 0.25) / H, (H - y0 + 0.25) / H
    r.filepath = path
    bpy.ops.render.render(write_still=True)


def process(item: dict, common: dict) -> dict:
    """Render one item. Two ways to place things:

    * static (the usual case): the mesh stays at the world origin scaled by the pose's
      scale, a flattened linked copy of it (the footprint) stays far away, and only the
      camera moves -- to the pose's inverse for the appearance and geometry renders, to
      the copy for the footprint render. Cycles then keeps its BVH between renders and
      poses (moving an object costs a rebuild: ~0.1 CPU-s per render for 27k
      triangles, measured). Normals come out in the world frame; the parent rotates
      them with the ``cam_to_world`` reported.
    * moving (non-uniform scale, modifiers): the camera stays at the origin and the
      mesh root moves, as zcomp did first.
    """
    samples = int(common.get("samples", 16))
    timings = {}
    t = time.monotonic()
    key = (item["mesh"], item["format"])
    reused = _STATE["mesh_key"] == key
    if not reused:
        _STATE["mesh_key"] = None
        reset_scene()
        root, meshes = import_mesh(item["mesh"], item["format"])
        flags = setup_materials(meshes)
        setup_scene(flags)
        fp_root = _make_footprint_copy(root, meshes) if _static_copy_ok(root) else None
        _STATE.update(mesh_key=key, root=root, flags=flags, fp_root=fp_root, offset=0.0, S=None, off=None)
    root, flags, fp_root = _STATE["root"], _STATE["flags"], _STATE["fp_root"]
    setup_camera(item)
    cam = bpy.context.scene.camera
    M = np.asarray(item["mesh_to_camera"], dtype=np.float64)
    F = np.asarray(item["footprint_to_camera"], dtype=np.float64)
    sim = _similarity(M) if fp_root is not None else None
    # Farthest any mesh point can be from the camera: the far clip (the footprint copy
    # stays beyond it) and the copy's distance follow from it.
    reach = float(np.linalg.norm(M[:3, 3])) + (sim[0] if sim else 1.0) * float(item.get("mesh_radius", 1e3))
    cam.data.clip_end = 1.05 * reach + 1.0
    if sim is not None:
        s, R, tr = sim
        flat = np.linalg.inv(M) @ F  # mesh -> mesh coordinates: the squash onto the base
        S = np.diag([s, s, s, 1.0])
        # The copy must stay beyond the far clip (1.05 reach + 1) from either camera: the
        # flattened copy reaches at most sqrt(2) * s * radius from its origin, so an
        # offset of 3 reach + 10 leaves it >= 1.58 reach + 10 away. Moving it costs a
        # BVH rebuild: when it must move, move it farther than needed.
        if _STATE["offset"] < 3.0 * reach + 10.0:
            _STATE["offset"] = 4.0 * reach + 10.0
        off = np.eye(4)
        off[0, 3] = _STATE["offset"]
        # Set the roots only when they change: moving an object costs a BVH rebuild.
        if _STATE["S"] is None or not np.array_equal(_STATE["S"], S @ flat) or _STATE["off"] != _STATE["offset"]:
            root.matrix_world = _mat(S)
            fp_root.matrix_world = _mat(off @ S @ flat)
            _STATE["S"], _STATE["off"] = S @ flat, _STATE["offset"]
        cam_to_world = np.eye(4)
        cam_to_world[:3, :3] = R.T
        cam_to_world[:3, 3] = -R.T @ tr
        cams = {"appearance": cam_to_world, "geometry": cam_to_world, "footprint": off @ cam_to_world}
    else:
        cams = {k: np.eye(4) for k in ("appearance", "geometry", "footprint")}
        if fp_root is not None:  # (a non-uniform pose) the copy goes behind the camera
            behind = np.eye(4)
            behind[2, 3] = 4.0 * reach + 10.0
            fp_root.matrix_world = _mat(behind)
            _STATE["S"] = None
    timings["setup_s"] = time.monotonic() - t
    borders = item.get("borders") or {}
    work = item["work_dir"].rstrip("/")
    files = {}
    plan = (("appearance", samples, 1.5), ("geometry", 1, 0.01), ("footprint", 1, 0.01))
    for name, n, fw in plan:
        if sim is not None:
            cam.matrix_world = _mat(cams[name])
        else:
            cam.matrix_world = Matrix.Identity(4)
            root.matrix_world = _mat(F if name == "footprint" else M)
        files[name] = f"{work}/{name}.exr"
        t, c = time.monotonic(), time.process_time()
        # geometry and footprint: one sample through the pixel centre, i.e. depth and
        # normals of exactly one surface point per pixel (several samples would
        # average depths across silhouettes).
        render_to(files[name], n, fw, borders.get(name))
        timings[f"{name}_s"] = time.monotonic() - t
        timings[f"{name}_cpu_s"] = time.process_time() - c
    return {"files": files, "boxes": {k: borders.get(k) for k in files}, "has_roughness": flags["roughness"],
            "has_metallic": flags["metallic"], "mesh_reused": reused, "static_scene": sim is not None,
            "cam_to_world": cams["geometry"].tolist(),
            "timings": {k: round(v, 4) for k, v in timings.items()}}


def main(job_path: str) -> int:
    return serve_job_file(job_path, process, started=_T0, blender_version=bpy.app.version_string)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
