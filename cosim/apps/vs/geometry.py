"""The visual-servoing maths of paper 2 (Toro-Arcila et al.), independent of images.

Frames: the camera frame {c} is OpenCV's (x right, y down, z optical axis); the robot frame
{e} is body FRD. A twist is [v; w] (m/s, rad/s), each in the frame it is written in.

- `homography_error(H)`: Eq. 2, e = [e_v; e_w] with e_v = (H - I) m*, [e_w]x = H - H^T, for a
  Euclidean homography H (det 1) that maps current normalised points to target ones
  (m* ~ H m; with this direction e_v is the camera's offset from the target divided by the
  distance to the plane, so v = -lambda e_v moves towards the target; tested in closed loop).
- `adaptive_gain`: Eq. 4.  `control_law`: Eq. 3 with per-axis gains.
- `twist_body_from_camera`: Eqs. 5-6 (S eTc), 6-D camera twist -> [vx, vy, vz, wz] body.
- `interaction_point`: the 2x6 interaction matrix of a normalised image point.
- `Ramp`: the activation of Eq. 20 and the target-change smoothing of Eqs. 28-30.
- `hierarchy`: Eqs. 13-19 (Lee, Mansard, Park 2012 intermediate values), written in the 4
  controllable body velocities (see its docstring).
"""

from __future__ import annotations

import math

import numpy as np

R_EC = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # paper Eq. 5 eRc
BODY_ROWS = (0, 1, 2, 5)            # S of Eq. 6: vx, vy, vz, wz of the 6-D body twist
M_STAR = np.array([0.0, 0.0, 1.0])  # the target point of Eq. 2: the principal point


def skew(v) -> np.ndarray:
    x, y, z = (float(c) for c in v)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def vex(A: np.ndarray) -> np.ndarray:
    """The vector w of a skew-symmetric part: [w]x = A (for A = H - H^T)."""
    return np.array([A[2, 1], A[0, 2], A[1, 0]])


def homography_error(H: np.ndarray, m_star: np.ndarray = M_STAR) -> np.ndarray:
    """Eq. 2 for a Euclidean homography with det 1: [e_v (3); e_w (3)]."""
    e_v = (H - np.eye(3)) @ m_star
    e_w = vex(H - H.T)
    return np.concatenate((e_v, e_w))


def decouple(e: np.ndarray, m_star: np.ndarray = M_STAR, lo_rad: float = 0.0,
             hi_rad: float = 0.0) -> np.ndarray:
    """Eq. 2's error with the heading's share taken out of e_v (ours, issue 28).

    For H = R + t n^T / d, e_v = (R - I) m* + t / Z* (Z* the depth of m* on the plane): at a
    turn key the first term dominates (a 45 deg yaw gives e_v = (0.71, 0, -0.29) and the
    servo drives forward into the corner before turning). The camera is level (the
    stabilised stream; eRc constant), so R is a turn about the camera's y axis by the angle
    with 2 sin(angle) = e_w[1] ([e_w]x = H - H^T ~ R - R^T); e_v - (R - I) m* leaves the
    translation. The other two parts of e_w are not rotations of a level camera (they come
    from the translation's coupling, t n^T - n t^T, and cannot be servoed): they are not
    used. Only while the vehicle is turned: a share rising from 0 at a heading error of
    `lo_rad` to all of it at `hi_rad` (0, 0: always all), so near a key, where e_w[1] is
    mostly the translation's coupling again, the law is the paper's; at e = 0 nothing
    changes."""
    s = min(max(float(e[4]) / 2.0, -1.0), 1.0)
    ang = abs(math.asin(s))
    share = 1.0 if hi_rad <= lo_rad else min(max((ang - lo_rad) / (hi_rad - lo_rad), 0.0), 1.0)
    out = np.array(e, dtype=float)
    if share == 0.0:
        return out
    c = math.sqrt(1.0 - s * s)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    out[:3] = e[:3] - share * ((R - np.eye(3)) @ m_star)
    return out


def adaptive_gain(norm_e: float, l0: float, linf: float, l0_slope: float) -> float:
    """Eq. 4 (Kermorgant & Chaumette): l0 at e = 0, linf for large e, slope l0' at 0."""
    if l0 == linf:
        return l0
    return (l0 - linf) * math.exp(-l0_slope * norm_e / (l0 - linf)) + linf


def control_law(e: np.ndarray, lam: float, vy_extra: float, w_ratio: float = 0.5
                ) -> np.ndarray:
    """Eq. 3 with the paper's per-axis gains: lambda on camera vx and vz, lambda + vy_extra on
    vy (camera y is down: the altitude gain), w_ratio * lambda on the rotations."""
    gains = np.array([lam, lam + vy_extra, lam, w_ratio * lam, w_ratio * lam, w_ratio * lam])
    return -gains * e


def twist_transform(R: np.ndarray, t) -> np.ndarray:
    """The 6x6 twist transform [[R, [t]x R], [0, R]] (Eq. 5)."""
    T = np.zeros((6, 6))
    T[:3, :3] = R
    T[:3, 3:] = skew(t) @ R
    T[3:, 3:] = R
    return T


def body_from_camera_matrix(mount_B) -> np.ndarray:
    """S eTc (4x6): camera twist -> [vx, vy, vz, wz] in the body frame (Eqs. 5-6)."""
    return twist_transform(R_EC, mount_B)[list(BODY_ROWS), :]


def camera_from_body_matrix(mount_B) -> np.ndarray:
    """(6x4): a body twist with only vx, vy, vz, wz -> the camera's twist in {c}.

    The inverse of eTc is cTe = [[R^T, -R^T [t]x], [0, R^T]]; its columns for the four
    controllable body velocities."""
    R = R_EC.T
    T = np.zeros((6, 6))
    T[:3, :3] = R
    T[:3, 3:] = -R @ skew(mount_B)
    T[3:, 3:] = R
    return T[:, list(BODY_ROWS)]


def interaction_point(x: float, y: float, Z: float) -> np.ndarray:
    """The 2x6 interaction matrix of a normalised point (x, y) at depth Z: d(x,y)/dt = L v_c."""
    iz = 1.0 / Z
    return np.array([[-iz, 0.0, x * iz, x * y, -(1.0 + x * x), y],
                     [0.0, -iz, y * iz, 1.0 + y * y, -x * y, -x]])


class Ramp:
    """A value that moves between levels along half a cosine (Eqs. 20 and 28-30).

    `set(t, target)` starts a move from the current value towards `target` over `duration_s`;
    h(t) = h_start + (target - h_start) * 0.5 * (1 - cos(pi (t - t0) / T)), then the target.
    Continuous by construction (a new move starts from where the value is)."""

    def __init__(self, duration_s: float, value: float = 0.0) -> None:
        self.T = float(duration_s)
        self.t0 = -math.inf
        self.h0 = float(value)
        self.target = float(value)

    def value(self, t: float) -> float:
        if self.T <= 0.0 or t - self.t0 >= self.T:
            return self.target
        s = max(0.0, (t - self.t0) / self.T)
        return self.h0 + (self.target - self.h0) * 0.5 * (1.0 - math.cos(math.pi * s))

    def set(self, t: float, target: float) -> None:
        if target != self.target:
            self.h0 = self.value(t)
            self.t0 = t
            self.target = float(target)

    def restart(self, t: float, start: float, target: float = 1.0) -> None:
        """Jump to `start` and move to `target` (the target-change smoothing of Eq. 28)."""
        self.h0, self.t0, self.target = float(start), t, float(target)


def pinv(A: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Moore-Penrose pseudo-inverse with a fixed relative cut-off (deterministic)."""
    return np.linalg.pinv(A, rcond=tol)


def hierarchy(nu_v: np.ndarray, J_a: np.ndarray | None, edot_a, h_a: float,
              J_m: np.ndarray | None, edot_m: np.ndarray | None, h_m: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eqs. 13-19: avoidance (1-D) > visibility (2-D) > visual servoing, with activations.

    All in the 4 controllable body velocities q = [vx, vy, vz, wz] (ours: the paper writes the
    hierarchy in the 6-D camera twist and then drops wx, wy, which can undo the priorities;
    here the task Jacobians are first mapped through cTe S^T, so the null-space projections
    act on what the vehicle can do). The servo task is given as the velocity it asks for
    (`nu_v`, J_v = I). `J_a` (k x 4) and `edot_a` (k) = -lambda_a e_a; `J_m` (2x4) and `edot_m` =
    -lambda_m e_m; h_a, h_m their activations in [0, 1]. Intermediate values (Eqs. 17-18):
    a task that is not fully active asks for what the tasks below it would do.
    Returns (nu, nu_a, nu_m): the command and the parts of the two upper tasks."""
    n = nu_v.shape[0]
    eye = np.eye(n)
    zero = np.zeros(n)
    lower_m = zero
    if J_m is not None and h_m > 0.0:
        lower_m = h_m * (pinv(J_m) @ edot_m)
    nu_a = zero
    N_a = eye
    if J_a is not None and h_a > 0.0:
        e_a_i = h_a * np.atleast_1d(edot_a) + (1.0 - h_a) * (J_a @ (lower_m + nu_v))  # Eq. 17
        Ja_p = pinv(J_a)
        nu_a = Ja_p @ e_a_i
        N_a = eye - Ja_p @ J_a
    nu_m = zero
    N_m = N_a
    if J_m is not None and h_m > 0.0:
        e_m_i = h_m * edot_m + (1.0 - h_m) * (J_m @ nu_v)                    # Eq. 18
        JN = J_m @ N_a
        JN_p = pinv(JN)
        nu_m = JN_p @ (e_m_i - J_m @ nu_a)
        N_m = N_a - JN_p @ JN
    nu_s = N_m @ (nu_v - nu_a - nu_m)                                      # Eq. 19, J_v = I
    return nu_a + nu_m + nu_s, nu_a, nu_m
