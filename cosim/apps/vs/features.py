"""Image side of paper 2's Algorithms 1-2: features, matching, tracking and the homography.

- `Detector`: SIFT (Exps 5.1-5.2), Shi-Tomasi corners (GFTT, Exp 5.3) described with SIFT
  descriptors (ours: the paper names the detector, not the descriptor), or ORB.
- `match`: nearest neighbours with Lowe's ratio test and a one-to-one check, then a robust
  filter (RANSAC on the fundamental matrix: the scene is 3-D; a homography fit when F cannot be
  estimated). RANSAC is seeded (`cv2.setRNGSeed`) so a run is repeatable bit for bit.
- `sort_points`: paper's sortPoints: 1 = max x, 2 = min x, 3 = max y, the rest in order.
- `Tracker`: pyramidal Lucas-Kanade frame to frame (Bouguet), with a forward-backward check.
- `homography`: the Euclidean homography (det 1) that maps current normalised points to the
  target's (m* ~ H m). "virtual_plane": the generic homography of the plane through the 3
  sorted points, compatible with the fundamental matrix (Malis & Chaumette 2000; Hartley &
  Zisserman Result 13.6). Where that is degenerate (all points on one plane, or too little
  baseline left near convergence: one homography then explains the points, median transfer
  error under `planar_px`, and F is ill-conditioned), F cannot be estimated, or the result
  differs from the dominant-plane homography by more than `gate` in any entry (a wild H
  from an ill-conditioned F), the dominant-plane RANSAC homography is used instead, and the result
  says so. "dominant_plane": always that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from cosim.cvthreads import single_thread

DETECTORS = ("sift", "gftt", "orb")
HOMOGRAPHIES = ("virtual_plane", "dominant_plane")
# Every pixel length here (RANSAC thresholds, the LK window, GFTT spacing, the forward-backward
# bound) is given for the Bebop 2's 856-px-wide stream, the paper's, and scales with the
# image's width (`px_scale`): at half the resolution a point's error is half as many pixels.
REF_WIDTH_PX = 856
# The smallest LK window a scaled one gets, in pixels of the image tracked (issue 41's floor
# for the window, applied at every width; docs/papers/visual-servoing.md, "Tracking"): E2 at
# 428 x 240 with the 15 px window scaled to 9 px passed 5 of seeds 0-6 (a collision on seed
# 0), with 11 px 6 of 7; at 11 px the half-size flights are the ones measured before (the
# 100-run study, 90/100)
WIN_MIN_PX = 11


def px_scale(width: int) -> float:
    """Pixels of an image `width` px wide per pixel of the 856-px stream (1.0 at 856)."""
    return int(width) / REF_WIDTH_PX


class Detector:
    def __init__(self, kind: str = "sift", n_max: int = 800) -> None:
        if kind not in DETECTORS:
            raise ValueError(f"detector: got {kind!r}; allowed: {', '.join(DETECTORS)}")
        self.kind = kind
        self.n_max = int(n_max)
        if kind == "orb":
            self._det = cv2.ORB_create(nfeatures=self.n_max)
            self.norm = cv2.NORM_HAMMING
        else:
            self._det = cv2.SIFT_create(nfeatures=self.n_max if kind == "sift" else 0)
            self.norm = cv2.NORM_L2

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N x 2 float32 pixel positions, N x D descriptors). On one OpenCV thread: SIFT
        gathers its keypoints from its threads in the order they finish."""
        with single_thread():
            return self._detect(gray)

    def _detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.kind == "gftt":
            s = px_scale(gray.shape[1])
            block = max(3, 2 * round(2.0 * s) + 1)          # 5 px at 856
            c = cv2.goodFeaturesToTrack(gray, self.n_max, 0.01, 7.0 * s, blockSize=block)
            kps = [] if c is None else [cv2.KeyPoint(float(x), float(y), 16.0 * s)
                                        for x, y in c.reshape(-1, 2)]
            kps, desc = self._det.compute(gray, kps)
        else:
            kps, desc = self._det.detectAndCompute(gray, None)
        if desc is None or not kps:
            return np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32)
        pts = np.array([k.pt for k in kps], dtype=np.float32)
        return pts, desc


def gray_of(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb


def match(det: Detector, pts_a: np.ndarray, desc_a: np.ndarray, pts_b: np.ndarray,
          desc_b: np.ndarray, seed: int, ratio: float = 0.8, ransac_px: float = 1.5,
          px: float = 1.0, quality: bool = False) -> tuple[np.ndarray, ...]:
    """Matched (a, b) pixel positions (M x 2 each) after the ratio test, the one-to-one check
    and the robust filter; empty arrays when fewer than 8 survive. With `quality`, a third
    array: each match's distance ratio to the second-best neighbour (lower: more distinct)."""
    empty = (np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32))
    if quality:
        empty += (np.zeros(0),)
    if len(pts_a) < 8 or len(pts_b) < 8:
        return empty
    bf = cv2.BFMatcher(det.norm)
    pairs = bf.knnMatch(desc_a, desc_b, k=2)
    best: dict[int, tuple[float, int, float]] = {}
    for p in pairs:
        if len(p) == 2 and p[0].distance < ratio * p[1].distance:
            m = p[0]
            if m.trainIdx not in best or m.distance < best[m.trainIdx][0]:
                best[m.trainIdx] = (m.distance, m.queryIdx, m.distance / p[1].distance)
    if len(best) < 8:
        return empty
    ib = np.array(sorted(best), dtype=int)
    ia = np.array([best[i][1] for i in ib], dtype=int)
    a, b = pts_a[ia], pts_b[ib]
    keep = robust_inliers(a, b, seed, ransac_px, px)
    if quality:
        return a[keep], b[keep], np.array([best[i][2] for i in ib])[keep]
    return a[keep], b[keep]


def robust_inliers(a: np.ndarray, b: np.ndarray, seed: int, ransac_px: float = 1.5,
                   px: float = 1.0) -> np.ndarray:
    """Boolean inlier mask of correspondences a <-> b (seeded RANSAC); `ransac_px` at the
    856-px stream, times `px` (`px_scale`)."""
    n = len(a)
    if n < 8:
        return np.zeros(n, bool)
    cv2.setRNGSeed(int(seed))
    F, mask = cv2.findFundamentalMat(a, b, cv2.FM_RANSAC, ransac_px * px, 0.999, 2000)
    if F is None or F.shape != (3, 3) or mask is None:
        cv2.setRNGSeed(int(seed))
        _, mask = cv2.findHomography(a, b, cv2.RANSAC, 3.0 * px)
    if mask is None:
        return np.zeros(n, bool)
    return mask.ravel().astype(bool)


def sort_points(target: np.ndarray, current: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Paper's sortPoints on the target points: 1 = max x, 2 = min x, 3 = max y, rest after."""
    n = len(target)
    if n < 3:
        return target, current
    i1 = int(np.argmax(target[:, 0]))
    i2 = int(np.argmin(target[:, 0]))
    order_y = np.argsort(-target[:, 1], kind="stable")
    i3 = next(int(i) for i in order_y if i not in (i1, i2))
    head = [i1, i2, i3]
    rest = [i for i in range(n) if i not in head]
    idx = np.array(head + rest)
    return target[idx], current[idx]


def spread(pts: np.ndarray, n_max: int, width: int, height: int, score: np.ndarray,
           cols: int = 8, rows: int = 6) -> np.ndarray:
    """Indices (ascending) of at most `n_max` of the points (N x 2 px), spread over the image:
    the image is cut into `cols` x `rows` cells and the points are taken in rounds, one per
    cell a round (each cell's points by ascending `score`); within a round the cells' points
    go by ascending score too (ties: raster order of the cells), so a cap keeps every part of
    the image the matches cover when it can (`n_max` >= the cells holding points), and
    otherwise the best points of a round wherever they are, not the top rows. All of them
    when `n_max` <= 0 or there are no more than that."""
    n = len(pts)
    if n_max <= 0 or n <= n_max:
        return np.arange(n)
    cx = np.clip((pts[:, 0] * (cols / width)).astype(np.int64), 0, cols - 1)
    cy = np.clip((pts[:, 1] * (rows / height)).astype(np.int64), 0, rows - 1)
    cell = cy * cols + cx
    order = np.lexsort((np.arange(n), score, cell))     # by cell, then score, then index
    first = np.searchsorted(cell[order], cell[order])   # where each point's cell starts
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(n) - first                  # the point's place in its cell
    pick = np.lexsort((np.arange(n), cell, score, rank))   # by round, score, cell, index
    return np.sort(pick[:n_max])


class Tracker:
    """Pyramidal LK of the current points from the last frame to this one; points that fail
    or do not come back within `fb_px` (forward-backward) are dropped. The window, the
    pyramid's levels and `fb_px` are the 856-px stream's; on another width they scale with it
    (`px_scale`): the window by the scale (odd) but not below `WIN_MIN_PX` (or the window
    asked for, if smaller), one level fewer per halving, so the coarsest level sees the same
    part of the scene."""

    def __init__(self, win: int, levels: int = 3, fb_px: float = 1.0) -> None:
        self.win, self.levels, self.fb = win, levels, fb_px
        self._width = -1

    def _scaled(self, width: int) -> None:
        s = px_scale(width)
        half = max(1, min(self.win, WIN_MIN_PX) // 2, round((self.win - 1) / 2 * s))
        levels = max(0, self.levels + round(math.log2(s)))
        self.params = dict(winSize=(2 * half + 1, 2 * half + 1), maxLevel=levels,
                           criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
        self.fb_px = self.fb * s
        self._width = width

    def track(self, prev: np.ndarray, cur: np.ndarray, pts: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
        """(new positions N x 2, keep mask N)."""
        if len(pts) == 0:
            return pts, np.zeros(0, bool)
        if cur.shape[1] != self._width:
            self._scaled(cur.shape[1])
        p0 = pts.reshape(-1, 1, 2).astype(np.float32)
        p1, st, _ = cv2.calcOpticalFlowPyrLK(prev, cur, p0, None, **self.params)
        pb, st_b, _ = cv2.calcOpticalFlowPyrLK(cur, prev, p1, None, **self.params)
        fb = np.linalg.norm((pb - p0).reshape(-1, 2), axis=1)
        h, w = cur.shape[:2]
        p1 = p1.reshape(-1, 2)
        inside = (p1[:, 0] >= 0) & (p1[:, 0] < w) & (p1[:, 1] >= 0) & (p1[:, 1] < h)
        keep = st.ravel().astype(bool) & st_b.ravel().astype(bool) & (fb < self.fb_px) & inside
        return p1, keep


@dataclass
class HomographyResult:
    H: np.ndarray | None     # Euclidean, det 1, m* ~ H m; None when it failed
    method: str              # "virtual_plane", "dominant_plane" or "failed"


def _normalise(H: np.ndarray) -> np.ndarray | None:
    d = float(np.linalg.det(H))
    if not np.isfinite(d) or abs(d) < 1e-12:
        return None
    return H / np.cbrt(d)


def _virtual_plane(F: np.ndarray, x: np.ndarray, xp: np.ndarray) -> np.ndarray | None:
    """H (pixels) with xp ~ H x for the first 3 points, compatible with F (xp^T F x = 0)."""
    _, _, Vt = np.linalg.svd(F.T)
    ep = Vt[-1]                           # epipole in the second image: F^T e' = 0
    ex = np.array([[0.0, -ep[2], ep[1]], [ep[2], 0.0, -ep[0]], [-ep[1], ep[0], 0.0]])
    A = ex @ F
    M = np.column_stack((x[:3], np.ones(3)))
    b = np.zeros(3)
    for i in range(3):
        xi = np.array([x[i, 0], x[i, 1], 1.0])
        xpi = np.array([xp[i, 0], xp[i, 1], 1.0])
        c1 = np.cross(xpi, A @ xi)
        c2 = np.cross(xpi, ep)
        den = float(c2 @ c2)
        if den < 1e-18:
            return None
        b[i] = float(c1 @ c2) / den
    if abs(np.linalg.det(M)) < 1e-6:
        return None
    v = np.linalg.solve(M, b)
    return A - np.outer(ep, v)


def homographies(current: np.ndarray, target: np.ndarray, K: np.ndarray, method: str,
                 seed: int, planar_px: float = 2.0, gate: float = 0.3, px: float = 1.0
                 ) -> dict[str, tuple[np.ndarray, np.ndarray] | None]:
    """Both candidate Euclidean homographies from current to target points (pixels, sorted:
    the first 3 define the virtual plane), each with the point m* (normalised, z = 1) its
    error of Eq. 2 is taken at: {"virtual_plane": (H, m*) or None, "dominant_plane": (H, m*)
    or None}. The virtual plane is None where it is degenerate or wild (see the module
    docstring), and always with `method` = "dominant_plane". Its m* is the principal point;
    the dominant plane's is the centroid of its inlier target points (ours, issue 28: Eq. 2
    wants m* on the plane; a side wall as the dominant plane has the principal point far off
    it, and there a forward offset gives no e_v at all)."""
    out: dict[str, tuple[np.ndarray, np.ndarray] | None] = {"virtual_plane": None,
                                                             "dominant_plane": None}
    if len(current) < 8:
        return out
    cv2.setRNGSeed(int(seed))
    Hd, inl = cv2.findHomography(current, target, cv2.RANSAC, 2.0 * px)
    Kinv = np.linalg.inv(K)
    H_px = None
    if method == "virtual_plane":
        planar = False
        if Hd is not None:
            proj = cv2.perspectiveTransform(current.reshape(-1, 1, 2).astype(np.float64), Hd)
            err = np.linalg.norm(proj.reshape(-1, 2) - target, axis=1)
            planar = float(np.median(err)) < planar_px * px
        if not planar:
            cv2.setRNGSeed(int(seed))
            F, _ = cv2.findFundamentalMat(current, target, cv2.FM_RANSAC, 1.0 * px, 0.999,
                                          500)
            if F is not None and F.shape == (3, 3):
                H_px = _virtual_plane(F, current.astype(np.float64), target.astype(np.float64))
    Hd_e = _normalise(Kinv @ Hd @ K) if Hd is not None else None
    if Hd_e is not None and np.all(np.isfinite(Hd_e)):
        on = inl.ravel().astype(bool) if inl is not None else np.ones(len(target), bool)
        c = np.mean(target[on] if on.any() else target, axis=0)
        m = Kinv @ np.array([c[0], c[1], 1.0])
        out["dominant_plane"] = (Hd_e, m / m[2])
    else:
        Hd_e = None
    if H_px is not None:
        H = _normalise(Kinv @ H_px @ K)
        # an ill-conditioned F (3 nearly collinear points, little parallax) gives a wild H:
        # it must not disagree with the dominant plane by more than a plausible plane change
        if H is not None and np.all(np.isfinite(H)) and (
                Hd_e is None or np.abs(H - Hd_e).max() <= gate):
            out["virtual_plane"] = (H, np.array([0.0, 0.0, 1.0]))
    return out


def homography(current: np.ndarray, target: np.ndarray, K: np.ndarray, method: str,
               seed: int, planar_px: float = 2.0, gate: float = 0.3, px: float = 1.0
               ) -> HomographyResult:
    """The Euclidean homography from current to target points (pixels, sorted: the first 3
    define the virtual plane): the virtual plane's when it is usable, else the dominant
    plane's (one cycle on its own; the app holds its choice steady: vs/choice.py)."""
    c = homographies(current, target, K, method, seed, planar_px, gate, px)
    for used in ("virtual_plane", "dominant_plane"):
        if c[used] is not None:
            return HomographyResult(c[used][0], used)
    return HomographyResult(None, "failed")
