"""Front-facing pinhole camera on flat ground, rendered by looking up the road map.

The camera looks level along the car's heading; the image is the 64 rows just below the
horizon (the paper cropped the sky away), 128 wide, grayscale. Every pixel sees a fixed
ground point in the car's frame, so rendering is one rotation and one table lookup per pixel.
"""

from __future__ import annotations

import numpy as np

from actors.envs.road_map import RES, RoadMap

WIDTH, HEIGHT = 128, 64
FOCAL = 100.0  # pixels; 65 degrees horizontal field of view
CAM_HEIGHT = 1.5  # metres above the road (default; EnvConfig.camera_height)
CAM_FORWARD = 1.0  # metres ahead of the car's reference point
HORIZON_GAP = 2.0  # rows between the horizon and the top of the crop: the top row sees 40 x height


def ground_points(height: float = CAM_HEIGHT) -> tuple[np.ndarray, np.ndarray]:
    """Forward and left distance (m, car frame) of the ground point under every pixel centre."""
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    down = (v + 0.5 + HORIZON_GAP) / FOCAL  # tangent of the ray's angle below the horizon
    forward = height / down
    left = -forward * (u + 0.5 - WIDTH / 2) / FOCAL
    return (forward + CAM_FORWARD).ravel(), left.ravel()


class Camera:
    """Renders (n, 64, 128) uint8 frames for n cars, each on its own road map."""

    def __init__(self, height: float = CAM_HEIGHT) -> None:
        fwd, left = ground_points(height)
        self._fwd = (fwd / RES).astype(np.float32)
        self._left = (left / RES).astype(np.float32)

    def render(
        self, maps: list[RoadMap], x: np.ndarray, y: np.ndarray, theta: np.ndarray, luts: np.ndarray, out: np.ndarray
    ) -> None:
        """Write each car's frame into out[i], mapped through its brightness table luts[i] (n, 256)."""
        c = np.cos(theta).astype(np.float32)[:, None]
        s = np.sin(theta).astype(np.float32)[:, None]
        ox = np.array([(xi - m.x0) / RES for xi, m in zip(x, maps)], np.float32)[:, None]
        oy = np.array([(yi - m.y0) / RES for yi, m in zip(y, maps)], np.float32)[:, None]
        gx = c * self._fwd - s * self._left + ox
        gy = s * self._fwd + c * self._left + oy
        for i, m in enumerate(maps):
            out[i] = luts[i].take(m.lookup(gx[i], gy[i])).reshape(HEIGHT, WIDTH)
