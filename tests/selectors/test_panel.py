"""The canonical view panel: a 2x2 grid of labelled, non-blank views."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

from grt.selectors.keypoints import sample_keypoints
from grt.selectors.panel import render_panel


def test_panel_has_four_labelled_views(box):
    kp = sample_keypoints(box)
    png = render_panel(kp.frame.to_unit(box.vertices), box.faces, kp.positions, size_px=512)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(float)
    assert img.shape == (512, 512, 3)
    for r in (0, 256):
        for c in (0, 256):
            quad = img[r + 2:r + 254, c + 2:c + 254]
            drawn = (quad.min(-1) < 200).mean()
            assert 0.02 < drawn < 0.9  # a mesh was drawn, not a blank or a filled square
            label = img[r + 4:r + 40, c + 4:c + 40]  # the A-D letter sits in the top-left corner
            assert (label.max(-1) < 80).sum() > 20
            # colored pixels: keypoints (viridis) and the RGB axes
            assert (quad.max(-1) - quad.min(-1) > 100).sum() > 50


def test_panel_differs_between_views_and_objects(box, sphere):
    kp = sample_keypoints(box)
    png = render_panel(kp.frame.to_unit(box.vertices), box.faces, kp.positions, size_px=256)
    img = np.asarray(Image.open(io.BytesIO(png)).convert("L")).astype(float)
    quads = [img[r:r + 128, c:c + 128] for r in (0, 128) for c in (0, 128)]
    for i in range(4):
        for j in range(i + 1, 4):
            assert np.abs(quads[i] - quads[j]).mean() > 1.0  # four different viewpoints
