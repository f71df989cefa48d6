"""Writes the small records files the guide's Records chapter checks (docs/src/records.md).

A 1-D constant-velocity target (position measured), simulated and filtered by a Kalman
filter whose Q and R equal the truth's, 24 runs x 40 steps, in plain Python (no NumPy), so
that anyone can regenerate the files and compare: `python3 write_cv1d.py` writes
`cv1d.csv` (errors, covariances, innovations: judged by NEES and NIS) and
`cv1d_innovations.csv` (innovations only: judged without truth). Run i draws from
random.Random(1000 + i) alone, as the seed contract of the worker protocol asks.

It also writes two single recordings of the same filter, as a drive with a reference
trajectory would give them: `cv1d_drive.csv` (one run of 500 steps, from
random.Random(2000)) and `cv1d_short.csv` (its first 30 steps).
"""

import random

RUNS, STEPS, DT = 24, 40, 1.0
Q_ACCEL, R_POS = 0.5, 1.0


def run(i, steps=STEPS, seed=None):
    rng = random.Random(1000 + i if seed is None else seed)
    dt2, dt3, dt4 = DT * DT, DT**3, DT**4
    q = [[Q_ACCEL * dt4 / 4, Q_ACCEL * dt3 / 2], [Q_ACCEL * dt3 / 2, Q_ACCEL * dt2]]
    # Truth and estimate start from the same prior: x0 ~ N(0, P0).
    p = [[10.0, 0.0], [0.0, 1.0]]
    x = [rng.gauss(0, 10.0**0.5), rng.gauss(0, 1.0)]
    xh = [0.0, 0.0]
    rows = []
    for k in range(1, steps + 1):
        # White acceleration held over the step (the dwna model of problems/cv1d.toml).
        a = rng.gauss(0, Q_ACCEL**0.5)
        x = [x[0] + DT * x[1] + dt2 / 2 * a, x[1] + DT * a]
        xh = [xh[0] + DT * xh[1], xh[1]]
        p = [
            [p[0][0] + 2 * DT * p[0][1] + dt2 * p[1][1] + q[0][0], p[0][1] + DT * p[1][1] + q[0][1]],
            [0.0, p[1][1] + q[1][1]],
        ]
        p[1][0] = p[0][1]
        z = x[0] + rng.gauss(0, R_POS**0.5)
        nu = z - xh[0]
        s = p[0][0] + R_POS
        g = [p[0][0] / s, p[1][0] / s]
        xh = [xh[0] + g[0] * nu, xh[1] + g[1] * nu]
        p = [
            [p[0][0] - g[0] * p[0][0], p[0][1] - g[0] * p[0][1]],
            [p[1][0] - g[1] * p[0][0], p[1][1] - g[1] * p[0][1]],
        ]
        p[0][1] = p[1][0] = 0.5 * (p[0][1] + p[1][0])
        e = [x[0] - xh[0], x[1] - xh[1]]
        rows.append((i, k, e, p, nu, s))
    return rows


def write_full(path, rows):
    with open(path, "w") as f:
        f.write("run,step,e_1,e_2,P_1_1,P_2_1,P_2_2,nu_1,S_1_1\n")
        for i, k, e, p, nu, s in rows:
            vals = [e[0], e[1], p[0][0], p[1][0], p[1][1], nu, s]
            f.write(f"{i},{k}," + ",".join(f"{v:.6g}" for v in vals) + "\n")


def main():
    rows = [r for i in range(RUNS) for r in run(i)]
    write_full("cv1d.csv", rows)
    drive = run(0, steps=500, seed=2000)
    write_full("cv1d_drive.csv", drive)
    write_full("cv1d_short.csv", drive[:30])
    with open("cv1d_innovations.csv", "w") as f:
        f.write("run,step,nu_1,S_1_1\n")
        for i, k, _, _, nu, s in rows:
            f.write(f"{i},{k},{nu:.6g},{s:.6g}\n")


if __name__ == "__main__":
    main()
