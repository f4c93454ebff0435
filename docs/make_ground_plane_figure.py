"""Draw docs/ground_plane.png: what the ground-plane depth proxy assumes.

Run: .venv/bin/python docs/make_ground_plane_figure.py
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from zcomp_cli.camera import Camera  # noqa: E402
from zcomp_cli.estimators.ground_plane import GroundPlaneSpec, ground_plane_depth  # noqa: E402


def main(out: Path = Path(__file__).with_name("ground_plane.png")) -> None:
    h, pitch, backdrop, fov = 1.5, -15.0, 8.0, 50.0
    cam = Camera.from_fov(fov, 320, 240)
    spec = GroundPlaneSpec(h, pitch_deg=pitch, backdrop_distance_m=backdrop)
    depth, normals = ground_plane_depth(cam, spec)

    fig, (ax0, ax1, ax2) = plt.subplots(1, 3, figsize=(15, 4.2))
    # Side view (world: forward horizontal, up vertical).
    p = math.radians(pitch)
    vfov = 2 * math.atan(cam.height / 2 / cam.fy)
    ax0.axhline(0, color="saddlebrown", lw=3, label="floor (y = 0)")
    ax0.plot([0], [h], "ko")
    ax0.annotate(f"camera, height {h} m", (0, h), (0.2, h + 0.35))
    for a, style in ((p, "k-"), (p + vfov / 2, "b--"), (p - vfov / 2, "b--")):
        dx, dy = math.cos(a), math.sin(a)
        t = min(-h / dy if dy < 0 else np.inf, (backdrop + 2) / dx)
        ax0.plot([0, t * dx], [h, h + t * dy], style, lw=1)
    ax0.text(1.5, h + 0.1 + 1.5 * math.tan(p), f"pitch {pitch:g} deg", rotation=pitch)
    # Backdrop: a fronto-parallel plane at z-depth `backdrop` (drawn for the optical axis).
    bx = backdrop * math.cos(p)
    by = h + backdrop * math.sin(p)
    ux, uy = -math.sin(p), math.cos(p)
    s0 = max(-3.0, -by / uy)  # the floor hides the backdrop below it
    ax0.plot([bx + s0 * ux, bx + 3 * ux], [by + s0 * uy, by + 3 * uy], "g-", lw=3,
             label=f"backdrop, z-depth {backdrop:g} m")
    ax0.set_xlim(-0.5, backdrop + 2)
    ax0.set_ylim(-0.5, 4)
    ax0.set_aspect("equal")
    ax0.set_xlabel("forward (m)")
    ax0.set_ylabel("up (m)")
    ax0.set_title("side view: what the proxy assumes")
    ax0.legend(loc="upper left", fontsize=8)

    im = ax1.imshow(depth, cmap="turbo")
    ax1.set_title("z-depth (m): floor below the horizon, backdrop above")
    fig.colorbar(im, ax=ax1, fraction=0.035)
    ax2.imshow(np.clip(normals * 0.5 + 0.5, 0, 1))
    ax2.set_title("normals (camera frame) * 0.5 + 0.5")
    for ax in (ax1, ax2):
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
