"""Steady choices of the visual-servo app across vision cycles (issue 28, ours).

`HomographyChoice`: which homography's error drives the servo. Each cycle gives up to two
candidates (the virtual plane's and the dominant plane's, features.homographies); taken on
its own the choice flips whenever the virtual plane's degeneracy test flips, and the two can
disagree wildly. A side wall as the dominant plane is the bad case: its normal is
perpendicular to the optical axis, so with m* at the principal point (Eq. 2) a forward offset
t gives e_v = t (n . m*) / d = 0 and shows up as a rotation error instead (measured: -0.66
with no forward error in an 8 m corridor, the vehicle yawed and crept backwards).

The rule, a consistency test between consecutive cycles: the error e (Eq. 2) moves little in
one cycle (at 0.3 m/s and 2 m depth about 0.006 per 40 ms cycle; a yaw at 60 deg/s 0.04), so
a candidate is consistent when its e is within `jump` (max norm) of the last accepted one.
Of the consistent candidates the one of the model in use is kept, else the preferred, else
the other (a change between models that agree is harmless). When none is consistent the
last accepted error is held, for at most `hold_n` cycles; then the preferred available
candidate is taken as it is (the view really changed). A fresh match (new point set)
starts the test anew (`reset`). Deterministic: no randomness, no clock.
"""

from __future__ import annotations

import numpy as np

from cosim.apps.vs.geometry import decouple, homography_error

MODELS = ("virtual_plane", "dominant_plane")


class HomographyChoice:
    def __init__(self, prefer: str, jump: float, hold_n: int, decoupled: bool = False,
                 turn_rad: float = 0.0) -> None:
        self.prefer = prefer
        self.decoupled = decoupled
        self.turn_rad = turn_rad     # decoupled from half this heading error, fully from it
        self.jump = float(jump)
        self.hold_n = int(hold_n)
        self.reset()
        self.holds = 0          # cycles the last error was held (a run's total)
        self.changes = 0        # changes of model (a run's total)

    def reset(self) -> None:
        self.model: str | None = None
        self.e: np.ndarray | None = None
        self._held = 0

    def choose(self, candidates: dict[str, tuple[np.ndarray, np.ndarray] | None],
               turn: bool = True) -> tuple[np.ndarray | None, str]:
        """(e, method) of this cycle: method is the model used, "held" when the last error is
        held, "failed" when there is nothing (no candidate, nothing to hold). `turn`: the
        key is a turn key (decoupled, when `decoupled`)."""
        errs = {m: homography_error(*c) for m, c in candidates.items() if c is not None}
        if self.decoupled and turn:
            errs = {m: decouple(e, candidates[m][1], 0.5 * self.turn_rad, self.turn_rad)
                    for m, e in errs.items()}
        order = [m for m in (self.model, self.prefer, *MODELS) if m in errs]
        if not errs:
            return None, "failed"
        if self.e is not None:
            for m in order:
                if float(np.max(np.abs(errs[m] - self.e))) <= self.jump:
                    return self._take(errs[m], m)
            if self._held < self.hold_n:
                self._held += 1
                self.holds += 1
                return self.e.copy(), "held"
        first = self.prefer if self.prefer in errs else order[0]
        return self._take(errs[first], first)

    def _take(self, e: np.ndarray, m: str) -> tuple[np.ndarray, str]:
        if self.model is not None and m != self.model:
            self.changes += 1
        self.model, self.e, self._held = m, e, 0
        return e, m


class Refresh:
    """When to match the frame with the key afresh (SIFT) instead of tracking on (issue 28,
    ours). Tracked points thin out and drift (LK on a changing view), the virtual plane of
    three of them goes bad, and the visibility task, once on, takes two of the four degrees
    of freedom from the servo: measured on a 1 m lateral path, it stayed on for ~28 s while
    the vehicle drifted 0.7 m past the key. A fresh match gives a new point set inside the
    view. Due, at most once per `min_s`, when:
    - "visibility": the visibility task has been on for `vis_max_s` (it is then switched off
      and kept off for another `vis_max_s`: its time is bounded);
    - "thinned": fewer than `frac` of the points matched are still tracked;
    - "stalled": eps has not fallen below 0.9 x its best since the match for `stall_s`."""

    def __init__(self, vis_max_s: float, stall_s: float, frac: float, min_s: float = 1.0
                 ) -> None:
        self.vis_max_s, self.stall_s, self.frac, self.min_s = vis_max_s, stall_s, frac, min_s
        self.t_match = -1e9
        self.n_match = 0
        self.best = float("inf")
        self.t_best = -1e9
        self.vis_on = float("nan")
        self.vis_block = -1e9
        self.count: dict[str, int] = {"visibility": 0, "thinned": 0, "stalled": 0}

    def matched(self, t: float, n: int) -> None:
        self.t_match, self.n_match = t, n
        self.best, self.t_best = float("inf"), t

    def visibility_allowed(self, t: float, wanted: bool) -> bool:
        """The visibility task's activation this cycle: wanted, and not blocked."""
        on = wanted and t >= self.vis_block
        if on and self.vis_on != self.vis_on:       # NaN: it was off
            self.vis_on = t
        elif not on:
            self.vis_on = float("nan")
        return on

    def due(self, t: float, n_tracked: int, eps: float) -> str | None:
        if eps < 0.9 * self.best:
            self.best, self.t_best = eps, t
        if t - self.t_match < self.min_s:
            return None
        why = None
        if self.vis_on == self.vis_on and t - self.vis_on >= self.vis_max_s:
            why = "visibility"
            self.vis_block = t + self.vis_max_s
            self.vis_on = float("nan")
        elif n_tracked < self.frac * self.n_match:
            why = "thinned"
        elif t - self.t_best >= self.stall_s:
            why = "stalled"
        if why is not None:
            self.count[why] += 1
            self.t_match = t          # a failed fresh match is tried again min_s later
        return why
