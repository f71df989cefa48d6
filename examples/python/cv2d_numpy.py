"""cv2d worker: the Kalman filter vectorized across runs in NumPy.

For a linear filter on a fixed measurement schedule the covariance recursion (P, S, K) is
the same in every run, so it is computed once per request; the runs then only propagate
their estimates, all at once as the rows of an (n, 4) array.

Parameters: q_accel_x, q_accel_y (DWNA acceleration variances, (m/s^2)^2), r_pos_x,
r_pos_y (position measurement variances, m^2). Records, raw: e (n, T, 4), P (n, T, 4, 4),
nu_pos (n, T, 2), S_pos (n, T, 2, 2); sensor "pos" measures x and y.

Run as autotune's worker (cv2d_numpy.toml) or import ``simulate``.
"""

from __future__ import annotations

import numpy as np

import cv2d_model as m


def covariance_schedule(Q: np.ndarray, R: np.ndarray, steps: int):
    """P (T, 4, 4), S (T, 2, 2), K (T, 4, 2) after the update at steps 1..T, in the same
    arithmetic as filterpy's predict/update (Joseph form)."""
    P = m.P0.copy()
    I = np.eye(4)
    Ps = np.empty((steps, 4, 4))
    Ss = np.empty((steps, 2, 2))
    Ks = np.empty((steps, 4, 2))
    for k in range(steps):
        P = m.F @ P @ m.F.T + Q
        PHT = P @ m.H.T
        S = m.H @ PHT + R
        K = PHT @ np.linalg.inv(S)
        IKH = I - K @ m.H
        P = IKH @ P @ IKH.T + K @ R @ K.T
        Ps[k], Ss[k], Ks[k] = P, S, K
    return Ps, Ss, Ks


def run_filter(theta: dict, x: np.ndarray, z: np.ndarray) -> dict:
    """The filter at θ on truth x (n, T, 4) and measurements z (n, T, 2): raw records."""
    Q, R = m.filter_noise(theta)
    n, steps = z.shape[:2]
    Ps, Ss, Ks = covariance_schedule(Q, R, steps)
    xh = np.broadcast_to(m.X0, (n, 4))
    nu = np.empty((n, steps, 2))
    e = np.empty((n, steps, 4))
    FT, HT = m.F.T, m.H.T
    for k in range(steps):
        xp = xh @ FT
        nu[:, k] = z[:, k] - xp @ HT
        xh = xp + nu[:, k] @ Ks[k].T
        e[:, k] = x[:, k] - xh
    return {
        "e": e,
        "P": np.broadcast_to(Ps, (n, steps, 4, 4)),
        f"nu_{m.SENSOR}": nu,
        f"S_{m.SENSOR}": np.broadcast_to(Ss, (n, steps, 2, 2)),
    }


def simulate(theta: dict, seed: int, runs: tuple[int, int], steps: int) -> dict:
    """Records of runs [a, b) at θ (the worker's callback)."""
    x, z = m.truth(seed, runs, steps)
    return run_filter(theta, x, z)


if __name__ == "__main__":
    import sys

    if "--sums" in sys.argv[1:]:
        # The installed package (pip install of python/'s wheel): the statistics computed
        # here, answered as sums.
        from autotune import serve
    else:
        from autotune_worker import serve

    raise SystemExit(serve(simulate))
