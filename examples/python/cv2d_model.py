"""The 2-D nearly-constant-velocity problem of autotune's problems/cv2d.toml, in NumPy.

Shared by the two workers (cv2d_numpy.py, cv2d_filterpy.py), write_records.py and
mean_nm.py, so that all of them see the same truth.

State [x, vx, y, vy], dt = 1 s, position measured on both axes. The truth has DWNA process
noise per axis, Q_axis = q * [[dt^4/4, dt^3/2], [dt^3/2, dt^2]] with q_x = 0.5 and
q_y = 0.1 (m/s^2)^2, and R = diag(1, 4) m^2. Its initial state is drawn from N(x0, P0), as
autotune's linear problems do; the filter starts at x0 with covariance P0.

The seed contract: run i's random numbers come from ``np.random.default_rng([seed, i])``
alone, drawn in a fixed order (4 normals for the initial state, then per step 4 normals:
the x and y accelerations and the x and y measurement errors), so a run is the same
whatever range it is asked in, and its first T steps are the same whatever the step count.
The truth does not depend on the filter's parameters θ.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

DT = 1.0
STATE_NAMES = ("x", "vx", "y", "vy")
SENSOR = "pos"
F = np.array(
    [
        [1.0, DT, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, DT],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
X0 = np.array([0.0, 10.0, 0.0, -5.0])
P0 = np.diag([4.0, 1.0, 16.0, 1.0])

PARAMS = ("q_accel_x", "q_accel_y", "r_pos_x", "r_pos_y")
TRUTH = {"q_accel_x": 0.5, "q_accel_y": 0.1, "r_pos_x": 1.0, "r_pos_y": 4.0}
# The designer's guess of problems/cv2d.toml: one number per quantity, copied across axes.
START = {"q_accel_x": 0.2, "q_accel_y": 0.2, "r_pos_x": 2.0, "r_pos_y": 2.0}

# DWNA noise gain of one axis: the state increment of a unit acceleration held over dt.
_GAIN = np.array([DT**2 / 2.0, DT])


def q_matrix(q_x: float, q_y: float) -> np.ndarray:
    """The 4×4 process noise of DWNA accelerations with variances q_x, q_y."""
    g = np.outer(_GAIN, _GAIN)  # [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]
    q = np.zeros((4, 4))
    q[0:2, 0:2] = q_x * g
    q[2:4, 2:4] = q_y * g
    return q


def r_matrix(r_x: float, r_y: float) -> np.ndarray:
    """The 2×2 measurement noise."""
    return np.diag([float(r_x), float(r_y)])


def filter_noise(theta: dict) -> tuple[np.ndarray, np.ndarray]:
    """The filter's (Q, R) at parameter values θ (a dict by parameter name)."""
    missing = [p for p in PARAMS if p not in theta]
    if missing:
        raise ValueError(f"theta lacks {', '.join(missing)}")
    th = {p: float(theta[p]) for p in PARAMS}
    bad = [p for p, v in th.items() if not (v > 0.0 and np.isfinite(v))]
    if bad:
        raise ValueError(f"parameters must be positive and finite: {bad}")
    return q_matrix(th["q_accel_x"], th["q_accel_y"]), r_matrix(th["r_pos_x"], th["r_pos_y"])


def _draws(seed: int, i: int, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Run i's standard normals: (4,) for the initial state, (steps, 4) per step."""
    rng = np.random.default_rng([seed, i])
    xi0 = rng.standard_normal(4)
    per_step = rng.standard_normal((steps, 4))
    return xi0, per_step


def _simulate_truth(seed: int, a: int, b: int, steps: int) -> tuple[np.ndarray, np.ndarray]:
    n = b - a
    xi0 = np.empty((n, 4))
    d = np.empty((n, steps, 4))
    for j, i in enumerate(range(a, b)):
        xi0[j], d[j] = _draws(seed, i, steps)
    sd_p0 = np.sqrt(np.diag(P0))  # P0 is diagonal
    sq_q = np.sqrt([TRUTH["q_accel_x"], TRUTH["q_accel_y"]])
    sd_r = np.sqrt([TRUTH["r_pos_x"], TRUTH["r_pos_y"]])
    # w_k = [g a_x, g a_y] with a ~ N(0, q): covariance q g g' per axis, the DWNA Q.
    acc = d[:, :, 0:2] * sq_q  # (n, T, 2)
    w = np.empty((n, steps, 4))
    w[:, :, 0:2] = acc[:, :, 0:1] * _GAIN
    w[:, :, 2:4] = acc[:, :, 1:2] * _GAIN
    x = np.empty((n, steps, 4))
    xk = X0 + xi0 * sd_p0  # x_0 ~ N(x0, P0)
    for k in range(steps):
        xk = xk @ F.T + w[:, k]
        x[:, k] = xk
    z = x @ H.T + d[:, :, 2:4] * sd_r
    return x, z


# The truth does not depend on θ, and a tune asks for the same runs of the same seed many
# times (in whatever ranges autotune splits them into): keep the last runs, one entry each.
_CACHE: OrderedDict = OrderedDict()
_CACHE_RUNS = 4096  # about 10 kB a run at 200 steps


def truth(seed: int, runs: tuple[int, int], steps: int) -> tuple[np.ndarray, np.ndarray]:
    """True states x (n, T, 4) and measurements z (n, T, 2) of runs [a, b), steps 1..T.

    Step k (1-based) is row k-1: x_k = F x_{k-1} + w_k, z_k = H x_k + v_k.
    """
    a, b = int(runs[0]), int(runs[1])
    seed, steps = int(seed), int(steps)
    if not 0 <= a <= b:
        raise ValueError(f"bad run range [{a}, {b})")
    if steps < 1:
        raise ValueError(f"steps must be at least 1, not {steps}")
    keys = [(seed, i, steps) for i in range(a, b)]
    missing = [i for i, key in zip(range(a, b), keys) if key not in _CACHE]
    # Fresh runs in maximal contiguous stretches, each simulated at once.
    j = 0
    while j < len(missing):
        k = j
        while k + 1 < len(missing) and missing[k + 1] == missing[k] + 1:
            k += 1
        x, z = _simulate_truth(seed, missing[j], missing[k] + 1, steps)
        for r in range(k - j + 1):
            _CACHE[(seed, missing[j] + r, steps)] = (x[r], z[r])
        j = k + 1
    for key in keys:
        _CACHE.move_to_end(key)
    x = np.stack([_CACHE[key][0] for key in keys]) if keys else np.empty((0, steps, 4))
    z = np.stack([_CACHE[key][1] for key in keys]) if keys else np.empty((0, steps, 2))
    while len(_CACHE) > max(_CACHE_RUNS, len(keys)):
        _CACHE.popitem(last=False)
    return x, z


def normalize(rec: dict) -> dict:
    """Raw cv2d records (e, P, nu_pos, S_pos) → the precomputed form, in float64:
    nees, nees_dof, e2p, nis_pos, nis_dof_pos, u_pos."""
    e = np.asarray(rec["e"], dtype=np.float64)
    P = np.asarray(rec["P"], dtype=np.float64)
    nu = np.asarray(rec[f"nu_{SENSOR}"], dtype=np.float64)
    S = np.asarray(rec[f"S_{SENSOR}"], dtype=np.float64)
    nees = np.einsum("...i,...i->...", e, np.linalg.solve(P, e[..., None])[..., 0])
    nis = np.einsum("...i,...i->...", nu, np.linalg.solve(S, nu[..., None])[..., 0])
    return {
        "nees": nees,
        "nees_dof": np.array(e.shape[-1]),
        "e2p": e**2 / np.diagonal(P, axis1=-2, axis2=-1),
        f"nis_{SENSOR}": nis,
        f"nis_dof_{SENSOR}": np.array(nu.shape[-1]),
        f"u_{SENSOR}": nu / np.sqrt(np.diagonal(S, axis1=-2, axis2=-1)),
    }
