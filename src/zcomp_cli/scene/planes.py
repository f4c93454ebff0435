"""The scene's walls beyond the frame: large vertical planes of the known geometry,
extended past the frame's edges, as occluders of the sky and of the lights.

Screen-space rays see only what the frame shows: a ray that leaves the frame counts as
unoccluded. A wall seen at the frame's edge goes on past it, and it hides the sky and
the sun from the floor in front of it: on the benchmark's scenes the radiance-weighted
sky visible from an object's base was 0.57 where the screen-space march found 1.0 (a
side wall three metres away, out of the frame at the object's depth).

A **wall** is a plane of the known geometry whose normal is horizontal (within
``wall_vertical_deg`` of the ground), holding pixels that touch the frame's left or right
edge (what is cut by the frame sideways goes on sideways; a box's face inside the
frame, or cut only by the top, is no wall), at
least ``min_wall_share`` of the valid pixels. It is taken to go on without end along the
ground, and up to the highest of its pixels: as high as it is seen to go (taken without
end where it reaches the frame's top, it hid the sun from most of the floor of a scene
whose wall was three metres tall).
Found by voting: normals binned by azimuth, then the offsets ``n . p`` of the bin's
pixels binned at ``wall_offset_bin_rel`` of their median depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zcomp_cli.scene.config import FrameConfig



@dataclass(frozen=True)
class Wall:
    """A vertical plane ``normal . p = offset`` (camera frame; ``normal`` unit, toward
    the camera's side), standing on the ground ``up . p = ground`` up to ``top`` metres
    above it (inf: without end)."""

    normal: np.ndarray
    offset: float
    top: float
    ground: float
    up: np.ndarray

    def to_info(self) -> dict:
        return {"normal_camera": np.asarray(self.normal).tolist(), "offset_m": self.offset,
                "top_m": None if not math.isfinite(self.top) else self.top}

    def to_dict(self) -> dict:
        """Every field, exactly (``from_dict`` takes it back; an endless wall's top None)."""
        return {**self.to_info(), "ground_m": float(self.ground), "up_camera": np.asarray(self.up).tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "Wall":
        return cls(normal=np.asarray(d["normal_camera"], np.float64), offset=float(d["offset_m"]),
                   top=math.inf if d["top_m"] is None else float(d["top_m"]), ground=float(d["ground_m"]),
                   up=np.asarray(d["up_camera"], np.float64))


def find_walls(points: np.ndarray, normals: np.ndarray, valid: np.ndarray, up, cfg: FrameConfig | None = None) -> tuple:
    """The walls of a frame's geometry (module docstring).

    Args:
        points: (h, w, 3) camera-frame points; normals: (h, w, 3) unit; valid: (h, w).
        up: (3,) world up.
    Returns:
        tuple of Wall, the largest first.
    """
    cfg = FrameConfig() if cfg is None else cfg
    up = np.asarray(up, np.float64)
    h, w = valid.shape
    P = points[valid].astype(np.float64)
    Nn = normals[valid].astype(np.float64)
    ys, xs = np.nonzero(valid)
    n_valid = len(P)
    if n_valid < 10:
        return ()
    horiz = np.abs(Nn @ up) < math.sin(math.radians(cfg.wall_vertical_deg))
    floor_pts = P[(Nn @ up) > math.cos(math.radians(cfg.wall_vertical_deg))]
    ground = float(np.median(floor_pts @ up)) if len(floor_pts) else float(np.min(P @ up))
    from zcomp_cli.worldframe import ground_frame

    right, _, fwd = ground_frame(up)
    az = np.arctan2(Nn @ fwd, Nn @ right)
    nb = cfg.wall_azimuth_bins
    bins = np.floor((az + math.pi) / (2 * math.pi) * nb).astype(int) % nb
    used = np.zeros(n_valid, bool)
    walls = []
    for _ in range(cfg.max_walls):
        cand = horiz & ~used
        if cand.sum() < cfg.min_wall_share * n_valid:
            break
        counts = np.bincount(bins[cand], minlength=nb)
        # a bin with its neighbours (a plane's normals straddle a bin edge)
        wide = counts + np.roll(counts, 1) + np.roll(counts, -1)
        b = int(np.argmax(wide))
        sel = cand & (np.abs(((bins - b + nb // 2) % nb) - nb // 2) <= 1)
        n = Nn[sel].mean(0)
        n = n - up * float(n @ up)
        if np.linalg.norm(n) < 1e-6:
            break
        n /= np.linalg.norm(n)
        off = P[sel] @ n
        z = float(np.median(-P[sel][:, 2]))
        step = max(cfg.wall_offset_bin_rel * z, 1e-6)
        ob = np.round(off / step).astype(int)
        vals, cnt = np.unique(ob, return_counts=True)
        d = float(np.median(off[np.abs(ob - vals[np.argmax(cnt)]) <= 1]))
        inl = cand & (np.abs(P @ n - d) < 1.5 * step) & ((Nn @ n) > math.cos(math.radians(cfg.wall_vertical_deg)))
        used |= inl | sel
        if inl.sum() < cfg.min_wall_share * n_valid:
            continue
        yi, xi = ys[inl], xs[inl]
        if not (xi.min() == 0 or xi.max() == w - 1):
            # cut by neither side: it ends in the frame sideways (a box's face cut only by
            # the top goes on upward, not 100 m along the ground)
            continue
        if d > 0:  # facing away from the camera: its back is no wall we see
            continue
        top = float((P[inl] @ up).max() - ground)
        walls.append(Wall(normal=n, offset=d, top=top, ground=ground, up=up))
    return tuple(walls)


def walls_block(walls, points: np.ndarray, dirs: np.ndarray, max_t=None):
    """Whether rays from ``points`` (N, 3) along unit ``dirs`` ((N, 3) or (3,)) meet a
    wall within ``max_t`` ((N,) or scalar metres; None: any distance): (blocked (N,)
    bool, distance (N,), inf where not)."""
    P = np.asarray(points, np.float64).reshape(-1, 3)
    D = np.broadcast_to(np.asarray(dirs, np.float64), P.shape)
    blocked = np.zeros(len(P), bool)
    dist = np.full(len(P), np.inf)
    for wl in walls:
        s = P @ wl.normal - wl.offset  # > 0: on the camera's side
        c = D @ wl.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where((s > 1e-6) & (c < -1e-9), s / -c, np.inf)
        hit_h = (P + np.where(np.isfinite(t), t, 0.0)[:, None] * D) @ wl.up - wl.ground
        hit = np.isfinite(t) & (hit_h < wl.top)
        if max_t is not None:
            hit &= t < np.broadcast_to(np.asarray(max_t, np.float64), t.shape)
        dist = np.where(hit, np.minimum(dist, t), dist)
        blocked |= hit
    return blocked, dist


__all__ = ["Wall", "find_walls", "walls_block"]
