"""Render passes for compositors (compositing/aovs.py): they recombine into the composite."""

import numpy as np

from zcomp_cli.compositing.aovs import LAYERS, aov_layers, channel_names, recombine
from zcomp_cli.compositing.compositor import composite


def test_the_layers_recombine_into_the_composite():
    rng = np.random.default_rng(3)
    H, W = 24, 32
    bg = rng.uniform(0.0, 4.0, (H, W, 3)).astype(np.float32)  # HDR plate
    f_bg = rng.uniform(0.1, 1.0, (H, W, 3)).astype(np.float32)
    f_comp = f_bg * rng.uniform(0.3, 1.0, (H, W, 1)).astype(np.float32)
    s = np.zeros((H, W), bool)
    s[6:18, 8:26] = True
    m = np.zeros((H, W), np.float32)
    m[9:15, 12:20] = 1.0
    m[9, 12:20] = 0.4  # an anti-aliased edge
    res = composite(bg, f_bg, f_comp, s, m)
    layers = aov_layers(bg, f_bg, f_comp, res.ratio_blurred, m, res.balance, res.image)
    assert set(layers) == set(LAYERS) and all(v.dtype == np.float32 for v in layers.values())
    assert layers["object"].shape == (H, W, 4) and layers["shadow"].shape == (H, W, 1)
    assert np.allclose(recombine(layers), res.image, atol=1e-5)
    data, names = channel_names(layers)
    assert data.shape == (H, W, len(names)) and "object.A" in names and "shadow.Y" in names
    assert len(set(names)) == len(names)
