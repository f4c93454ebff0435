"""The conventions of the ZeroComp ("labo") and SpotLight evaluation archives, and their
conversion into zcomp's (DESIGN.md section 3), once, at the edge.

Each rule below was read from the official code (github.com/lvsn/ZeroComp at 1de5c9b,
github.com/lvsn/SpotLight at 51a4f36); the comment names where.

Multi-layer bundle (``<case>/<case>_bundle0001.exr``), as both loaders read it with
skylibs' ``ezexr.imread(path, rgb="hybrid")``:

* a layer is the channel-name prefix before the first ``.``; its channels are ordered
  R, G, B, A, X, Y, Z, then any others (``CHANNEL_ORDER``);
* value layers (depth, footprint_depth, roughness, metallic) are RGBA: the ZeroComp
  loader takes channel 0 (``[:, :, :1]``), SpotLight's channels 2 and 3 as "value,
  alpha" (``[:, :, 2:4]``), and composites them as *premultiplied* by that alpha
  (``compositor.alpha_blend``, "assuming premultiplied alpha"); so do its normals
  (``n * 0.5 + 0.5 * alpha``). zcomp stores straight values with a separate coverage
  mask, so a layer with an alpha channel is divided by it (``unpremultiply``);
* normals: ``[:, :, :3]``; the ZeroComp loader decodes them from [0, 1] when the whole
  layer is >= 0 (``comp_normal_to_openrooms_normal``) and negates z (Blender's
  shader camera space, z forward -> OpenRooms/OpenGL, +z toward the viewer), SpotLight's
  loader does not (its bundles are read as OpenGL camera frame already);
* depth: z-depth in metres (``sdi_utils.depth_map_to_point_cloud`` unprojects it as
  ``(x, -y, -z)`` with ``z = depth``, horizontal fov 50 degrees);
* albedo: linear (``albedo_gamma_correction: false``); mask: a 1-channel coverage layer;
* background, composite: linear RGB (the loaders gamma-encode them after clipping,
  ``gamma_correction``; zcomp keeps them linear).

Background maps (``<case>_bg_*``), read by ``load_image(path, isGamma=False)``: the PNG
values divided by 255 are used *as they are* (no sRGB or gamma decoding), RGB order.
``_bg_normal.png`` is StableNormal's output, x negated relative to OpenRooms
(``stablenormal_normal_to_openrooms_normal``); ``_bg_depth.exr`` is metres, channel 0.

SpotLight lights (``<case>_light_path_dto.json``): ``light_frames[i]
.blender_light_xyz_position_object_space`` = v, scaled by ``eval.light_distance`` (10)
and placed at ``obj_center + camera.matrix_world @ Rx(-90 deg) @ (d v)`` in Blender's
world (``shadow_map_generation.py``; the camera of ``shadowmap.blend`` sits at the
origin, 512 x 512, 50 degrees). In the camera frame that is ``centre + d * (v_x, v_z,
-v_y)``: v's axes are right, forward, up. The lamp's radius is ``eval.light_radius`` (1 m,
Blender's point-lamp ``shadow_soft_size``).
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.conventions import MIN_FACING_FRACTION, facing_fraction, normalize, pixel_ray  # noqa: F401 (re-exported)

# The archives' camera: horizontal fov (configs/sg_labo.yaml point_cloud_fov; SpotLight's
# shadowmap.blend camera: 50 degrees at 512 x 512).
FOV_DEG = 50.0
# configs/sg_labo.yaml (seed, eval.num_inference_steps, eval.weight_dtype: fp16 under
# torch.autocast) and ZeroComp's PointCloud shading mask, relative range 1.0 (lambda).
PAPER_SEED = 469
PAPER_STEPS = 20
PAPER_DTYPE = "fp16-autocast"
PAPER_WINDOW = "center"  # the official Resize(512) + CenterCrop(512)
ZEROCOMP_SHADING_RADIUS = 1.0
# SpotLight configs/default.yaml: eval.shading_maskout_pc_range_relative, eval.light_distance,
# eval.light_radius.
SPOTLIGHT_SHADING_RADIUS = 0.5
SPOTLIGHT_LIGHT_DISTANCE_M = 10.0
SPOTLIGHT_LIGHT_RADIUS_M = 1.0
# skylibs ezexr ``rgb="hybrid"``: channel order within a layer.
CHANNEL_ORDER = "RGBAXYZ"
# Below this alpha a premultiplied value carries no usable information: 0 (no data).
ALPHA_EPS = 1e-3
# Normal frames of the bundles: which official loader reads them how.
NORMAL_FRAMES = ("blender-camera", "opengl")


def order_channels(names) -> list[str]:
    """Channel names of one layer in skylibs' "hybrid" order: R, G, B, A, X, Y, Z first
    (in that order), then the others in their given order.

    ``order_channels(["A", "B", "G", "R"]) == ["R", "G", "B", "A"]``.
    """
    names = list(names)
    return sorted(names, key=lambda c: CHANNEL_ORDER.index(c) if c in CHANNEL_ORDER else len(CHANNEL_ORDER))


def group_layers(channels: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``{"albedo.R": HxW, "albedo.G": ..., "mask.R": ...}`` -> ``{"albedo": HxWxC, ...}``.

    A layer is the name before the first ``.``; the rest names the channel, ordered by
    :func:`order_channels`. A channel without a ``.`` is a layer of its own with one
    channel (skylibs would drop it; zcomp keeps it so that an error can name it).
    """
    by_layer: dict[str, dict[str, np.ndarray]] = {}
    for full, arr in channels.items():
        layer, _, chan = full.partition(".")
        by_layer.setdefault(layer, {})[chan or full] = arr
    return {layer: np.stack([chans[c] for c in order_channels(chans)], axis=-1).astype(np.float32)
            for layer, chans in by_layer.items()}


def unpremultiply(value, alpha, eps: float = ALPHA_EPS) -> np.ndarray:
    """Straight values from values premultiplied by ``alpha``: ``value / alpha`` where
    ``alpha > eps``, else 0 (no data). Non-finite input -> 0.

    Args:
        value: (H, W) or (H, W, C).
        alpha: (H, W) coverage in [0, 1].
    Returns:
        float32, the shape of ``value``. ``unpremultiply(1.5, 0.5) = 3.0``.
    """
    v = np.nan_to_num(np.asarray(value, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    a = np.nan_to_num(np.asarray(alpha, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    if v.ndim == a.ndim + 1:
        a = a[..., None]
    ok = a > eps
    return np.where(ok, v / np.where(ok, a, 1.0), 0.0).astype(np.float32)


def bundle_normals_to_camera(normals, frame: str, *, decode_nonnegative: bool = False) -> np.ndarray:
    """A bundle's normals layer (its first 3 channels) -> zcomp camera-frame unit normals.

    With ``decode_nonnegative`` (the ZeroComp loader's rule,
    ``comp_normal_to_openrooms_normal``) a layer whose every value is >= 0 is taken as
    encoded, ``2 e - 1``; SpotLight's loader always reads signed vectors. Then ``frame``
    "blender-camera" (the ZeroComp loader: Blender's shader camera space, z forward)
    negates z, "opengl" (SpotLight's loader) keeps the vector. The length is removed
    (premultiplied or filtered normals are shorter); zero vectors stay 0.

    ``bundle_normals_to_camera([0.6, 0, -0.8], "blender-camera") == [0.6, 0, 0.8]``.
    """
    if frame not in NORMAL_FRAMES:
        raise ValueError(f"unknown normals frame {frame!r} (one of {', '.join(NORMAL_FRAMES)})")
    n = np.nan_to_num(np.asarray(normals, np.float64)[..., :3], nan=0.0, posinf=0.0, neginf=0.0)
    if decode_nonnegative and n.size and n.min() >= 0:
        n = 2.0 * n - 1.0
    if frame == "blender-camera":
        n = n * np.array([1.0, 1.0, -1.0])
    return normalize(n)


def stablenormal_png_to_camera_normals(encoded) -> np.ndarray:
    """A precomputed StableNormal map ``_bg_normal.png`` (values / 255, RGB) -> zcomp
    camera-frame unit normals: ``n = 2 e - 1`` with x negated
    (``stablenormal_normal_to_openrooms_normal``), normalised; vectors shorter than 0.5
    (the 8-bit "no normal" (128, 128, 128)) -> 0.

    ``e = (64, 128, 255) / 255`` -> ``(0.4458, 0.0035, 0.8951)``.
    """
    e = np.nan_to_num(np.asarray(encoded, np.float64)[..., :3], nan=0.5)
    n = 2.0 * e - 1.0
    # 8 bits cannot store 0.5 exactly: "no normal" (128, 128, 128) decodes to a short
    # vector (0.004 per axis), not to a direction; a decoded normal is ~unit length.
    n = np.where((np.linalg.norm(n, axis=-1) < 0.5)[..., None], 0.0, n)
    return normalize(n * np.array([-1.0, 1.0, 1.0]))


def spotlight_light_to_camera(position_object_space, centre_cam, distance: float = SPOTLIGHT_LIGHT_DISTANCE_M
                              ) -> np.ndarray:
    """SpotLight's ``blender_light_xyz_position_object_space`` -> the lamp's camera-frame
    position (zcomp: x right, y up, z toward the viewer; metres).

    ``shadow_map_generation.py`` puts the lamp at ``obj_center + camera.matrix_world @
    Rx(-90 deg) @ (distance * v)``; with the camera at the origin that is, in the
    camera's own frame, ``centre + distance * (v_x, v_z, -v_y)`` (v: right, forward, up).

    Args:
        position_object_space: v, 3 numbers.
        centre_cam: the object's bounding-box centre in the camera frame (metres).
        distance: ``eval.light_distance`` (10 in SpotLight's default config).
    Returns:
        (3,) float64. v = (0, 1, 0) (straight ahead) with the centre at (0, 0, -3) and
        distance 10 -> (0, 0, -13).
    """
    v = np.asarray(position_object_space, np.float64).reshape(3)
    c = np.asarray(centre_cam, np.float64).reshape(3)
    if not (np.isfinite(v).all() and np.isfinite(c).all() and np.isfinite(distance)):
        raise ValueError("light position, object centre and distance must be finite")
    return c + float(distance) * np.array([v[0], v[2], -v[1]])
