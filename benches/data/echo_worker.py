#!/usr/bin/env python3
"""The protocol-overhead bench's worker (benches/external.rs): it answers every request
with the same synthetic cv2d-shaped records (e, P, nu_pos, S_pos, float64, made once per
request size), written with np.savez as a real numpy worker would. What the bench times is
then the protocol alone: the request, np.savez, autotune reading the archive and summing it.

`python3 echo_worker.py --time-filter` prints instead what one step of a numpy Kalman
filter vectorized over 64 runs (the 4-state, 2-measurement cv2d problem) costs per run.
"""
import json
import os
import sys
import time

import numpy as np

cache = {}


def records(n, steps):
    if (n, steps) not in cache:
        g = np.random.default_rng(0)
        P = np.broadcast_to(np.diag([1.0, 2.0, 3.0, 4.0]), (n, steps, 4, 4)).copy()
        S = np.broadcast_to(np.diag([1.5, 2.5]), (n, steps, 2, 2)).copy()
        cache[(n, steps)] = dict(
            e=g.standard_normal((n, steps, 4)) * np.sqrt([1.0, 2.0, 3.0, 4.0]),
            P=P,
            nu_pos=g.standard_normal((n, steps, 2)) * np.sqrt([1.5, 2.5]),
            S_pos=S,
        )
    return cache[(n, steps)]


def time_filter(n=64, steps=2000):
    F = np.array([[1, 1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1.0]])
    H = np.array([[1, 0, 0, 0], [0, 0, 1, 0.0]])
    Q = np.eye(4) * 0.1
    R = np.eye(2)
    x = np.zeros((n, 4))
    P = np.eye(4)
    z = np.random.default_rng(1).standard_normal((steps, n, 2))
    t0 = time.perf_counter()
    for k in range(steps):
        x = x @ F.T
        P = F @ P @ F.T + Q
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        nu = z[k] - x @ H.T
        x = x + nu @ K.T
        P = (np.eye(4) - K @ H) @ P
    dt = (time.perf_counter() - t0) / steps
    print(f"numpy KF step over {n} runs: {dt * 1e6:.1f} us, {dt / n * 1e9:.0f} ns per run-step")


def main():
    if "--time-filter" in sys.argv:
        time_filter()
        return
    for line in sys.stdin:
        req = json.loads(line)
        a, b = req["runs"]
        path = os.path.join(req["dir"], "%d.npz" % req["id"])
        np.savez(path, **records(b - a, req["steps"]))
        print(json.dumps({"id": req["id"], "file": path}), flush=True)


main()
