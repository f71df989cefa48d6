"""autotune's worker helper: serve a Python filter and simulator to autotune, with the
statistics of its runs computed in this process (docs/src/workers.md, "Sums in the worker").

A problem file's ``[external]`` section names a command that calls ``serve(simulate)``::

    import autotune

    def simulate(theta, seed, runs, steps):
        a, b = runs
        ...                       # run i's noise from np.random.default_rng([seed, i])
        return {"e": e, "P": P, "nu_pos": nu, "S_pos": S}   # leading axes (b - a, steps)

    if __name__ == "__main__":
        autotune.serve(simulate)

``serve`` reads one JSON request per line from stdin, calls ``simulate(theta, seed, (a, b),
steps)``, hands the arrays (the NumPy records layout of docs/src/records.md) to the native
library, which sums them exactly as autotune sums a records file, and answers
``{"id": id, "sums": "..."}``: a few kilobytes instead of the records. An exception answers
``{"id": id, "error": "Type: message"}`` (traceback on stderr) and the loop goes on; end of
input ends it.

The protocol owns stdout: while ``serve`` runs, ``sys.stdout`` and file descriptor 1 both
point to stderr, so a stray ``print`` shows up as a diagnostic instead of corrupting the
answers. With ``AUTOTUNE_WORKER_STATS`` set to a file name, the worker appends one JSON line
to it when it exits: its requests and the seconds spent in ``simulate``, in summing and
answering, and waiting for requests.

``Chunk`` is the same, one request at a time, for a loop of your own: ``Chunk(line)``,
then ``state(run, step, e, P)`` and ``sensor(run, step, name, nu, S)`` for every run and
step (or ``array(name, shape, bytes)``), then ``answer()``.
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback

from ._native import Chunk, __version__

__all__ = ["Chunk", "serve", "answer", "__version__"]


def answer(request: str, arrays: dict) -> str:
    """The sums answer line (no newline) of ``request`` (the line autotune sent) for the
    records ``arrays`` (a dict of NumPy arrays, leading axes (runs asked for, steps))."""
    import numpy as np

    chunk = Chunk(request)
    for name, value in arrays.items():
        a = np.ascontiguousarray(value, dtype="<f8")
        chunk.array(name, list(a.shape), a.tobytes())
    return chunk.answer()


def serve(simulate, stdin=None) -> int:
    """Answer autotune's requests with ``simulate`` until stdin closes; returns 0."""
    stdin = sys.stdin if stdin is None else stdin
    sys.stdout.flush()
    proto = os.fdopen(os.dup(1), "w", encoding="utf-8", newline="\n")
    saved_fd1 = os.dup(1)
    os.dup2(2, 1)
    saved_stdout = sys.stdout
    sys.stdout = sys.stderr

    def send(text: str) -> None:
        proto.write(text + "\n")
        proto.flush()

    stats = {"pid": os.getpid(), "requests": 0, "simulate_s": 0.0, "sums_s": 0.0, "wait_s": 0.0}
    clock = time.perf_counter()
    try:
        while True:
            line = stdin.readline()
            stats["wait_s"] += time.perf_counter() - clock
            if not line:
                break
            if not line.strip():
                clock = time.perf_counter()
                continue
            rid = None
            try:
                req = json.loads(line)
                rid = req.get("id") if isinstance(req, dict) else None
                theta, seed = req["theta"], int(req["seed"])
                a, b = (int(v) for v in req["runs"])
                steps = int(req["steps"])
                stats["requests"] += 1
                t0 = time.perf_counter()
                arrays = simulate(theta, seed, (a, b), steps)
                t1 = time.perf_counter()
                text = answer(line, arrays)
                stats["simulate_s"] += t1 - t0
                stats["sums_s"] += time.perf_counter() - t1
                send(text)
            except Exception as e:  # noqa: BLE001 - every failure is answered, not fatal
                traceback.print_exc(file=sys.stderr)
                message = f"{type(e).__name__}: {e}".replace("\n", " ")
                send(json.dumps({"id": rid, "error": message}))
            clock = time.perf_counter()
    finally:
        sys.stdout = saved_stdout
        os.dup2(saved_fd1, 1)
        os.close(saved_fd1)
        path = os.environ.get("AUTOTUNE_WORKER_STATS")
        if path:
            with open(path, "a") as f:
                f.write(json.dumps(stats) + "\n")
    return 0
