"""The soil-raft interface as both leaves receive it: points (x, y) on the plane z = 0 with the
tributary area of each, checked once for the BEM mesh (soil_impedance.mesh) and for the raft
(structure.model)."""
from __future__ import annotations

import numpy as np


def interface_points(xy, area, error=ValueError, what: str = "interface") -> tuple[np.ndarray, np.ndarray]:
    """(xy (N, 2) m, area (N,) m^2) as read-only float arrays, or ``error`` naming what is wrong:
    N >= 1 points of finite coordinates, one finite area > 0 per point. ``what`` names the
    points in the message ("mesh", "raft")."""
    xy = np.array(xy, dtype=float)
    area = np.array(area, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2 or xy.shape[0] == 0:
        raise error(f"{what} nodes must be an (n, 2) array of x, y with n >= 1, got shape {xy.shape}")
    if area.shape != (xy.shape[0],):
        raise error(f"{what} areas must have one value per node ({xy.shape[0]}), got shape {area.shape}")
    if not np.all(np.isfinite(xy)):
        raise error(f"{what} node coordinates must be finite numbers")
    bad = np.flatnonzero(~(area > 0) | ~np.isfinite(area))
    if bad.size:
        raise error(f"{what} node {bad[0]} has area {float(area[bad[0]]):g}: every tributary area must be > 0")
    xy.setflags(write=False)
    area.setflags(write=False)
    return xy, area
