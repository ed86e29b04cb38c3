"""Image processing system of the line follower (paper 1, Algorithm 1, and its released code).

Pure and fast: numpy + cv2 on a 160 x 120 RGB frame, precomputed masks, no Python loop over
pixels. One ``ImageProcessor`` per vehicle; it remembers the previous VTP direction.

Steps (reference/minidrone.md §4):

1. Colour conversion and binarisation: ``F = R - G/GG - B/GB``; ``bin = F >= K_T``.
2. Track branch: erode ``bin`` with a square kernel; keep the pixels whose centre lies at a
   distance in [R_min, R_max] from the image centre (59.5, 79.5) (the "ring"); if the track was
   seen in the previous frame keep only those within +-arc_width/2 of the previous VTP
   direction; the VTP is the centroid of what remains. Nothing left: flag_track = False,
   e = 0, and the next frame searches ``search_arc_width`` (released: the whole ring) around
   the last direction. Initial state: "seen", direction lower-left of the image (-3 pi/4).
   Addition (``search_nearest``, on by default): in a search frame the ring pixels are split
   into branches (angular gaps > ``cluster_gap``) and the VTP is the centroid of the branch
   nearest the last direction, not of all of them. With one branch on the ring this is the
   released rule; with two (the leg behind and the leg ahead after an overshoot, or the two
   crossings of a line beside the drone) the released centroid falls between them, near the
   centre, and the follower oscillates between "lost" and "found". Also, a VTP closer than
   r_min/2 to the centre (a ring full of red, e.g. during take-off) does not redefine the
   direction. ``search_nearest=False`` restores the literal released rule; it only matters
   in frames after a miss, which the released state machine never uses for following (its
   first miss latches End-Marker).
   The general preset (issue 27) measures the look-ahead along the line instead
   (``along_line``, see ``ImageProcessor._along_line``): from the line pixel under the drone
   it grows through the eroded line for the ring's radius; the ways reached form separate
   pieces, the one back where the drone came from is dropped, and at a junction the way
   nearest the previous direction (a line end within reach counts) is kept. A hairpin's
   other leg or a crossing line that only passes near is not reached; an X is passed
   straight. With no line under the drone (a start beside it, a gap) the ring rules apply.
   ``measured_width``: the square kernel is no wider than half the line in view (measured on
   the ring from the distance transform), so a line thinner than configured is kept.
3. Marker branch (the released code evaluates it only after the track is lost): erode ``bin``
   with a disk kernel; the marker is the centroid of all remaining pixels; found if any.

Image conventions (reference §3): row down, col right, 0-based; errors in pixels
``e_x = -(row - 59.5)`` (image up = body forward, positive) and ``e_y = col - 79.5`` (image
right = body right, positive). Directions are ``atan2(e_x, e_y)`` in rad (0 = right,
+pi/2 = up). The centre is the exact image centre ((H-1)/2, (W-1)/2), the camera's principal
point (cosim.sensors.camera); the released MATLAB uses COG = (60, 80) in 1-based indices,
i.e. half a pixel off the exact centre.

Paper (Table I) vs released code (``variables.m``), both available as presets:

=====================  ===========================  ==================================
item                   paper (``IPSParams.paper``)   released (``IPSParams.released``)
=====================  ===========================  ==================================
threshold K_T          150                          100
track erosion          square, size not given:      8 x 8 square
                       we use the released 8 x 8
marker erosion         circular, size not given:    disk of radius 11
                       we use the released r = 11
ring radii             R_min 26, R_max 28 px        27 / 28 px
arc width              2.3 rad                      2 pi / 2.9 = 2.17 rad
GG, GB                 2, 2                         2, 2
=====================  ===========================  ==================================

Implementation notes:

- Binarisation is one ``cv2.transform`` computing ``sat_u8(64 (F - K_T) + 1)`` (exact for
  GG = GB = 2, where F is a multiple of 0.5; within 1/128 otherwise).
- Erosion is ``cv2.erode`` (outside the frame counts as set, like MATLAB's imerode). An even
  kernel (8 x 8) has no centre pixel: cv2 anchors it at (4, 4), which shifts the eroded set by
  half a pixel down-right; the VTP is corrected by that half pixel (MATLAB's own anchor is
  biased the other way).
- The track branch binarises and erodes only a crop holding the ring plus the kernel's reach:
  the ring pixels get exactly the values the full frame would give.
- Marker kernel: ``marker_kernel = "octagon"`` (default) erodes by a (2a+1)-square and then
  r - a times by the 3 x 3 cross, a = round(r (sqrt 2 - 1)): the Minkowski sum is an octagon of
  inradius r (r = 11: a 23 x 23 octagon). MATLAB's ``strel('disk', r)`` with its default
  n = 4 is itself a decomposition into line elements in 4 directions, i.e. an octagon, so this
  is the closer match, and it is ~3x faster than cv2's 23 x 23 ellipse ("ellipse").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from cosim.apps.ips_along import AlongLine

__all__ = ["IPSParams", "IPSResult", "ImageProcessor"]

_SCALE = 64.0   # binarisation slope, see module docstring


@dataclass(frozen=True)
class IPSParams:
    """Parameters of the image processing system (defaults: the released code)."""

    k_t: float = 100.0                       # threshold on F (0-255 units)
    gg: float = 2.0                          # green divisor, >= 1
    gb: float = 2.0                          # blue divisor, >= 1
    square_kernel: int = 8                   # px, side of the square erosion kernel (track)
    disk_radius: int = 11                    # px, radius of the disk erosion kernel (marker)
    marker_kernel: str = "octagon"           # "octagon" (fast) or "ellipse" (cv2 disk)
    r_min: float = 27.0                      # px, inner ring radius
    r_max: float = 28.0                      # px, outer ring radius
    arc_width: float = 2.0 * math.pi / 2.9   # rad, full width of the arc around the previous
    search_arc_width: float = 2.0 * math.pi  # rad, searched after a miss (2 pi: whole ring)
    search_nearest: bool = True              # after a miss: branch nearest the last direction
    cluster_gap: float = 0.35                # rad, angular gap that separates ring branches
    initial_direction: float = -0.75 * math.pi  # rad, atan2(e_x, e_y): lower-left
    width: int = 160                         # px, frame width
    height: int = 120                        # px, frame height
    # the "general" preset's additions (off in released / paper):
    adaptive_k_t: bool = False               # per frame K_T = clamp(F_p99 / 2, k_t_min, k_t)
    k_t_min: float = 40.0                    # lowest adaptive threshold (F units)
    marker_shape: bool = False               # marker: only in a disc-sized blob wholly in view
    marker_r_px: float = 14.5                # px, the marker disc's radius in the image
    nearest_always: bool = False             # keep only the ring branch nearest the direction
    initial_search: bool = False             # the first frame searches the whole ring
    along_line: bool = False                 # VTP at the look-ahead measured along the line
                                             # from the drone (hairpins, crossings)
    measured_width: bool = False             # track erosion no wider than the line in view

    @classmethod
    def released(cls, **overrides: float) -> IPSParams:
        """The released Simulink code's values (variables.m); the default."""
        return replace(cls(), **overrides)

    @classmethod
    def paper(cls, **overrides: float) -> IPSParams:
        """Table I of the paper; kernel sizes it does not give are the released ones."""
        return replace(cls(k_t=150.0, r_min=26.0, r_max=28.0, arc_width=2.3), **overrides)

    @classmethod
    def general(cls, *, camera_height_m: float, vfov_deg: float = 45.0, width: int = 160,
                height: int = 120, line_width_m: float = 0.10, marker_radius_m: float = 0.10,
                lookahead_m: float = 0.19, **overrides: float) -> IPSParams:
        """Pixel constants from the camera model, the height and the line (issue 12): the
        ring at `lookahead_m` on the floor, the track erosion half the line's width, the
        marker erosion three quarters of the marker's radius; adaptive threshold, disc-shaped
        marker, nearest-branch tracking, a first frame that searches the whole ring.
        At the seed mission's 1.0 m camera height this gives the released 27-28 px ring, an
        7 px square (released 8) and an 11 px disk (released 11)."""
        if not (camera_height_m > 0.0 and 0.0 < vfov_deg < 170.0 and line_width_m > 0.0
                and marker_radius_m > 0.0 and lookahead_m > 0.0):
            raise ValueError("camera_height_m, vfov_deg, line_width_m, marker_radius_m and "
                             "lookahead_m must be positive")
        f = 0.5 * height / math.tan(0.5 * math.radians(vfov_deg))     # px
        px = f / camera_height_m                                       # px per metre
        r = lookahead_m * px
        line = line_width_m * px
        marker = marker_radius_m * px
        base = cls(r_min=max(2.0, r - 0.5), r_max=r + 0.5,
                   square_kernel=max(1, int(round(0.5 * line))),
                   disk_radius=max(1, int(round(0.75 * marker))), marker_r_px=marker,
                   width=width, height=height, adaptive_k_t=True, marker_shape=True,
                   nearest_always=True, initial_search=True, along_line=True,
                   measured_width=True)
        return replace(base, **overrides)

    def __post_init__(self) -> None:
        if not 0.0 < self.k_t <= 255.0:
            raise ValueError(f"k_t must be in (0, 255] (F of a plain floor is 0), got {self.k_t}")
        if not (self.gg >= 1.0 and self.gb >= 1.0):
            raise ValueError("gg and gb must be >= 1")
        if not 0 < self.r_min <= self.r_max:
            raise ValueError("need 0 < r_min <= r_max")
        if self.r_max >= min(self.width, self.height) / 2:
            raise ValueError("r_max must fit inside the frame")
        if not (0 < self.arc_width <= 2 * math.pi and 0 < self.search_arc_width <= 2 * math.pi):
            raise ValueError("arc_width and search_arc_width must be in (0, 2 pi]")
        if self.square_kernel < 1 or self.disk_radius < 1:
            raise ValueError("kernel sizes must be positive")
        if self.marker_kernel not in ("octagon", "ellipse"):
            raise ValueError("marker_kernel must be 'octagon' or 'ellipse'")


@dataclass(frozen=True, slots=True)
class IPSResult:
    """One frame's output. Errors in pixels: e_x up-positive, e_y right-positive.

    ``e_x, e_y`` follow Algorithm 1: the VTP's errors if the track was found, else the
    marker's if the marker was found, else 0. ``marker_e_x, marker_e_y`` are always the
    marker's errors (0 when not found or not evaluated).
    """

    flag_track: bool
    flag_marker: bool
    e_x: float
    e_y: float
    vtp_rc: tuple[float, float] | None        # (row, col) of the VTP
    marker_rc: tuple[float, float] | None     # (row, col) of the marker centroid
    marker_e_x: float
    marker_e_y: float
    direction: float                          # rad, atan2(e_x, e_y) of the VTP (or last one)
    n_ring_px: int                            # track pixels kept in the ring/arc
    marker_evaluated: bool                    # whether the marker branch ran
    line_e: tuple[float, float] | None = None  # general preset, nothing on the ring: (e_x,
                                              # e_y) px of the nearest red in view (acquire)


class ImageProcessor(AlongLine):
    """Paper Algorithm 1 with the released code's details; keeps the VTP direction state."""

    def __init__(self, params: IPSParams | None = None) -> None:
        self.params = p = params or IPSParams()
        h, w = p.height, p.width
        self.center_rc = (0.5 * (h - 1), 0.5 * (w - 1))
        r0, c0 = self.center_rc
        # F >= K_T  <=>  64 (R - G/GG - B/GB - K_T) + 1 >= 1 after saturation to uint8
        # cv2 works on the frame as stored (RGB): coefficient order R, G, B.
        self._bin_m = np.array([[_SCALE, -_SCALE / p.gg, -_SCALE / p.gb,
                                 1.0 - _SCALE * p.k_t]], dtype=np.float32)
        k = p.square_kernel
        self._k_square = np.ones((k, k), np.uint8)
        # cv2's anchor is k//2: an even kernel shifts the eroded set by half a pixel (+row,
        # +col); the VTP is corrected by this amount
        self._vtp_shift = 0.5 * (k - 1) - k // 2
        r = p.disk_radius
        if p.marker_kernel == "octagon":
            a = int(round(r * (math.sqrt(2.0) - 1.0)))
            self._k_marker = [(np.ones((2 * a + 1, 2 * a + 1), np.uint8), 1),
                              (cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3)), r - a)]
        else:
            self._k_marker = [(cv2.getStructuringElement(cv2.MORPH_ELLIPSE,
                                                         (2 * r + 1, 2 * r + 1)), 1)]
        # The track branch only needs the eroded image on the ring: work on a crop that holds
        # the ring plus the kernel's reach (same result as the full frame).
        half = int(math.ceil(p.r_max)) + k + 1
        self._crop = (slice(max(0, int(r0) - half), min(h, int(r0) + half + 2)),
                      slice(max(0, int(c0) - half), min(w, int(c0) + half + 2)))
        cr, cc = self._crop
        rows, cols = np.mgrid[cr, cc]
        ex, ey = -(rows - r0), cols - c0
        dist = np.hypot(ex, ey)
        ring = (dist >= p.r_min) & (dist <= p.r_max)
        full = np.mgrid[0:h, 0:w]
        fd = np.hypot(full[0] - r0, full[1] - c0)
        if np.count_nonzero((fd >= p.r_min) & (fd <= p.r_max)) != np.count_nonzero(ring):
            raise ValueError("ring does not fit in the frame")
        self._ring_idx = np.flatnonzero(ring)
        ang = np.arctan2(ex.ravel()[self._ring_idx], ey.ravel()[self._ring_idx])
        self._ring_cos, self._ring_sin = np.cos(ang), np.sin(ang)
        self._ring_ang = ang
        self._min_vtp_r = 0.5 * p.r_min
        self._ring_row = rows.ravel()[self._ring_idx].astype(float)
        self._ring_col = cols.ravel()[self._ring_idx].astype(float)
        # along-line look-ahead: crop-relative squared distance to the centre (the seed is the
        # line pixel nearest it), steps of the geodesic growth (cross, square, cross, cross,
        # square: ~0.99 px per step on the diagonal as on the axes)
        self._crop_d2 = ((rows - r0) ** 2 + (cols - c0) ** 2).ravel()
        self._crop_origin = (cr.start, cc.start)
        cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
        square = np.ones((3, 3), np.uint8)
        self._geo_kernels = (cross, square, cross, cross, square)
        self._geo_steps = max(3, int(round(0.5 * (p.r_min + p.r_max))))
        self._kernels = {k: self._k_square}
        self._k_frame, self._shift_frame = self._k_square, self._vtp_shift
        self._cos_half = math.cos(0.5 * p.arc_width)
        self._cos_half_search = math.cos(0.5 * p.search_arc_width)
        self.reset()

    def _nearest_branch(self, sel: np.ndarray, direction: float) -> np.ndarray:
        """Keep only the ring branch (angular cluster) nearest ``direction``."""
        idx = np.flatnonzero(sel)
        ang = self._ring_ang[idx]
        order = np.argsort(ang)
        a = ang[order]
        gap = self.params.cluster_gap
        labels = np.concatenate(([0], np.cumsum(np.diff(a) > gap)))
        if labels[-1] == 0:
            return sel                                 # a single branch
        if a[0] + 2.0 * math.pi - a[-1] <= gap:        # the branch across +-pi
            labels[labels == labels[-1]] = 0
        c = np.bincount(labels, weights=np.cos(a))
        s = np.bincount(labels, weights=np.sin(a))
        off = np.abs(np.arctan2(s * math.cos(direction) - c * math.sin(direction),
                                c * math.cos(direction) + s * math.sin(direction)))
        off[np.bincount(labels) == 0] = np.inf
        keep = idx[order[labels == int(np.argmin(off))]]
        out = np.zeros_like(sel)
        out[keep] = True
        return out

    def _marker(self, binary: np.ndarray) -> tuple[float, float] | None:
        """Centroid (row, col) of the binary image eroded by the marker kernel, or None."""
        e = binary
        for kernel, n in self._k_marker:
            e = cv2.erode(e, kernel, iterations=n)
        if not cv2.countNonZero(e):
            return None
        idx = np.flatnonzero(e)
        w = self.params.width
        return float((idx // w).mean()), float((idx % w).mean())

    def reset(self) -> None:
        """Back to the initial state: previous track "seen" in the initial direction."""
        self.prev_seen = not self.params.initial_search
        self.prev_direction = self.params.initial_direction
        self._ref_dir = self.prev_direction     # direction of the last clean frame (junctions)
        self._clean = False
        self._start = True                      # no line found yet (ips_along: the start)

    def _threshold_matrix(self, image_rgb: np.ndarray) -> np.ndarray:
        """The binarisation matrix for this frame (adaptive K_T: half the frame's 99th
        percentile of F, within [k_t_min, k_t]: a dark or low-contrast red line still
        passes, a bright one keeps the configured threshold)."""
        p = self.params
        if not p.adaptive_k_t:
            return self._bin_m
        f = cv2.transform(image_rgb, np.array([[1.0, -1.0 / p.gg, -1.0 / p.gb]],
                                               dtype=np.float32))
        k = min(p.k_t, max(p.k_t_min, 0.5 * float(np.percentile(f, 99.0))))
        return np.array([[_SCALE, -_SCALE / p.gg, -_SCALE / p.gb, 1.0 - _SCALE * k]],
                        dtype=np.float32)

    def _nearest_red(self, image_rgb, binary, bin_m) -> tuple[float, float] | None:
        """(e_x, e_y) px of the line pixel (after the track erosion) nearest the image centre,
        or None: where to fly to find the line from a start beside it."""
        if binary is None:
            binary = cv2.transform(image_rgb, bin_m)
        e = cv2.erode(binary, self._k_frame)
        idx = np.flatnonzero(e)
        if not idx.size:
            return None
        w = self.params.width
        r0, c0 = self.center_rc
        rows, cols = idx // w + self._shift_frame, idx % w + self._shift_frame
        k = int(np.argmin((rows - r0) ** 2 + (cols - c0) ** 2))
        return float(r0 - rows[k]), float(cols[k] - c0)

    def _marker_disc(self, binary: np.ndarray) -> tuple[float, float] | None:
        """The released marker test (what survives the disk erosion) kept only where it lies
        in a disc-sized red blob wholly in view: area 0.5-2 pi r^2, at least half of its
        bounding box filled, not cut by the image border. A line's sharp corner belongs to a
        blob whose legs run out of the image and is refused; a marker first seen at the border
        is accepted a few frames later (the planner coasts on). Centroid (row, col) of the
        surviving pixels of the accepted blobs, or None."""
        p = self.params
        e = binary
        for kernel, n in self._k_marker:
            e = cv2.erode(e, kernel, iterations=n)
        if not cv2.countNonZero(e):
            return None
        n, labels, stats, _ = cv2.connectedComponentsWithStats(
            (binary > 0).astype(np.uint8), connectivity=8)
        want = math.pi * p.marker_r_px ** 2
        ok = np.zeros(n, bool)
        for i in range(1, n):
            x, y, w, h, area = (int(v) for v in stats[i])
            inside = x > 0 and y > 0 and x + w < p.width and y + h < p.height
            ok[i] = inside and 0.5 * want <= area <= 2.0 * want and area >= 0.5 * w * h
        idx = np.flatnonzero(e)
        idx = idx[ok[labels.ravel()[idx]]]
        if not idx.size:
            return None
        w = p.width
        return float((idx // w).mean()), float((idx % w).mean())

    # ------------------------------------------------------------------ steps
    def binarise(self, image_rgb: np.ndarray) -> np.ndarray:
        """Full-frame uint8 image, nonzero where F >= K_T (values are not 0/1; test > 0)."""
        p = self.params
        if image_rgb.shape != (p.height, p.width, 3) or image_rgb.dtype != np.uint8:
            raise ValueError(f"expected a {p.height}x{p.width}x3 uint8 RGB frame, got "
                             f"{image_rgb.shape} {image_rgb.dtype}")
        return cv2.transform(image_rgb, self._bin_m)

    def process(self, image_rgb: np.ndarray, detect_marker: bool | None = None,
                forward_only: bool = False) -> IPSResult:
        """Run the IPS on one frame and update the direction state.

        detect_marker: None (released behaviour) runs the marker branch only when the track
        is not found in this frame; True always; False never. forward_only: a search (after
        a miss) looks only at the half ring ahead of the last direction (the planner asks for
        it while it coasts over a gap, so the line behind is not taken for the way on).
        """
        p = self.params
        if image_rgb.shape != (p.height, p.width, 3) or image_rgb.dtype != np.uint8:
            raise ValueError(f"expected a {p.height}x{p.width}x3 uint8 RGB frame, got "
                             f"{image_rgb.shape} {image_rgb.dtype}")
        cr, cc = self._crop
        binary = None
        bin_m = self._threshold_matrix(image_rgb)
        if detect_marker:
            binary = cv2.transform(image_rgb, bin_m)
            crop = binary[cr, cc]
        else:
            crop = cv2.transform(image_rgb[cr, cc], bin_m)
        if p.measured_width:
            k_sq, shift = self._frame_kernel(crop)
        else:
            k_sq, shift = self._k_square, self._vtp_shift
        self._k_frame, self._shift_frame = k_sq, shift
        eroded = cv2.erode(crop, k_sq)
        cos_p, sin_p = math.cos(self.prev_direction), math.sin(self.prev_direction)
        thr = self._cos_half if self.prev_seen else (
            max(0.0, self._cos_half_search) if forward_only else self._cos_half_search)
        r0, c0 = self.center_rc
        along = self._along_line(eroded, thr, cos_p, sin_p) if p.along_line else None
        if along is not None:
            n = along[2]
            o_r, o_c = self._crop_origin
            row, col = along[0] + o_r + shift, along[1] + o_c + shift
        else:
            vals = eroded.ravel()[self._ring_idx]
            sel = vals > 0
            if thr > -1.0:
                sel &= (self._ring_cos * cos_p + self._ring_sin * sin_p) >= thr - 1e-12
            searching = not self.prev_seen
            n = int(np.count_nonzero(sel))
            if n and ((searching and p.search_nearest) or p.nearest_always):
                sel = self._nearest_branch(sel, self.prev_direction)
                n = int(np.count_nonzero(sel))
            if n:
                row = float(self._ring_row[sel].mean()) + shift
                col = float(self._ring_col[sel].mean()) + shift
        if n:
            e_x, e_y = r0 - row, col - c0
            vtp: tuple[float, float] | None = (row, col)
            self.prev_seen = True
            self._start = False
            if math.hypot(e_x, e_y) >= self._min_vtp_r:
                self.prev_direction = math.atan2(e_x, e_y)
                if along is None or self._clean:
                    self._ref_dir = self.prev_direction
        else:
            e_x = e_y = 0.0
            vtp = None
            self.prev_seen = False
        flag_track = n > 0

        run_marker = (not flag_track) if detect_marker is None else detect_marker
        marker_rc: tuple[float, float] | None = None
        mx = my = 0.0
        if run_marker:
            if binary is None:
                binary = cv2.transform(image_rgb, bin_m)
            marker_rc = self._marker_disc(binary) if p.marker_shape else self._marker(binary)
            if marker_rc is not None:
                mx, my = r0 - marker_rc[0], marker_rc[1] - c0
        flag_marker = marker_rc is not None
        if not flag_track and flag_marker:
            e_x, e_y = mx, my
        line_e = None
        if p.initial_search and not flag_track and not flag_marker:
            line_e = self._nearest_red(image_rgb if binary is None else None, binary, bin_m)
        return IPSResult(flag_track=flag_track, flag_marker=flag_marker, e_x=e_x, e_y=e_y,
                         vtp_rc=vtp, marker_rc=marker_rc, marker_e_x=mx, marker_e_y=my,
                         direction=self.prev_direction, n_ring_px=n,
                         marker_evaluated=run_marker, line_e=line_e)
