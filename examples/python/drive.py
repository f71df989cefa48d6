"""A fake autotune driver: a protocol smoke test of the cv2d workers (docs/external.md §2).

    python3 drive.py [--runs N] [--steps T] [--repeat K] [worker.py ...]

For each worker (default: cv2d_numpy.py and cv2d_filterpy.py) it starts the command as
autotune would (in this directory, AUTOTUNE_WORKER=1), and checks:

- a request at the truth θ answers {"id", "file"} with the NumPy layout (e, P, nu_pos,
  S_pos with leading axes (N, T)), and ANEES ≈ 4, ANIS ≈ 2 there;
- the seed contract: runs [4, 8) asked alone equal runs 4..7 of [0, 8) bit for bit;
- a bad request (a missing parameter) answers {"id", "error"} and the worker keeps serving;
- a stray print inside simulate does not reach the protocol (the helper's own test, with a
  worker that prints);
- the worker exits at end of input;

and, with two or more workers, that their records agree. It prints the round-trip time of
a request against the time simulate takes in-process (the protocol's overhead).
Exit status 0 when every check passes.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
TRUTH = {"q_accel_x": 0.5, "q_accel_y": 0.1, "r_pos_x": 1.0, "r_pos_y": 4.0}

PRINTING_WORKER = r"""
import os, numpy as np
from autotune_worker import serve
def simulate(theta, seed, runs, steps):
    print("stray print from simulate")
    os.write(1, b"stray bytes on fd 1\n")
    n = runs[1] - runs[0]
    return {"nees": np.full((n, steps), 4.0)}
serve(simulate)
"""

failures = []


def check(ok: bool, what: str) -> None:
    print(("  ok    " if ok else "  FAIL  ") + what)
    if not ok:
        failures.append(what)


class Worker:
    def __init__(self, command: list[str]):
        env = dict(os.environ, AUTOTUNE_WORKER="1")
        self.p = subprocess.Popen(
            command,
            cwd=HERE,
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        self.next_id = 0

    def ask(self, theta, seed, runs, steps, directory):
        self.next_id += 1
        req = {"id": self.next_id, "theta": theta, "seed": seed, "runs": list(runs),
               "steps": steps, "dir": directory}
        t0 = time.perf_counter()
        self.p.stdin.write(json.dumps(req) + "\n")
        self.p.stdin.flush()
        line = self.p.stdout.readline()
        dt = time.perf_counter() - t0
        if not line:
            raise RuntimeError("worker closed stdout; stderr:\n" + self.p.stderr.read())
        reply = json.loads(line)
        if reply.get("id") != self.next_id:
            raise RuntimeError(f"reply {reply} answers another id than {self.next_id}")
        return reply, dt

    def records(self, *args):
        reply, dt = self.ask(*args)
        if "file" not in reply:
            raise RuntimeError(f"no file in reply {reply}")
        with np.load(reply["file"]) as z:
            rec = {k: z[k] for k in z.files}
        os.remove(reply["file"])
        return rec, dt

    def close(self) -> int:
        self.p.stdin.close()
        rest = self.p.stdout.read()
        code = self.p.wait(timeout=30)
        self.stderr = self.p.stderr.read()
        return code, rest


def nees_nis(rec):
    e, P, nu, S = rec["e"], rec["P"], rec["nu_pos"], rec["S_pos"]
    nees = np.einsum("...i,...i->...", e, np.linalg.solve(P, e[..., None])[..., 0])
    nis = np.einsum("...i,...i->...", nu, np.linalg.solve(S, nu[..., None])[..., 0])
    return nees.mean(), nis.mean()


def drive(script: str, runs: int, steps: int, repeat: int, tmp: str):
    print(f"{script}:")
    w = Worker([sys.executable, script])
    rec, dt = w.records(TRUTH, 2, (0, runs), steps, tmp)
    shapes = {k: v.shape for k, v in rec.items()}
    want = {"e": (runs, steps, 4), "P": (runs, steps, 4, 4), "nu_pos": (runs, steps, 2),
            "S_pos": (runs, steps, 2, 2)}
    check(shapes == want, f"records layout {shapes}")
    anees, anis = nees_nis(rec)
    # ANEES of N·T samples: sd ≈ sqrt(2·4/(N·T)) times a correlation factor of a few.
    check(abs(anees - 4) < 0.15 and abs(anis - 2) < 0.1,
          f"at the truth θ: ANEES {anees:.4f} (≈ 4), ANIS {anis:.4f} (≈ 2)")
    whole, _ = w.records(TRUTH, 7, (0, 8), steps, tmp)
    part, _ = w.records(TRUTH, 7, (4, 8), steps, tmp)
    check(all(np.array_equal(whole[k][4:], part[k]) for k in whole),
          "seed contract: runs [4, 8) alone equal runs 4..7 of [0, 8)")
    bad, _ = w.ask({"q_accel_x": 0.5}, 2, (0, 2), steps, tmp)
    check(set(bad) == {"id", "error"} and "theta lacks" in bad["error"],
          f"a bad request answers an error: {bad}")
    again, _ = w.records(TRUTH, 2, (0, 2), steps, tmp)
    check(np.array_equal(again["e"], rec["e"][:2]), "the worker keeps serving after an error")
    # Round trip against simulate's own time, at the same size.
    trips = []
    for r in range(repeat):
        theta = {k: v * (1 + 0.01 * (r + 1)) for k, v in TRUTH.items()}
        _, dt = w.records(theta, 2, (0, runs), steps, tmp)
        trips.append(dt)
    code, rest = w.close()
    check(code == 0 and rest == "", f"exits cleanly at end of input (code {code})")
    sys.path.insert(0, HERE)
    mod = __import__(os.path.splitext(script)[0])
    mod.simulate(TRUTH, 2, (0, runs), steps)  # the worker's truth cache was warm too
    inproc = []
    for r in range(repeat):
        theta = {k: v * (1 + 0.01 * (r + 1)) for k, v in TRUTH.items()}
        t0 = time.perf_counter()
        mod.simulate(theta, 2, (0, runs), steps)
        inproc.append(time.perf_counter() - t0)
    trip, sim = np.median(trips), np.median(inproc)
    print(f"  time  {runs} runs × {steps} steps: round trip {1e3 * trip:.1f} ms, simulate "
          f"in-process {1e3 * sim:.1f} ms, overhead {1e3 * (trip - sim):.1f} ms "
          f"(medians of {repeat})")
    return rec


def drive_printing(tmp: str):
    print("a worker that prints inside simulate:")
    w = Worker([sys.executable, "-c", PRINTING_WORKER])
    rec, _ = w.records(TRUTH, 2, (0, 3), 5, tmp)
    check(rec["nees"].shape == (3, 5), "the answer is still a protocol line")
    code, rest = w.close()
    check(code == 0 and rest == "", "nothing else reached stdout")
    check("stray print from simulate" in w.stderr and "stray bytes on fd 1" in w.stderr,
          "the stray output went to stderr")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("workers", nargs="*", default=["cv2d_numpy.py", "cv2d_filterpy.py"])
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="autotune-drive-") as tmp:
        recs = [drive(s, a.runs, a.steps, a.repeat, tmp) for s in a.workers]
        for s, r in zip(a.workers[1:], recs[1:]):
            diff = max(float(np.max(np.abs(r[k] - recs[0][k]))) for k in r)
            check(diff < 1e-9, f"{s} agrees with {a.workers[0]}: max |difference| {diff:.3g}")
        drive_printing(tmp)
        left = os.listdir(tmp)
        check(not left, f"no file left in the scratch directory {left}")
    print("all checks pass" if not failures else f"{len(failures)} check(s) FAILED")
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
