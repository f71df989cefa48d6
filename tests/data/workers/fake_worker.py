#!/usr/bin/env python3
"""A scripted worker for autotune's protocol tests (tests/external.rs), pure Python.

A scalar random walk x_k = x_{k-1} + w_k, w ~ N(0, 0.5), measured as z = x + v, v ~ N(0, 2),
and a Kalman filter with parameters q and r. Run i's noise comes from random.Random of
(seed, i) alone (the seed contract). The first argument picks a behaviour: "good" answers
inline, "file" writes a JSON Lines file; every other mode breaks the protocol in one way.
With FAKE_WORKER_LOG set, each request appends a JSON line (the worker's pid, the request's
dir, that dir's real path and mode) to that file.
"""
import json
import math
import os
import random
import signal
import subprocess
import sys
import time

MODE = sys.argv[1] if len(sys.argv) > 1 else "good"
# "ranked": the mode FAKE_FAIL on the MPI rank FAKE_FAIL_RANK, "good" on the others.
if MODE == "ranked":
    failing = os.environ.get("OMPI_COMM_WORLD_RANK") == os.environ.get("FAKE_FAIL_RANK")
    MODE = os.environ.get("FAKE_FAIL", "good") if failing else "good"
Q_TRUE, R_TRUE = 0.5, 2.0
shared = random.Random(12345)  # for "unseeded": noise that depends on the request order
# "cached_truth": each run's true trajectory drawn once per process from a generator seeded by
# the pid and cached (a truth cache not keyed on (seed, i) alone); "advancing": the same cache
# filled from a fixed-seed generator in the order runs are first asked for.
truth_rng = random.Random(os.getpid() if MODE == "cached_truth" else 12345)
truth_cache = {}


def truth(seed, i, steps):
    key = (seed, i, steps)
    if key not in truth_cache:
        truth_cache[key] = [truth_rng.gauss(0.0, 1.0)] + [
            truth_rng.gauss(0.0, math.sqrt(Q_TRUE)) for _ in range(steps)
        ]
    return truth_cache[key]


def run_records(theta, seed, i, steps):
    if MODE == "unseeded":
        rng = shared
    elif MODE == "seed0":  # every run seeded with (seed, 0): all runs the same
        rng = random.Random(f"{seed}:0")
    else:
        rng = random.Random(f"{seed}:{i}")
    cached = truth(seed, i, steps) if MODE in ("cached_truth", "advancing") else None
    q, r = theta["q"], theta["r"]
    x = cached[0] if cached else rng.gauss(0.0, 1.0)
    xh, p = 0.0, 1.0
    out = []
    for k in range(1, steps + 1):
        x += cached[k] if cached else rng.gauss(0.0, math.sqrt(Q_TRUE))
        z = x + rng.gauss(0.0, math.sqrt(R_TRUE))
        p += q
        s = p + r
        nu = z - xh
        g = p / s
        xh += g * nu
        p = (1.0 - g) * p
        if MODE == "nan" and q > 1.0:
            p = float("nan")
        rec = {"run": i, "step": k, "e": [x - xh], "P": [[p]], "nu_z": [nu], "S_z": [[s]]}
        if MODE == "wrong_shape":
            rec["e"] = [x - xh, 0.0]
        out.append(rec)
    return out


def log(record):
    path = os.environ.get("FAKE_WORKER_LOG")
    if path:
        with open(path, "a") as f:
            f.write(json.dumps(record) + "\n")


def main():
    if MODE == "exit_at_start":
        print("cannot import the filter module", file=sys.stderr)
        sys.exit(3)
    if MODE == "stubborn":
        # Ignores SIGTERM, and so does the child it starts (SIG_IGN survives exec).
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    for line in sys.stdin:
        req = json.loads(line)
        a, b = req["runs"]
        st = os.stat(req["dir"])
        log({"pid": os.getpid(), "dir": req["dir"], "real": os.path.realpath(req["dir"]),
             "mode": st.st_mode & 0o777})
        if MODE == "stubborn":
            child = subprocess.Popen(["sleep", "60"], stdin=subprocess.DEVNULL)
            log({"pid": child.pid})
            log({"pid": os.getpid(), "busy": True})
            time.sleep(60)
        if MODE == "orphan":
            # Exits without answering while a child it started keeps its stdout open.
            child = subprocess.Popen(["sleep", "30"], stdin=subprocess.DEVNULL)
            log({"pid": child.pid})
            print("lost the filter state", file=sys.stderr, flush=True)
            sys.exit(4)
        if MODE in ("escape", "escape_link"):
            # A records file outside the scratch directory: named through "..", or through a
            # symbolic link inside it.
            outside = os.path.join(req["dir"], "..", "victim.jsonl")
            if MODE == "escape_link":
                with open(outside, "w") as f:
                    for i in range(a, b):
                        for rec in run_records(req["theta"], req["seed"], i, req["steps"]):
                            f.write(json.dumps(rec) + "\n")
                link = os.path.join(req["dir"], "link.jsonl")
                os.symlink(os.path.realpath(outside), link)
                outside = link
            print(json.dumps({"id": req["id"], "file": outside}), flush=True)
            continue
        if MODE == "exit_mid":
            print(json.dumps(run_records(req["theta"], req["seed"], a, req["steps"])[0]), flush=True)
            print("Traceback: ZeroDivisionError in update()", file=sys.stderr, flush=True)
            sys.exit(1)
        if MODE == "garbage":
            print("iteration 1: P = 3.2", flush=True)
            continue
        if MODE == "wrong_id":
            print(json.dumps({"id": req["id"] + 1000, "done": True}), flush=True)
            continue
        if MODE == "timeout":
            time.sleep(30)
        if MODE == "slow":
            time.sleep(0.5)
        if MODE == "error":
            print(json.dumps({"id": req["id"], "error": "theta out of range"}), flush=True)
            continue
        if MODE == "missing_run":
            b -= 1
        records = [rec for i in range(a, b) for rec in run_records(req["theta"], req["seed"], i, req["steps"])]
        if MODE in ("file", "bad_file"):
            path = os.path.join(req["dir"], "%d.jsonl" % req["id"])
            with open(path, "w") as f:
                for rec in records:
                    f.write(json.dumps(rec) + "\n")
                if MODE == "bad_file":
                    f.write('{"run": %d, "step": 1, "e": [0.1], "P": "oops"}\n' % b)
            print(json.dumps({"id": req["id"], "file": path}), flush=True)
            continue
        for rec in records:
            sys.stdout.write(json.dumps(rec) + "\n")
        print(json.dumps({"id": req["id"], "done": True}), flush=True)


main()
