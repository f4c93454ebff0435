"""The dictionary of the light fit: what each kind of light adds to the known shading.

Each atom is a column over the fit pixels (``FitPixels``) of a light of unit strength,
rendered with the same transport the renderer synthesises with (``lightmodel``):

* ``sky_atoms``: non-negative radiance lobes over the upper hemisphere (a uniform sky,
  cosine lobes toward the four ground directions and the zenith), each as SH shading
  times its visible share (``skyvis.weighted_visibility``: the screen-space
  occlusion of each direction weighted by the lobe's radiance there, so a wall hides
  the bright sky behind it and not the dark one);
* ``sun_column(s)``: ``max(0, n.l) V(p, l)`` averaged over a cone of the light's
  angular radius;
* ``lamp_column(s)``: ``max(0, n.(q - p)) / |q - p|^3 V(p, q)`` (a sphere of radius r: its
  cone from each point has half-angle ``asin(r / |q - p|)``);
The support's bounce (``bounce``) is no atom: it is measured on the photograph (the
support's own image radiance) and subtracted.

**The scene's specular layer.** A dielectric surface (Blender's Principled BSDF: F0
0.04) reflects a share R of its surround on top of its diffuse, and Cycles takes that
share from the diffuse beneath, so the image is ``E (albedo + R (1 - albedo))``, not
``E albedo``; R grows toward grazing views (``brdf.dielectric_offset``: 0.02-0.04 facing
the camera, up to 0.1-0.5 across a floor seen at a grazing angle, the smoother the
more). Fitted as ``E albedo``, that view-dependent brightening is read as light: on the
benchmark's scenes the photograph's exposure fitted under the full light was off by a
factor exp(0.145) on average, the floor's sheen read as a brighter light (the object
then rendered up to 1.6x too bright) or a constant offset taken for it (0.5x too dark).
``specular_roughness`` chooses the layer's roughness (the one, among
``FrameConfig.specular_roughness``, whose shading ``image / (albedo + offset)`` the sky
alone explains best on held-out pixels: a roughness sets how fast the offset grows
across the frame), and the fit's shading is ``image / (albedo + offset)``
(``offset_shading``). What it chooses is the offset's shape that explains the frame, not
a measurement of the surface's roughness (docs/calibration-record.md: given the floor's
true roughness instead, the exposure's error is 0.089 against the chosen one's 0.074).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import REC601, unit_normal_mask
from zcomp_cli.scene.brdf import camera_offset
from zcomp_cli.scene import sh
from zcomp_cli.scene.config import FrameConfig, MarchConfig
from zcomp_cli.scene.lightmodel import ground_view
from zcomp_cli.scene.march import march_visibility
from zcomp_cli.scene.sampling import dot, fibonacci_sphere, length, orthonormal_rows
from zcomp_cli.scene.skyvis import sky_samples, weighted_visibility


@dataclass(frozen=True)
class FitPixels:
    """The pixels the light is fitted on, at the working copy's resolution.

    ``points`` (N, 3) camera frame, ``normals`` (N, 3) unit, ``ys``/``xs`` (N,) their
    pixels in the copy; ``albedo`` (N, 3) linear; ``train`` (N,) the pixels the weights
    are fitted on (the others are held out: whole blocks of the frame, so that held-out
    pixels are not the neighbours of fitted ones); ``support`` (N,) on the support;
    ``depth`` (h, w) and ``camera`` of the copy; ``up`` (3,); ``walls`` the scene's walls
    beyond the frame (``planes``), which occlude every light's rays; ``caster`` the
    ray tracer of the scene's depth mesh (``depthmesh``), None: the screen-space march;
    ``blocks`` the frame's blocks per long side (held out in a checkerboard); ``march``
    the screen-space march's config; ``bias_rel`` a ray's start off its surface, a
    share of its depth (``SearchConfig.bias_rel``)."""

    points: np.ndarray
    normals: np.ndarray
    ys: np.ndarray
    xs: np.ndarray
    albedo: np.ndarray
    train: np.ndarray
    support: np.ndarray
    depth: np.ndarray
    camera: Camera
    up: np.ndarray
    march: MarchConfig
    bias_rel: float
    blocks: int
    walls: tuple = ()
    caster: object | None = None

    def __len__(self) -> int:
        return len(self.points)

    def with_caster(self, caster) -> "FitPixels":
        """The same pixels, their light rays answered by ``caster`` (``raycast.RayCaster``
        of the depth mesh, walls included) instead of the screen-space march."""
        import dataclasses

        return dataclasses.replace(self, caster=caster)

    @property
    def support_points(self) -> np.ndarray:
        """(M, 3) the support's points (every point where fewer than 3 are on it)."""
        return self.points[self.support] if self.support.sum() >= 3 else self.points

    def ray_origins(self) -> np.ndarray:
        """(N, 3) the points moved off their surface along the normal (``bias_rel`` of
        their depth), where shadow rays start."""
        return self.points + self.normals * (self.bias_rel * np.maximum(-self.points[:, 2], 1e-6))[:, None]


def working_copy(depth, normals, shading, known, albedo, camera: Camera, max_res: int):
    """The maps at a copy whose long side is at most ``max_res``: depth and normals
    nearest (no blending across edges), shading and albedo area-averaged, a pixel known
    only if all of its footprint is. Returns (d, n, shading, known, albedo, camera)."""
    import cv2

    H, W = depth.shape
    s = min(1.0, max_res / max(H, W))
    if s >= 1.0:
        return depth, normals, shading, known, albedo, camera
    w, h = max(1, round(W * s)), max(1, round(H * s))
    d = cv2.resize(depth.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
    n = cv2.resize(normals.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
    shc = cv2.resize(shading.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    a = cv2.resize(albedo.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    k = cv2.resize((~known).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) <= 0
    return d, n, shc, k, a, camera.resized(w, h)


def fit_pixels(depth, normals, shading, known, albedo, camera: Camera, up, *, max_fit_pixels: int,
               cfg: FrameConfig, march: MarchConfig, bias_rel: float, walls=None):
    """(FitPixels, shading (N, 3)) of the valid known pixels (finite positive shading,
    depth and unit normals), a deterministic stride subsample of at most
    ``max_fit_pixels``; ``walls`` the scene's walls beyond the frame (None: found on
    this copy); ``march`` and ``bias_rel`` their rays' (``FitPixels``)."""
    nn = np.linalg.norm(normals, axis=-1)
    unit = unit_normal_mask(normals)
    valid = (known & (depth > 0) & unit & np.all(np.isfinite(shading), -1)
             & np.all(shading > 0, -1))
    idx = np.flatnonzero(valid.ravel())
    if len(idx) > max_fit_pixels:
        idx = idx[np.linspace(0, len(idx) - 1, max_fit_pixels).astype(np.int64)]
    h, w = depth.shape
    ys, xs = np.divmod(idx, w)
    pts = camera.unproject(depth)
    P = pts.reshape(-1, 3)[idx].astype(np.float64)
    N = normals.reshape(-1, 3)[idx].astype(np.float64)
    N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
    S = shading.reshape(-1, 3)[idx].astype(np.float64)
    A = np.clip(np.nan_to_num(albedo.reshape(-1, 3)[idx].astype(np.float64)), 0.0, 1.0)
    blk = max(h, w) / cfg.holdout_blocks
    train = ((ys // blk).astype(int) + (xs // blk).astype(int)) % 2 == 0
    up = np.asarray(up, np.float64)
    support = N @ up > np.cos(np.deg2rad(cfg.support_deg))
    if walls is None:
        from zcomp_cli.scene.planes import find_walls

        geo = (depth > 0) & unit
        nrm = normals / np.maximum(nn, 1e-12)[..., None]
        walls = find_walls(pts, nrm, geo, up, cfg)
    fp = FitPixels(points=P, normals=N, ys=ys, xs=xs, albedo=A, train=train, support=support,
                   depth=np.asarray(depth, np.float32), camera=camera, up=up, walls=tuple(walls),
                   blocks=cfg.holdout_blocks, march=march, bias_rel=bias_rel)
    return fp, S


def ground_radiance(fp: FitPixels, shading: np.ndarray) -> np.ndarray:
    """(3,) the support's image radiance (albedo x shading, median over its pixels): what
    a surface facing down sees of it. Zero without support pixels."""
    if fp.support.sum() < 1:
        return np.zeros(3)
    return np.median(fp.albedo[fp.support] * shading[fp.support], axis=0)


def bounce(fp: FitPixels, ground: np.ndarray) -> np.ndarray:
    """(N, 3) shading the support's bounce adds at the fit pixels."""
    return ground_view(fp.normals, fp.up)[:, None] * np.asarray(ground, np.float64)[None]


def sky_visibility(fp: FitPixels):
    """The sky seen from each fit pixel: ``skyvis.sky_samples`` (directions (K, N, 3),
    visibility (K, N)), with the sky's directions, steps and reach of ``fp.march``, as
    the synthesis sees it (one sky)."""
    return sky_samples(fp.points, fp.normals, fp.ys, fp.xs, fp.depth, fp.camera, cfg=fp.march, walls=fp.walls)


def sky_lobes(frame) -> list[tuple[str, np.ndarray]]:
    """Non-negative sky radiance lobes above the ground (``frame`` rows right, up,
    forward): the uniform sky, ``max(0, w . a)`` toward each of the four ground
    directions and the zenith. Returns (name, radiance SH (9,)) each, unit radiance
    scale (the uniform sky: radiance 1)."""
    right, up, fwd = np.asarray(frame, np.float64)
    d = fibonacci_sphere(4096)
    om = np.full(len(d), 4 * np.pi / len(d))
    above = (d @ up) > 0
    out = [("sky", sh.project(d[above], np.ones(above.sum()), om[above])[:, 0])]
    for name, a in (("sky_right", right), ("sky_forward", fwd), ("sky_left", -right), ("sky_back", -fwd),
                    ("sky_zenith", up)):
        L = np.maximum(d[above] @ a, 0.0)
        out.append((name, sh.project(d[above], L, om[above])[:, 0]))
    return out


def sky_atom_values(fp: FitPixels, radiance_sh: np.ndarray, samples, radiance_at=None) -> np.ndarray:
    """The shading a sky of SH radiance ``radiance_sh`` ((9,) grey: (N,); (9, 3): (N, 3))
    gives the fit pixels, times its visible share through ``samples``
    (``sky_visibility``), each direction weighed by the SH radiance there, or by
    ``radiance_at`` (directions (M, 3) -> (M, 3)) where the sky's map is known (a
    probe's: ``probe.ProbeLights.sky_radiance_at``), as the synthesis weighs it."""
    c = np.asarray(radiance_sh, np.float64)
    grey = c.ndim == 1
    c = c.reshape(9, -1)
    s = np.maximum(sh.evaluate(sh.shading_coeffs(c), fp.normals), 0.0) * weighted_visibility(
        *samples, c if radiance_at is None else radiance_at)
    return s[:, 0] if grey else s


def specular_roughness(fp: FitPixels, shading: np.ndarray, base: np.ndarray, *, cfg: FrameConfig, solver) -> float:
    """The roughness of the scene's specular layer (module docstring): among
    ``cfg.specular_roughness``, the one whose shading ``image / (albedo + offset)``
    (luminance) the grey columns ``base`` (N, B) fit best on the held-out pixels
    (relative losses, so the shading's scale does not count); NaN where no fit pixel has
    an albedo to read it on."""
    from zcomp_cli.light.solver import score_candidates

    a = fp.albedo @ REC601
    ok = a > 1e-3
    if not (fp.train & ok).any():  # no fit pixel of any albedo: no layer to read (its losses were NaN)
        return float("nan")
    img = (shading @ REC601) * a
    best_r, best_l = float("nan"), None
    for r in cfg.specular_roughness:
        g = camera_offset(fp.points, fp.normals, r, fp.albedo) @ REC601
        y = np.where(ok, img / np.maximum(a + g, 1e-6), 0.0)
        lh, _ = score_candidates(base, np.zeros((len(y), 1)), y, fp.train & ok, cfg=solver)
        loss = float(lh[0])
        if best_l is None or loss < best_l:
            best_r, best_l = float(r), loss
    return best_r


def offset_shading(fp: FitPixels, shading: np.ndarray, roughness: float) -> np.ndarray:
    """(N, 3) ``image / (albedo + offset)`` of the fit pixels (``shading`` = image /
    albedo), the offset of a specular layer of ``roughness`` (NaN: none)."""
    if not np.isfinite(roughness):
        return shading
    return shading * fp.albedo / np.maximum(fp.albedo + camera_offset(fp.points, fp.normals, roughness, fp.albedo),
                                            1e-6)


def sun_columns(fp: FitPixels, dirs: np.ndarray, *, steps: int, chunk: int = 32) -> np.ndarray:
    """(N, K) hard-shadowed ``max(0, n.l) V(p, l)`` of K directions (K, 3): one
    vectorised march per chunk of directions."""
    D = np.asarray(dirs, np.float64).reshape(-1, 3)
    out = np.zeros((len(fp), len(D)))
    P, Nr = fp.points, fp.normals
    if fp.caster is not None:
        O = fp.ray_origins()
        for c0 in range(0, len(D), 4 * chunk):
            Dc = D[c0:c0 + 4 * chunk]
            ndl = np.maximum(Nr @ Dc.T, 0.0)
            live = ndl.T > 0
            v = np.zeros((len(Dc), len(P)))
            if live.any():
                v[live] = ~fp.caster.occluded_grid(O, Dc, live)[live]
            out[:, c0:c0 + len(Dc)] = ndl * v.T
        return out
    for c0 in range(0, len(D), chunk):
        Dc = D[c0:c0 + chunk]
        C = len(Dc)
        ndl = np.maximum(Nr @ Dc.T, 0.0)  # (N, C)
        live = ndl.T.reshape(-1) > 0
        v = np.zeros(C * len(P))
        if live.any():
            Pr = np.tile(P, (C, 1))[live]
            Nn = np.tile(Nr, (C, 1))[live]
            Lr = np.repeat(Dc, len(P), 0)[live]
            v[live] = march_visibility(Pr, Nn, Lr, fp.depth, fp.camera, cfg=fp.march, steps=steps, walls=fp.walls)
        out[:, c0:c0 + C] = ndl * v.reshape(C, -1).T
    return out


def _cone_offsets(k: int, seed: int):
    """Unit-radius cone samples: (fractions of the radius in solid angle (k,), phases)."""
    rng = np.random.default_rng(seed)
    i = np.arange(k) + 0.5
    return i / k, rng.uniform(0, 2 * np.pi) + i * np.pi * (3 - np.sqrt(5))


def sun_column(fp: FitPixels, direction, radius_deg: float, *, steps: int, cone_samples: int,
               seed: int = 0) -> np.ndarray:
    """(N,) ``max(0, n.l) V(p, l)`` averaged over the cone of ``radius_deg`` around
    ``direction`` (``cone_samples`` directions uniform in solid angle)."""
    from zcomp_cli.scene.sampling import cone_directions

    k = cone_samples if radius_deg > 0 else 1
    dirs = cone_directions(direction, radius_deg, k, seed=seed)
    return sun_columns(fp, dirs, steps=steps).mean(1)


# Pixels per block of the unshadowed lamp columns: a block's four (64, K) planes, written
# in place, stay in the CPU's cache for the K lamps screened (~1000: 2 MB in all); the
# whole (N, K) planes at once took 1.8x the time, (256, K) planes made anew for each
# operation 1.4x (speed only: the values are the same).
_PIXEL_BLOCK = 64


def lamp_columns(fp: FitPixels, positions: np.ndarray, *, steps: int | None = None,
                 radius_m: float = 0.0, cone_samples: int = 1, seed: int = 0) -> np.ndarray:
    """(N, K) ``max(0, n.(q - p)) / |q - p|^3`` of K lamp positions (K, 3), times the
    visibility of the lamp (its sphere of ``radius_m`` sampled by ``cone_samples``
    directions from each point) when ``steps`` is given; unshadowed otherwise."""
    Q = np.asarray(positions, np.float64).reshape(-1, 3)
    P, Nr = fp.points, fp.normals
    if steps is None:  # unshadowed: every lamp at once, by blocks of pixels that stay in cache
        out = np.empty((len(P), len(Q)))
        planes = np.empty((4, min(_PIXEL_BLOCK, len(P)), len(Q)))
        for n0 in range(0, len(P), _PIXEL_BLOCK):
            p, nr = P[n0:n0 + _PIXEL_BLOCK], Nr[n0:n0 + _PIXEL_BLOCK]
            r2, ndl, v, t = planes[:, :len(p)]
            r2.fill(0.0)
            ndl.fill(0.0)
            for c in range(3):  # (n, K) planes of each axis
                np.subtract(Q[None, :, c], p[:, c, None], out=v)
                r2 += np.multiply(v, v, out=t)
                ndl += np.multiply(v, nr[:, c, None], out=t)
            np.maximum(r2, 1e-12, out=r2)
            t = np.multiply(np.sqrt(r2, out=t), r2, out=t)  # |q - p|^3
            np.divide(np.maximum(ndl, 0.0, out=ndl), t, out=out[n0:n0 + len(p)])
        return out
    # every lamp's rays at once: (K, N) planes, the live ones (lit, in front) flattened
    v = Q[:, None, :] - P[None]
    r = np.maximum(length(v), 1e-6)
    L = v / r[..., None]
    g = np.maximum(dot(Nr[None], L), 0.0) / (r * r)
    live = g > 0
    # (a lamp that lights no pixel keeps its column as it is)
    out = np.where(live.any(1)[:, None], 0.0, g).T.copy()
    if not live.any():
        return out
    kk, nn = np.nonzero(live)
    lv, rv = L[kk, nn], r[kk, nn]
    sampled = cone_samples > 1 and radius_m > 0
    n_s = cone_samples if sampled else 1
    fr, ph = _cone_offsets(max(1, cone_samples), seed)
    if sampled:
        u = orthonormal_rows(lv)[0]
        w = np.cross(lv, u)
        cos_max = np.sqrt(1 - np.clip(radius_m / rv, 0.0, 0.99) ** 2)

    def toward(s: int) -> np.ndarray:  # (M,) the rays' directions of sample s
        if not sampled:
            return lv
        cz = 1 - (1 - cos_max) * fr[s]
        sz = np.sqrt(np.maximum(0, 1 - cz * cz))
        d = cz[:, None] * lv + sz[:, None] * (np.cos(ph[s]) * u + np.sin(ph[s]) * w)
        d /= length(d)[:, None]
        return d

    # the ray ends at the lamp: nothing beyond it occludes
    if fp.caster is not None:  # every sample's rays in one query (a count of the seen ones: exact in any order)
        o = fp.ray_origins()[nn]
        occ = fp.caster.occluded(np.tile(o, (n_s, 1)), np.concatenate([toward(s) for s in range(n_s)]),
                                 tmax=np.tile(rv, n_s))
        acc = (~occ).reshape(n_s, -1).sum(0).astype(np.float64)
    else:
        acc = np.zeros(len(kk))
        for s in range(n_s):
            acc += march_visibility(P[nn], Nr[nn], toward(s), fp.depth, fp.camera, cfg=fp.march, steps=steps,
                                    max_distance=rv, walls=fp.walls)
    out[nn, kk] = g[kk, nn] * acc / n_s
    return out


def lamp_candidates(fp: FitPixels, n_directions: int, distances_rel) -> np.ndarray:
    """(K, 3) lamp positions to try: above the support's centre, in ``n_directions``
    directions above the ground, at ``distances_rel`` times the support's median
    distance from the camera (a relative depth map gives the same candidates)."""
    pts = fp.support_points
    aim = np.median(pts, 0)
    scale = float(np.median(np.linalg.norm(pts, axis=1)))
    W = fibonacci_sphere(2 * int(n_directions))
    W = W[W @ fp.up > 0.1]
    R = scale * np.asarray(distances_rel, np.float64)
    return (aim[None, None] + R[None, :, None] * W[:, None, :]).reshape(-1, 3)


__all__ = ["FitPixels", "working_copy", "fit_pixels", "ground_radiance", "bounce", "sky_visibility",
           "sky_lobes", "sky_atom_values", "specular_roughness", "offset_shading", "sun_columns",
           "sun_column", "lamp_columns", "lamp_candidates"]
