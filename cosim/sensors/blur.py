"""Motion blur of the front camera (``[camera] exposure_s``): the streak the image moves by
while the shutter is open.

Model, chosen to be cheap (one small convolution per frame): the image motion of the image
centre over the exposure, applied to the whole frame as a linear blur kernel. The exposure is
centred on the capture instant; the velocity and body rates are those of the vehicle at
capture, held over the exposure (at most tens of ms). The centre's image velocity is the
classical one of a point at depth Z on the optical axis (Chaumette & Hutchinson, "Visual servo
control I", IEEE RAM 2006, the interaction matrix at x = y = 0):

    du/dt = fx (-v_x / Z - w_y),    dv/dt = fy (-v_y / Z + w_x)

with the camera's velocity v and angular velocity w relative to the world in the rendered
view's axes (x right, y down, z optical axis), and Z the depth of the surface at the image
centre (one ray cast against the world's surfaces; nothing hit: the translation adds nothing).
A stabilized camera's view is level, but the sensor is rigid on the body: its body rates blur
the frame all the same (digital stabilization re-frames a frame after it is exposed), so w is
the body's angular velocity, expressed in the view's axes.

What this leaves out: the image motion away from the centre (the radial streaks of a forward
motion, ~x v_z T / Z: 0.6 px at the image edge at 0.3 m/s, 2 m, 10 ms; the (1 + x^2) growth of
the rotational streaks towards the edges, +64 % at the left and right edges of the Bebop 2's
77 deg field of view) and a rolling shutter. Averaging renders over the exposure would model
those but costs one render (~5 ms) per sample.

The kernel: the segment from -d/2 to +d/2 (d = (du, dv) px), sampled every half pixel and
splatted bilinearly, normalised to 1 (a box exposure); no blur below ``BLUR_MIN_PX``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

BLUR_MIN_PX = 0.01        # px, a streak shorter than this is no blur (the frame unchanged)


def centre_depth(surfaces, c: np.ndarray, axis: np.ndarray, near: float) -> float:
    """z (m) of the nearest surface hit by the ray from c along the unit optical axis (seen
    from its visible side, at least `near` away); inf if none."""
    hits = []                       # (distance, order, surface) of the planes ahead
    for i, s in enumerate(surfaces):
        nrm = s.normal
        den = float(axis @ nrm)
        if den >= -1e-12:           # seen edge-on or from behind (culled as in the renders)
            continue
        lam = float(nrm @ (s.O - c)) / den
        if lam >= near:
            hits.append((lam, i, s))
    hits.sort()
    for lam, _, s in hits:          # nearest first: the first inside its outline is it
        X = c + lam * axis - s.O
        if _inside_point(float(X @ s.U), float(X @ s.V), s.outline().tolist()):
            return lam
    return math.inf


def _inside_point(x: float, y: float, poly: list) -> bool:
    """raycast._inside for one point, in Python floats (the same operations in the same
    order, so the same answer bit for bit; a tenth of the numpy version's cost)."""
    pos = neg = True
    k = len(poly)
    for i in range(k):
        a0, a1 = poly[i]
        b0, b1 = poly[(i + 1) % k]
        cr = (b0 - a0) * (y - a1) - (b1 - a1) * (x - a0)
        pos = pos and cr >= -1e-12
        neg = neg and cr <= 1e-12
    return pos or neg


def streak_px(fx: float, fy: float, v_C, w_C, depth: float, exposure_s: float
              ) -> tuple[float, float]:
    """(du, dv) px the image centre moves over the exposure (see the module docstring)."""
    inv_z = 0.0 if not math.isfinite(depth) or depth <= 0.0 else 1.0 / depth
    du = fx * (-v_C[0] * inv_z - w_C[1]) * exposure_s
    dv = fy * (-v_C[1] * inv_z + w_C[0]) * exposure_s
    return du, dv


def kernel(du: float, dv: float) -> np.ndarray | None:
    """The linear blur kernel of a streak (du, dv) px, centred; None below BLUR_MIN_PX."""
    length = math.hypot(du, dv)
    if length < BLUR_MIN_PX:
        return None
    rx = int(abs(du) / 2.0) + 1
    ry = int(abs(dv) / 2.0) + 1
    k = np.zeros((2 * ry + 1, 2 * rx + 1), np.float64)
    n = max(2, int(math.ceil(2.0 * length)) + 1)
    s = np.linspace(-0.5, 0.5, n)
    xs = rx + s * du
    ys = ry + s * dv
    x0 = np.floor(xs).astype(np.int64)
    y0 = np.floor(ys).astype(np.int64)
    fx = xs - x0
    fy = ys - y0
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                      (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(k, (y0 + dy, x0 + dx), w)
    k /= k.sum()
    return k.astype(np.float32)


def apply(img: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The frame convolved with the kernel (edges replicated), uint8 rounded."""
    return cv2.filter2D(img, -1, k, borderType=cv2.BORDER_REPLICATE)
