"""A textured object that turns: a cylinder wrapped in a printed pattern, drawn in parallel
projection on black."""

import cv2
import numpy as np
import pytest

_RADIUS, _HEIGHT, _SIZE = 40, 80, 128


@pytest.fixture(scope="session")
def cylinder():
    """``draw(azimuth)``: the cylinder seen from ``azimuth`` radians, grey in [0, 1], and its
    box; its label's texture never repeats, so each side looks like itself only."""
    rng = np.random.default_rng(7)
    around = int(2 * np.pi * _RADIUS)
    label = cv2.GaussianBlur(rng.random((_HEIGHT, around)).astype(np.float32), (0, 0), 1.5)
    label = (label - label.min()) / np.ptp(label)
    cols = np.arange(-_RADIUS + 0.5, _RADIUS)

    def draw(azimuth):
        image = np.zeros((_SIZE, _SIZE))
        # A column at x shows the label where the surface faces the camera.
        angle = np.arcsin(cols / _RADIUS) - azimuth
        u = np.mod(angle / (2 * np.pi) * around, around).astype(np.float32)
        map_x = np.tile(u, (_HEIGHT, 1))
        map_y = np.tile(np.arange(_HEIGHT, dtype=np.float32)[:, None], (1, len(cols)))
        body = cv2.remap(label, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        shade = np.sqrt(1 - (cols / _RADIUS) ** 2)     # lit from the camera
        top = (_SIZE - _HEIGHT) // 2
        left = _SIZE // 2 - _RADIUS
        image[top:top + _HEIGHT, left:left + len(cols)] = 0.15 + 0.8 * body * shade
        return image, np.array([left, top, len(cols), _HEIGHT], dtype=float)

    return draw
