"""cv2d worker: the same filter as cv2d_numpy.py, written the way most Python code is:
one ``filterpy.kalman.KalmanFilter`` per run, stepped with filterpy's own predict/update.

Same parameters, same truth (cv2d_model.truth) and same raw records (e, P, nu_pos, S_pos)
as the NumPy worker, equal to rounding (~1e-12): the innovation and its covariance are
filterpy's ``y`` and ``S`` after each update.

Run as autotune's worker (cv2d_filterpy.toml) or import ``simulate``.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter

import cv2d_model as m


def run_filter(theta: dict, x: np.ndarray, z: np.ndarray) -> dict:
    """The filter at θ on truth x (n, T, 4) and measurements z (n, T, 2): raw records."""
    Q, R = m.filter_noise(theta)
    n, steps = z.shape[:2]
    e = np.empty((n, steps, 4))
    P = np.empty((n, steps, 4, 4))
    nu = np.empty((n, steps, 2))
    S = np.empty((n, steps, 2, 2))
    for j in range(n):
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x = m.X0.copy()
        kf.P = m.P0.copy()
        kf.F = m.F.copy()
        kf.H = m.H.copy()
        kf.Q = Q.copy()
        kf.R = R.copy()
        for k in range(steps):
            kf.predict()
            kf.update(z[j, k])
            e[j, k] = x[j, k] - kf.x
            P[j, k] = kf.P
            nu[j, k] = kf.y
            S[j, k] = kf.S
    return {"e": e, "P": P, f"nu_{m.SENSOR}": nu, f"S_{m.SENSOR}": S}


def simulate(theta: dict, seed: int, runs: tuple[int, int], steps: int) -> dict:
    """Records of runs [a, b) at θ (the worker's callback)."""
    x, z = m.truth(seed, runs, steps)
    return run_filter(theta, x, z)


if __name__ == "__main__":
    from autotune_worker import serve

    raise SystemExit(serve(simulate))
