"""Top-down RGB view for videos: the road map around a car, its recent path and the car."""

from __future__ import annotations

import math

import numpy as np

SIZE = 256  # pixels
SCALE = 0.3  # metres per pixel: an ~77 m square around the car


def render_topdown(sim, i: int) -> np.ndarray:
    """An (SIZE, SIZE, 3) uint8 image, north up, centred on car `i` of a LaneDriveSim."""
    m = sim.maps[i]
    cx, cy = sim.x[i], sim.y[i]
    r, c = np.mgrid[0:SIZE, 0:SIZE]
    wx = cx + (c - SIZE / 2) * SCALE
    wy = cy - (r - SIZE / 2) * SCALE  # row 0 is north
    gray = m.lookup(*m.to_grid(wx.ravel(), wy.ravel())).reshape(SIZE, SIZE)
    img = np.repeat(gray[..., None], 3, axis=2)
    img[..., 1] = np.clip(gray.astype(np.int16) + (gray < 90) * 30, 0, 255)  # grass a little green

    def pix(px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return ((py - cy) / -SCALE + SIZE / 2).astype(int), ((px - cx) / SCALE + SIZE / 2).astype(int)

    path = np.asarray(sim.path[i][-600:])
    pr, pc = pix(path[:, 0], path[:, 1])
    ok = (pr >= 0) & (pr < SIZE) & (pc >= 0) & (pc < SIZE)
    img[pr[ok], pc[ok]] = (230, 40, 40)
    th = sim.theta[i]
    along = np.linspace(-2.2, 2.2, 23)
    across = np.linspace(-0.9, 0.9, 10)
    a, b = np.meshgrid(along, across)
    bx = cx + a * math.cos(th) - b * math.sin(th)
    by = cy + a * math.sin(th) + b * math.cos(th)
    br, bc = pix(bx.ravel(), by.ravel())
    img[br.clip(0, SIZE - 1), bc.clip(0, SIZE - 1)] = (40, 90, 230)
    return img
