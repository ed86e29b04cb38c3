"""The general preset's look-ahead measured along the line, and its erosion no wider than the
line in view (issue 27): methods of ``cosim.apps.ips.ImageProcessor``, which holds the
state they read (``params``, the crop geometry, ``prev_seen``, ``_ref_dir``, the frame's
kernel). See the module docstring of ``cosim.apps.ips``."""

from __future__ import annotations

import math

import cv2
import numpy as np


class AlongLine:
    """Mixed into ``ImageProcessor`` (no state of its own)."""

    def _frame_kernel(self, crop: np.ndarray) -> tuple[np.ndarray, float]:
        """(square erosion kernel, VTP half-pixel shift) for this frame. ``measured_width``:
        the kernel is no wider than half the line in view, measured on the ring (twice the
        median distance of the set ring pixels to the line's edge ~ half its width), and at
        most the configured one: a line thinner than the configured ``line_width_m``, or seen
        from higher up, is not eroded away."""
        k = self.params.square_kernel
        if self.params.measured_width:
            on = crop.ravel()[self._ring_idx] > 0
            if np.count_nonzero(on) >= 3:
                dt = cv2.distanceTransform((crop > 0).astype(np.uint8), cv2.DIST_L2,
                                           cv2.DIST_MASK_PRECISE)
                half = 2.0 * float(np.median(dt.ravel()[self._ring_idx][on]))
                k = max(1, min(k, int(round(half))))
        kern = self._kernels.get(k)
        if kern is None:
            kern = self._kernels[k] = np.ones((k, k), np.uint8)
        return kern, 0.5 * (k - 1) - k // 2

    def _along_line(self, eroded: np.ndarray, thr: float, cos_p: float, sin_p: float
                    ) -> tuple[float, float, int] | None:
        """The look-ahead point measured along the line (``along_line``).

        Grow from the line pixel nearest the image centre through the eroded line, one pixel
        a step, for the ring's radius: the pixels reached in the last two steps form one
        piece per way on (behind, ahead, the other arms at a crossing, both legs of a
        hairpin only once its vertex is that close along the line). A leg that merely passes
        near on the floor (a hairpin's other side, a line crossing further on) is not
        reached, unlike on the ring. The piece nearest the way back is where the drone came
        from; the others are the ways on (no arc: a hairpin's next leg swings through it).
        Several ways on (a junction): the one nearest the direction of the last clean frame
        (one way on, one line wide; it points 0.19 m ahead along the line, so on a bend it
        leads into the turn: an averaged heading lagged behind a crossing on a bend and took
        the other line, and the previous frame's direction is pulled towards the other line
        where the two overlap ahead), the line
        ends within reach counted as ways too (a track that goes straight over a crossing
        and ends just after it), and none if no way lies within the arc of that direction.
        After a miss: the pieces within the search arc. The first sight of the line over a
        crossing (a track whose end crosses its beginning at the start): the piece nearest
        the way the line near the drone leans (the track begins under the drone; the
        crossing line passes through, balanced).

        (row, col) crop coordinates of the chosen point and its pixel count (0: none found);
        None when no line lies under the drone (nearest line pixel farther than r_min / 2
        from the centre: the ring rules apply)."""
        m = (eroded > 0).view(np.uint8)
        idx = np.flatnonzero(m)
        if not idx.size:
            return None
        d2 = self._crop_d2[idx]
        j = int(np.argmin(d2))
        if d2[j] > self._min_vtp_r ** 2:
            return None
        reached = np.zeros_like(m)
        reached.flat[idx[j]] = 1
        steps = [reached]                          # what was reached after each step
        inner = reached
        ks = self._geo_kernels
        n = self._geo_steps
        for i in range(n):
            grown = cv2.bitwise_and(cv2.dilate(reached, ks[i % len(ks)]), m)
            steps.append(grown)
            if i == n - 3:
                inner = reached
            reached = grown
        k, _, stats, cents = cv2.connectedComponentsWithStats(cv2.subtract(reached, inner),
                                                               connectivity=8)
        if k <= 1:
            return 0.0, 0.0, 0
        r0, c0 = self.center_rc
        o_r, o_c = self._crop_origin
        rows, cols = cents[1:, 1].copy(), cents[1:, 0].copy()
        area = stats[1:, cv2.CC_STAT_AREA].copy()
        ex, ey = r0 - (rows + o_r), (cols + o_c) - c0
        rad = np.maximum(np.hypot(ex, ey), 1e-9)
        if not (self.prev_seen and k > 2):
            cand = np.flatnonzero((ey * cos_p + ex * sin_p) / rad >= thr - 1e-12)
        else:
            cb = -(ey * cos_p + ex * sin_p) / rad
            cand = np.delete(np.arange(k - 1), int(np.argmax(cb)))
            if cand.size > 1:                      # a junction: line ends are ways on too
                # a line end: no pixel within a line's width further along
                w = 2 * self._k_frame.shape[0] + 3
                # g: the step at which each pixel was reached (n + 1 - how many of the n + 1
                # snapshots hold it; 0 where never reached)
                g = np.where(reached > 0, n + 1 - np.sum(steps, axis=0, dtype=np.uint8),
                             0).astype(np.uint8)
                tips = (g >= (n + 1) // 2) & (g <= n - 3) & (
                    g >= cv2.dilate(g, np.ones((w, w), np.uint8)))
                kt, _, st, ct = cv2.connectedComponentsWithStats(tips.view(np.uint8),
                                                                 connectivity=8)
                if kt > 1:
                    rows = np.concatenate((rows, ct[1:, 1]))
                    cols = np.concatenate((cols, ct[1:, 0]))
                    area = np.concatenate((area, st[1:, cv2.CC_STAT_AREA]))
                    ex, ey = r0 - (rows + o_r), (cols + o_c) - c0
                    rad = np.maximum(np.hypot(ex, ey), 1e-9)
                    cand = np.concatenate((cand, np.arange(k - 1, k - 1 + kt - 1)))
        if self._start and cand.size > 1:
            # the first sight of the line, over a crossing (a track whose end crosses its
            # beginning under the start; issue 44): the track begins under the drone, so the
            # line near it is lopsided: what the growth reached within a line's width or so
            # of the seed pixel lies towards the way on; a line that passes through (the
            # crossing one) is balanced. The way on is the piece nearest that direction.
            near = steps[min(n, 2 * self._k_frame.shape[0] + 3)]
            rr, cc = np.nonzero(near)
            sr, sc = divmod(int(idx[j]), m.shape[1])
            dx, dy = sr - float(rr.mean()), float(cc.mean()) - sc     # up, right (px)
            if math.hypot(dx, dy) >= 1.0:
                lean = (ey[cand] * dy + ex[cand] * dx) / rad[cand]
                cand = cand[[int(np.argmax(lean))]]
        if not cand.size:
            return 0.0, 0.0, 0
        self._clean = cand.size == 1
        if cand.size > 1:
            cr, sr = math.cos(self._ref_dir), math.sin(self._ref_dir)
            cosh = (ey[cand] * cr + ex[cand] * sr) / rad[cand]
            i = int(np.argmax(cosh))
            if cosh[i] < self._cos_half:           # no way on ahead at this junction
                return 0.0, 0.0, 0
            best = int(cand[i])
        else:
            best = int(cand[0])
        # one way on and a piece one line wide: a clean frame, its direction is the reference
        # for the next junction (a piece wider than a line is a crossing merging ahead: its
        # centroid is pulled towards the other line)
        self._clean = self._clean and area[best] <= 6 * (self._k_frame.shape[0] + 1)
        return float(rows[best]), float(cols[best]), int(area[best])

