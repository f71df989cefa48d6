"""cv2d worker that replays: the Kalman filter of cv2d_model.py run over a recorded
measurement record that autotune names, instead of over runs it simulates.

Serve it with cv2d_replay.toml; from the repository root:

    autotune simulate problems/cv2d.toml --out z.csv --steps 500 --seed 3
    autotune estimate examples/python/cv2d_replay.toml --measurements z.csv

autotune sends ``"replay": "/abs/path/z.csv"`` with θ; the worker reads the record (CSV:
``run,step,z_1,z_2``, or ``step,z_1,z_2`` for one sequence; a ``time`` column is
ignored), runs the filter over each sequence, and answers the innovations ``nu_pos`` and
their covariances ``S_pos`` (NaN at a step whose reading is missing) with
``"replays": true``. autotune computes the likelihood, the NIS statistics and the gate from
them, as for a filter it holds itself.
"""

from __future__ import annotations

import csv

import numpy as np

import cv2d_model as m
from autotune_worker import serve


_RECORDS: dict = {}


def read_record(path: str) -> np.ndarray:
    """The record as an array (sequences, steps, 2), NaN where a value is missing; read
    once per worker (autotune replays the same record at every θ)."""
    if path not in _RECORDS:
        _RECORDS[path] = _read_csv(path)
    return _RECORDS[path]


def _read_csv(path: str) -> np.ndarray:
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    col = {name: j for j, name in enumerate(header)}
    z_cols = [col["z_1"], col["z_2"]]
    runs: dict[int, list] = {}
    for row in body:
        run = int(row[col["run"]]) if "run" in col else 0
        runs.setdefault(run, []).append(
            [float(row[j]) if row[j].strip() else np.nan for j in z_cols]
        )
    return np.array([runs[r] for r in sorted(runs)], dtype=float)


def replay(theta: dict, path: str, steps: int) -> dict:
    """The filter at θ over every sequence of the record: raw innovation records."""
    z = read_record(path)[:, :steps]
    # The likelihood search may ask for a parameter at zero (is it at its bound?): a noise
    # of zero is a valid, if degenerate, filter.
    th = {p: float(theta[p]) for p in m.PARAMS}
    if not all(v >= 0.0 and np.isfinite(v) for v in th.values()):
        raise ValueError(f"parameters must be nonnegative and finite: {th}")
    Q = m.q_matrix(th["q_accel_x"], th["q_accel_y"])
    R = m.r_matrix(th["r_pos_x"], th["r_pos_y"])
    n = z.shape[0]
    nu = np.full((n, steps, 2), np.nan)
    S_out = np.full((n, steps, 2, 2), np.nan)
    I = np.eye(4)
    for i in range(n):
        x, P = m.X0.copy(), m.P0.copy()
        for k in range(steps):
            x = m.F @ x
            P = m.F @ P @ m.F.T + Q
            if not np.all(np.isfinite(z[i, k])):
                continue
            S = m.H @ P @ m.H.T + R
            K = P @ m.H.T @ np.linalg.inv(S)
            v = z[i, k] - m.H @ x
            x = x + K @ v
            IKH = I - K @ m.H
            P = IKH @ P @ IKH.T + K @ R @ K.T
            nu[i, k], S_out[i, k] = v, S
    return {f"nu_{m.SENSOR}": nu, f"S_{m.SENSOR}": S_out}


if __name__ == "__main__":
    raise SystemExit(serve(None, replay=replay))
