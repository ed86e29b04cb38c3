"""How much of a track was flown, in order, and the path error against the right part of it.

The track's centreline parts, in track order, are joined into one route (a gap between parts
is part of the route: the vehicle has to cross it) and resampled every `STEP_M`. A cursor
walks the route with the vehicle: at each recorded position the route samples from
`BACK_M` behind the cursor to `AHEAD_M` ahead of it are the candidates; the cursor
moves forward to the nearest candidate when that is within `tol_m` of the vehicle. So the
cursor follows a vehicle that flies the track, cannot jump to another leg that crosses or
comes near (a figure-eight's crossing, a hairpin's other side), and stops where the vehicle
left the line.

- coverage: the cursor's final arc length over the route's length (1.0 = flown to the end,
  in order);
- path error: the distance from the vehicle to the route between the cursor's window ends,
  i.e. to the part the vehicle should be on, not to the nearest point of any part.
"""

from __future__ import annotations

import numpy as np

STEP_M = 0.01      # m, route resampling
BACK_M = 0.30      # m behind the cursor still counted as the vehicle's part of the route
AHEAD_M = 0.50     # m ahead: how far the cursor may move between two recorded positions


def route(parts: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(K, 2) route samples about every STEP_M along the parts joined in order, and their arc
    lengths (K,) m."""
    pts = np.concatenate([np.asarray(p, dtype=float) for p in parts])
    keep = np.concatenate(([True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9))
    pts = pts[keep]
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = np.concatenate(([0.0], np.cumsum(seg)))
    if s[-1] == 0.0:
        return pts[:1], np.zeros(1)
    q = np.linspace(0.0, s[-1], int(np.ceil(s[-1] / STEP_M)) + 1)
    return np.column_stack((np.interp(q, s, pts[:, 0]), np.interp(q, s, pts[:, 1]))), q


def _to_segments(R: np.ndarray, lo: int, hi: int, p: np.ndarray) -> float:
    """Exact distance from p to the polyline R[lo:hi] (not just to its samples)."""
    A = R[lo:hi - 1]
    AB = R[lo + 1:hi] - A
    AP = p - A
    s = np.clip(np.einsum("ij,ij->i", AP, AB) / np.maximum(np.einsum("ij,ij->i", AB, AB),
                                                            1e-18), 0.0, 1.0)
    D = AP - s[:, None] * AB
    return float(np.sqrt(np.einsum("ij,ij->i", D, D).min()))


def track_progress(parts: list[np.ndarray], xy: np.ndarray, tol_m: float
                   ) -> tuple[float, np.ndarray]:
    """(coverage in [0, 1], path error (M,) m) of the positions `xy` (M, 2) flown in order."""
    R, arc = route(parts)
    n = len(R)
    back, ahead = int(round(BACK_M / STEP_M)), int(round(AHEAD_M / STEP_M))
    cur = 0
    err = np.empty(len(xy))
    for i, p in enumerate(np.asarray(xy, dtype=float)):
        lo, hi = max(0, cur - back), min(n, cur + ahead + 1)
        d = np.hypot(R[lo:hi, 0] - p[0], R[lo:hi, 1] - p[1])
        j = int(np.argmin(d))
        err[i] = _to_segments(R, lo, hi, p) if hi - lo > 1 else d[j]
        if d[j] <= tol_m:
            cur = max(cur, lo + j)
    return (float(arc[cur] / arc[-1]) if arc[-1] > 0 else 0.0), err
