"""The quad-X mixer: rotor thrusts <-> total thrust and body torques (PX4 motor order).

Motor order and spin (PX4 quad-X, viewed from above): 1 front-right CCW, 2 rear-left CCW,
3 front-left CW, 4 rear-right CW; rotor i at (+-a, +-a) with a = arm_length*sqrt(2)/2.
"""

from __future__ import annotations

from math import sqrt as _sqrt

from mav.airframe import Airframe


def mixer_matrix(v: Airframe) -> list[list[float]]:
    """A (4x4): [T; N; M; L] = A @ [T1, T2, T3, T4] for PX4 quad-X order (rows: total thrust N,
    yaw torque N m, pitch torque N m, roll torque N m; columns: rotor thrusts N)."""
    a = v.arm_length * _sqrt(2.0) / 2.0  # m, rotor offset along body x and y
    c = v.k_torque / v.k_thrust               # m, reaction torque per unit thrust
    # rotor positions (x forward, y right): 1 (+a,+a), 2 (-a,-a), 3 (+a,-a), 4 (-a,+a)
    # torque of a thrust T along -z at (x, y): roll = -y*T, pitch = +x*T
    return [
        [1.0, 1.0, 1.0, 1.0],
        [c, c, -c, -c],      # 1, 2 CCW -> +yaw; 3, 4 CW -> -yaw
        [a, -a, a, -a],      # front rotors (1, 3) pitch up
        [-a, a, a, -a],      # left rotors (2, 3) roll right
    ]


def inverse4(m: list[list[float]]) -> list[list[float]]:
    """Inverse of a 4x4 matrix by Gauss-Jordan with partial pivoting (set-up time only)."""
    n = 4
    aug = [list(map(float, row)) + [1.0 if i == j else 0.0 for j in range(n)]
           for i, row in enumerate(m)]
    for col in range(n):
        piv = max(range(col, n), key=lambda r: abs(aug[r][col]))
        if abs(aug[piv][col]) < 1e-15:
            raise ValueError("mixer matrix is singular (check arm_length, k_torque, k_thrust)")
        aug[col], aug[piv] = aug[piv], aug[col]
        pv = aug[col][col]
        aug[col] = [x / pv for x in aug[col]]
        for r in range(n):
            if r != col:
                f = aug[r][col]
                aug[r] = [x - f * y for x, y in zip(aug[r], aug[col], strict=True)]
    return [row[n:] for row in aug]
