#!/usr/bin/env python3
"""Smoke test of the Octave worker without autotune: python3 examples/octave/drive.py

Starts orbit_worker.m as autotune would (docs/external.md, section 2), sends requests
and checks the answers: the CSV header and shapes, the seed contract (the rows of a run
do not depend on the range it was asked in, nor on the worker), error replies that keep
the worker serving, and that the EKF with the truth's noise is consistent (mean NEES
near n = 4, mean NIS near the mean measured dimension). Prints timings. Exit 0 if all
checks pass, 1 otherwise. Plain Python 3, no packages.
"""

import json
import math
import os
import select
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
COMMAND = ["octave", "--no-gui", "--quiet", "--norc", "--no-window-system", "orbit_worker.m"]
TRUTH = {"q_accel": 1e-10, "r_range": 1e-4, "r_rate": 1e-8}
STATIONS = ["gs1", "gs2", "gs3"]
N_STATE = 4

failures = []


def check(ok, what):
    print(("ok    " if ok else "FAIL  ") + what)
    if not ok:
        failures.append(what)


class Worker:
    def __init__(self):
        env = dict(os.environ, AUTOTUNE_WORKER="1")
        self.p = subprocess.Popen(COMMAND, cwd=HERE, env=env, stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.next_id = 1

    def ask(self, req, timeout=120.0):
        """Send a request (a dict, or raw text) and return (reply dict, seconds)."""
        line = req if isinstance(req, str) else json.dumps(req)
        t0 = time.monotonic()
        self.p.stdin.write(line + "\n")
        self.p.stdin.flush()
        ready, _, _ = select.select([self.p.stdout], [], [], timeout)
        if not ready:
            raise RuntimeError(f"no reply within {timeout} s to {line}")
        reply = self.p.stdout.readline()
        secs = time.monotonic() - t0
        if not reply:
            raise RuntimeError(f"worker closed stdout; stderr:\n{self.p.stderr.read()}")
        return json.loads(reply), secs

    def request(self, theta, seed, runs, steps, directory):
        rid = self.next_id
        self.next_id += 1
        req = {"id": rid, "theta": theta, "seed": seed, "runs": list(runs),
               "steps": steps, "dir": directory}
        reply, secs = self.ask(req)
        if reply.get("id") != rid or "file" not in reply:
            raise RuntimeError(f"unexpected reply {reply} to {req}")
        return reply["file"], secs

    def close(self):
        self.p.stdin.close()
        out = self.p.stdout.read()
        rc = self.p.wait(timeout=30)
        err = self.p.stderr.read()
        return rc, out, err


def expected_header():
    cols = ["run", "step"] + [f"e_{i}" for i in range(1, N_STATE + 1)]
    cols += [f"P_{i}_{j}" for i in range(1, N_STATE + 1) for j in range(1, N_STATE + 1)]
    for s in STATIONS:
        cols += [f"nu_{s}_{i}" for i in (1, 2)]
        cols += [f"S_{s}_{i}_{j}" for i in (1, 2) for j in (1, 2)]
    return cols + ["diverged"]


def load(path):
    with open(path) as f:
        header = f.readline().rstrip("\n").split(",")
        lines = f.read().splitlines()
    data = [[float(v) for v in ln.split(",")] for ln in lines]
    return header, lines, data


def quad_form(v, A):
    """v' A^-1 v for a small symmetric positive definite A (Cholesky)."""
    n = len(v)
    L = [[0.0] * n for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            acc = A[i][j] - sum(L[i][k] * L[j][k] for k in range(j))
            if i == j:
                if acc <= 0:
                    raise ValueError("matrix not positive definite")
                L[i][i] = math.sqrt(acc)
            else:
                L[i][j] = acc / L[j][j]
    y = []
    for i in range(n):
        y.append((v[i] - sum(L[i][k] * y[k] for k in range(i))) / L[i][i])
    return sum(t * t for t in y)


def statistics(header, data):
    """Mean NEES, the sum of the NIS over sensors per row, and the measured dimension."""
    col = {name: k for k, name in enumerate(header)}
    idx = range(1, N_STATE + 1)
    nees, nis, dim = [], [], []
    for row in data:
        e = [row[col[f"e_{i}"]] for i in idx]
        P = [[row[col[f"P_{i}_{j}"]] for j in idx] for i in idx]
        nees.append(quad_form(e, P))
        total, d = 0.0, 0
        for s in STATIONS:
            nu = [row[col[f"nu_{s}_{i}"]] for i in (1, 2)]
            if math.isnan(nu[0]):
                continue
            S = [[row[col[f"S_{s}_{i}_{j}"]] for j in (1, 2)] for i in (1, 2)]
            total += quad_form(nu, S)
            d += 2
        nis.append(total)
        dim.append(d)
    return nees, nis, dim


def mean(xs):
    return sum(xs) / len(xs)


def main():
    tmp = tempfile.mkdtemp(prefix="autotune-octave-drive-")
    steps = 40

    t0 = time.monotonic()
    w = Worker()
    _, startup = w.request(TRUTH, 7, (0, 1), 1, tmp)
    print(f"Octave start-up and a first 1-run, 1-step request: {time.monotonic() - t0:.2f} s")

    # Header and shapes, runs not starting at 0.
    path, _ = w.request(TRUTH, 3, (5, 9), steps, tmp)
    header, lines, data = load(path)
    check(header == expected_header(), "CSV header " + ",".join(header[:8]) + ",...")
    shape = (len(data), sorted(set(len(row) for row in data)))
    check(shape == (4 * steps, [len(header)]), f"shape {shape} = (4 runs x {steps} steps, [{len(header)}])")
    check([row[0] for row in data] == [r for r in range(5, 9) for _ in range(steps)],
          "run column 5..8, run by run")
    check([row[1] for row in data] == [k for _ in range(4) for k in range(1, steps + 1)],
          "step column 1..T in every run")
    check(all(row[-1] == 0 for row in data), "no run diverged at the truth")
    dims = [2 * sum(not math.isnan(row[header.index(f"nu_{s}_1")]) for s in STATIONS) for row in data]
    check(min(dims) >= 2 and max(dims) == 4 and 2 in dims,
          f"measurement dimension varies over time ({sorted(set(dims))})")
    os.remove(path)

    # Seed contract: runs 4..7 of [0, 8) equal [4, 8), in this worker and in a fresh one.
    p_all, _ = w.request(TRUTH, 11, (0, 8), steps, tmp)
    p_part, _ = w.request(TRUTH, 11, (4, 8), steps, tmp)
    _, lines_all, _ = load(p_all)
    _, lines_part, _ = load(p_part)
    check(lines_all[4 * steps:] == lines_part, "seed contract: runs 4..7 of [0,8) == [4,8) (same worker, text identical)")
    w2 = Worker()
    p_fresh, _ = w2.request(TRUTH, 11, (6, 7), steps, tmp)
    _, lines_fresh, _ = load(p_fresh)
    check(lines_all[6 * steps:7 * steps] == lines_fresh, "seed contract: run 6 alone in a fresh worker == run 6 of [0,8)")
    p_theta, _ = w2.request(dict(TRUTH, q_accel=3e-10), 11, (0, 2), steps, tmp)
    _, _, d_theta = load(p_theta)
    _, _, d_all = load(p_all)
    e_cols = [header.index(f"e_{i}") for i in (1, 2)]
    check([[r[c] for c in e_cols] for r in d_theta] != [[r[c] for c in e_cols] for r in d_all[:2 * steps]],
          "theta changes the filter")
    p_seed, _ = w2.request(TRUTH, 12, (4, 8), steps, tmp)
    _, lines_seed, _ = load(p_seed)
    check(lines_seed != lines_part, "another seed gives other noise")

    # Errors come back as error replies and the worker goes on.
    reply, _ = w2.ask(json.dumps({"id": 90, "theta": {"q_accel": 1e-10}, "seed": 1,
                                  "runs": [0, 2], "steps": 3, "dir": tmp}))
    check(reply.get("id") == 90 and "r_range" in reply.get("error", ""), f"missing parameter -> {reply}")
    reply, _ = w2.ask("{not json")
    check("error" in reply, f"bad JSON -> {reply}")
    reply, _ = w2.ask(json.dumps({"id": 91, "theta": TRUTH, "seed": 1, "runs": [0, 2],
                                  "steps": 3, "dir": "/nonexistent/dir"}))
    check(reply.get("id") == 91 and "error" in reply, f"unwritable dir -> {reply}")
    p_big, _ = w2.request(TRUTH, 2**64 - 1, (0, 1), 2, tmp)
    check(os.path.exists(p_big), "a seed of 2^64 - 1 is served")
    rc, out, err = w2.close()
    check(rc == 0 and out == "", f"worker exits 0 at end of input, nothing more on stdout (rc {rc}, {out!r})")

    # Consistency at the truth, and the cost of an evaluation once the truth is cached.
    n = 64
    t1 = time.monotonic()
    path, first = w.request(TRUTH, 1, (0, n), steps, tmp)
    print(f"{n} runs x {steps} steps, new truth: {first:.2f} s")
    path, again = w.request(dict(TRUTH, r_rate=2e-8), 1, (0, n), steps, tmp)
    print(f"{n} runs x {steps} steps, cached truth (one evaluation): {again:.3f} s, "
          f"{os.path.getsize(path) / 1e6:.1f} MB of CSV")
    path, _ = w.request(TRUTH, 1, (0, n), steps, tmp)
    header, _, data = load(path)
    nees, nis, dim = statistics(header, data)
    anees = mean(nees)
    print(f"at the truth: ANEES {anees:.3f} (n = {N_STATE}), mean NIS {mean(nis):.3f}, "
          f"mean measured dimension {mean(dim):.2f}")
    check(abs(anees / N_STATE - 1) < 0.08, f"ANEES {anees:.3f} within 8% of {N_STATE}")
    check(abs(mean(nis) / mean(dim) - 1) < 0.08,
          f"mean NIS {mean(nis):.3f} within 8% of the mean measured dimension {mean(dim):.2f}")
    wrong = {"q_accel": 1e-11, "r_range": 4e-4, "r_rate": 4e-8}
    path, _ = w.request(wrong, 1, (0, n), steps, tmp)
    header, _, data = load(path)
    nees, nis, dim = statistics(header, data)
    print(f"at the wrong start {wrong}: ANEES {mean(nees):.3f}, mean NIS {mean(nis):.3f} "
          f"(mean measured dimension {mean(dim):.2f})")
    rc, out, err = w.close()
    check(rc == 0 and out == "", "first worker exits 0")
    for f in os.listdir(tmp):
        os.remove(os.path.join(tmp, f))
    os.rmdir(tmp)
    print("all checks passed" if not failures else f"{len(failures)} check(s) failed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
