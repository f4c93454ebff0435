"""The preview sheet: the photograph with the balls composited in, beside the balls alone
(zoomed, on a neutral grey), the light's numbers underneath. One sRGB PNG per scene."""

from __future__ import annotations

import numpy as np

# the backdrop behind the balls alone: mid-grey in sRGB (0.5 encoded), so that neither a
# dark nor a bright ball vanishes into it
BACKDROP_LINEAR = 0.214
# text: 8-bit sRGB colours and the font size (pixels) of the numbers
TEXT_RGB = (235, 235, 235)
PANEL_RGB = (28, 28, 28)
FONT_PX = 14
GAP_PX = 8


def make_sheet(composite: np.ndarray, alone_rgba: np.ndarray, lines: list[str], title: str) -> np.ndarray:
    """(H', W', 3) uint8 sRGB sheet.

    Args:
        composite: (H, W, 3) linear RGB, the photograph with the balls.
        alone_rgba: (h, w, 4) linear RGB and alpha, the balls alone.
        lines: the light's numbers (``summary.light_lines``), one per line.
        title: the sheet's heading (the scene's name).
    """
    from PIL import Image, ImageDraw, ImageFont

    from zcomp_cli.imageio import to_uint8_srgb

    comp = np.asarray(composite, np.float32)
    H, W = comp.shape[:2]
    a = np.asarray(alone_rgba, np.float32)
    rgb = a[..., :3] + (1.0 - np.clip(a[..., 3:4], 0.0, 1.0)) * BACKDROP_LINEAR
    left = Image.fromarray(to_uint8_srgb(comp))
    right = Image.fromarray(to_uint8_srgb(rgb))
    # the balls alone at the composite's height (their aspect kept), at most its width
    s = min(H / right.height, W / right.width)
    right = right.resize((max(1, round(right.width * s)), max(1, round(right.height * s))), Image.LANCZOS)
    font = ImageFont.load_default(size=FONT_PX)
    width = W + GAP_PX + right.width
    wrapped = [title] + [w for ln in lines for w in _wrap(ln, font, width - 2 * GAP_PX)]
    line_h = FONT_PX + 4
    text_h = GAP_PX * 2 + line_h * len(wrapped)
    sheet = Image.new("RGB", (width, H + text_h), PANEL_RGB)
    sheet.paste(left, (0, 0))
    sheet.paste(right, (W + GAP_PX, (H - right.height) // 2))
    draw = ImageDraw.Draw(sheet)
    y = H + GAP_PX
    for k, ln in enumerate(wrapped):
        draw.text((GAP_PX, y), ln, fill=(255, 255, 255) if k == 0 else TEXT_RGB, font=font)
        y += line_h
    return np.asarray(sheet)


def _wrap(text: str, font, width_px: int) -> list[str]:
    """``text`` broken at spaces into lines at most ``width_px`` wide (a longer word
    stands alone)."""
    out, cur = [], ""
    for word in text.split(" "):
        trial = word if not cur else f"{cur} {word}"
        if cur and font.getlength(trial) > width_px:
            out.append(cur)
            cur = "    " + word
        else:
            cur = trial
    if cur:
        out.append(cur)
    return out


__all__ = ["make_sheet"]
