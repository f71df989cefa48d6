"""Serve a Python filter + simulator to autotune as a worker (docs/external.md, §2).

A problem file's ``[external]`` section names a command that autotune starts once per
worker; the command calls ``serve(simulate)``::

    from autotune_worker import serve

    def simulate(theta, seed, runs, steps):
        a, b = runs
        ...                       # run i's noise from np.random.default_rng([seed, i])
        return {"e": e, "P": P, "nu_pos": nu, "S_pos": S}   # leading axes (b - a, steps)

    if __name__ == "__main__":
        serve(simulate)

``serve`` reads one JSON request per line from stdin, calls ``simulate(theta, seed,
(a, b), steps)``, writes the returned arrays with ``np.savez`` to ``<dir>/<id>.npz`` and
answers ``{"id": id, "file": path}``. An exception answers ``{"id": id, "error": "Type:
message"}`` (traceback on stderr) and the loop goes on; end of input ends it.

The protocol owns stdout: while ``serve`` runs, ``sys.stdout`` and file descriptor 1 both
point to stderr, so a stray ``print`` (or a C library writing to fd 1) shows up as a
diagnostic instead of corrupting the answers.

With the environment variable ``AUTOTUNE_WORKER_STATS`` set to a file name, the worker
appends one JSON line to that file when it exits: its requests and the seconds spent in
``simulate``, in writing the records, and waiting for requests (to tell the protocol's
cost from the filter's).

A filter that replays a recorded measurement record instead (``autotune estimate`` or
``--measurements`` on the problem) is served by ``serve(simulate, replay=replay)``: a
request that names a record (``"replay": path``) calls ``replay(theta, path, steps)``, which
returns the same arrays for every sequence of the record (leading axes (sequences,
steps)), and the answer says ``"replays": true``. ``simulate`` may then be ``None``: a
simulation request answers an error.

``write_records(path, arrays)`` writes the same arrays as a records file (.npz, .csv or
.jsonl) for ``autotune check --records``.

Needs only NumPy.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
import traceback

import numpy as np

__all__ = ["serve", "write_records", "check_shapes"]


def check_shapes(arrays: dict, n: int, steps: int) -> None:
    """Light check of the NumPy records layout: every array has leading axes (n, steps),
    except ``diverged`` (n,) and a ``*_dof`` that may be a scalar. Raises ValueError."""
    if not isinstance(arrays, dict) or not arrays:
        raise ValueError("simulate must return a non-empty dict of arrays")
    for name, value in arrays.items():
        shape = np.shape(value)
        if name == "diverged":
            want_ok = shape == (n,)
            want = f"({n},)"
        elif name == "nees_dof" or name.startswith("nis_dof"):
            want_ok = shape == () or shape[:2] == (n, steps)
            want = f"() or ({n}, {steps}, ...)"
        else:
            want_ok = shape[:2] == (n, steps)
            want = f"({n}, {steps}, ...)"
        if not want_ok:
            raise ValueError(f"array {name!r} has shape {shape}, expected {want}")


def _request_fields(req: dict) -> tuple:
    theta = req["theta"]
    seed = int(req["seed"])
    a, b = (int(v) for v in req["runs"])
    steps = int(req["steps"])
    directory = req["dir"]
    if not isinstance(theta, dict):
        raise ValueError("theta must be an object")
    if not 0 <= a <= b or steps < 1:
        raise ValueError(f"bad runs [{a}, {b}) or steps {steps}")
    return theta, seed, (a, b), steps, directory


def serve(simulate, stdin=None, replay=None) -> int:
    """Answer autotune's requests with ``simulate`` (and replay requests with ``replay``)
    until stdin closes; returns 0."""
    stdin = sys.stdin if stdin is None else stdin
    # Keep the real stdout for the protocol; point fd 1 and sys.stdout at stderr.
    sys.stdout.flush()
    proto = os.fdopen(os.dup(1), "w", encoding="utf-8", newline="\n")
    saved_fd1 = os.dup(1)
    os.dup2(2, 1)
    saved_stdout = sys.stdout
    sys.stdout = sys.stderr

    def answer(obj: dict) -> None:
        proto.write(json.dumps(obj, allow_nan=False) + "\n")
        proto.flush()

    stats = {"pid": os.getpid(), "requests": 0, "simulate_s": 0.0, "write_s": 0.0, "wait_s": 0.0}
    t_start = clock = time.perf_counter()
    try:
        while True:
            line = stdin.readline()
            stats["wait_s"] += time.perf_counter() - clock
            if not line:
                break  # EOF: autotune closed our stdin
            if not line.strip():
                continue
            rid = None
            try:
                req = json.loads(line)
                rid = req.get("id") if isinstance(req, dict) else None
                if not isinstance(req, dict):
                    raise ValueError("a request must be a JSON object")
                theta, seed, runs, steps, directory = _request_fields(req)
                stats["requests"] += 1
                t0 = time.perf_counter()
                record = req.get("replay")
                if record is not None:
                    if replay is None:
                        raise ValueError("this worker does not replay a record")
                    arrays = replay(theta, record, steps)
                elif simulate is None:
                    raise ValueError("this worker only replays a record (autotune estimate, or --measurements)")
                else:
                    arrays = simulate(theta, seed, runs, steps)
                t1 = time.perf_counter()
                check_shapes(arrays, runs[1] - runs[0], steps)
                path = os.path.join(directory, f"{rid}.npz")
                np.savez(path, **arrays)
                reply = {"id": rid, "file": path}
                if record is not None:
                    reply["replays"] = True
                answer(reply)
                stats["simulate_s"] += t1 - t0
                stats["write_s"] += time.perf_counter() - t1
            except Exception as exc:  # noqa: BLE001 - every failure becomes an answer
                traceback.print_exc(file=sys.stderr)
                sys.stderr.flush()
                answer({"id": rid, "error": f"{type(exc).__name__}: {exc}"})
            clock = time.perf_counter()
    except (BrokenPipeError, KeyboardInterrupt):
        pass
    finally:
        if os.environ.get("AUTOTUNE_WORKER_STATS"):
            stats["total_s"] = time.perf_counter() - t_start
            try:
                with open(os.environ["AUTOTUNE_WORKER_STATS"], "a", encoding="utf-8") as f:
                    f.write(json.dumps(stats) + "\n")
            except OSError as exc:
                print(f"autotune_worker: cannot write stats: {exc}", file=sys.stderr)
        sys.stdout = saved_stdout
        os.dup2(saved_fd1, 1)
        os.close(saved_fd1)
        try:
            proto.close()
        except BrokenPipeError:
            pass
    return 0


# --- records files --------------------------------------------------------------------


def _is_sensor(name: str) -> bool:
    return name.split("_", 1)[0] in ("nu", "S", "nis", "u")


def _layout(arrays: dict) -> tuple[int, int, list]:
    """(N, T, [(name, array with leading axes (N, T) or a 0-d scalar)]) from the arrays,
    ``diverged`` left out."""
    n = steps = None
    cols = []
    for name, value in arrays.items():
        if name == "diverged":
            continue
        a = np.asarray(value)
        if a.ndim >= 2:
            if n is None:
                n, steps = a.shape[:2]
            elif a.shape[:2] != (n, steps):
                raise ValueError(f"array {name!r} has leading axes {a.shape[:2]}, not {(n, steps)}")
        elif a.ndim != 0:
            raise ValueError(f"array {name!r} of shape {a.shape} has no (N, T) axes")
        cols.append((name, a))
    if n is None:
        raise ValueError("no array with leading axes (N, T)")
    return n, steps, cols


def _last_step(arrays: dict, n: int, steps: int) -> np.ndarray:
    """Per run, the last step to write (1-based): the diverged step, or T."""
    d = np.zeros(n, dtype=np.int64) if "diverged" not in arrays else np.asarray(arrays["diverged"]).astype(np.int64)
    if d.shape != (n,):
        raise ValueError(f"diverged has shape {d.shape}, expected ({n},)")
    return np.where(d > 0, np.minimum(d, steps), steps), d


def _headers(name: str, a: np.ndarray) -> list[str]:
    inner = a.shape[2:] if a.ndim >= 2 else ()
    if not inner:
        return [name]
    return [name + "".join(f"_{i + 1}" for i in idx) for idx in np.ndindex(*inner)]


def _fmt(v: float, sensor: bool) -> str:
    if math.isnan(v):
        return "" if sensor else "NaN"
    return repr(float(v))


def write_records(path: str, arrays: dict) -> None:
    """Write records in the NumPy layout (leading axes (N, T); ``diverged`` (N,), the
    1-based step at which run i diverged or 0) to ``path``, by its extension:

    - ``.npz``: ``np.savez`` as is;
    - ``.csv``: a header ``run,step,<quantity columns>`` with 1-based flattened indices
      (``e_1``, ``P_1_2``, ``nu_pos_2``, ``S_pos_1_1``, ``nees``, ...), one row per run and
      step; NaN in a sensor's columns (not measured) becomes an empty cell;
    - ``.jsonl``: one object ``{"run": i, "step": k, name: value, ...}`` per run and step;
      a sensor quantity holding NaN (not measured) is left out.

    A run that diverged at step k ends there: its row (CSV) has ``diverged`` = 1, and in
    JSON Lines the record of step k is ``{"run", "step", "diverged": "..."}``.
    """
    ext = os.path.splitext(path)[1].lower()
    if ext == ".npz":
        np.savez(path, **arrays)
        return
    n, steps, cols = _layout(arrays)
    last, div = _last_step(arrays, n, steps)
    has_div = "diverged" in arrays
    if ext == ".csv":
        header = ["run", "step"]
        for name, a in cols:
            header += _headers(name, a)
        if has_div:
            header.append("diverged")
        sensor = [_is_sensor(name) for name, _ in cols]
        with open(path, "w", encoding="utf-8", newline="\n") as f:
            f.write(",".join(header) + "\n")
            for i in range(n):
                for k in range(int(last[i])):
                    row = [str(i), str(k + 1)]
                    for (name, a), s in zip(cols, sensor):
                        v = a if a.ndim == 0 else a[i, k]
                        row += [_fmt(x, s) for x in np.ravel(v)]
                    if has_div:
                        row.append("1" if div[i] == k + 1 else "0")
                    f.write(",".join(row) + "\n")
    elif ext == ".jsonl":
        with open(path, "w", encoding="utf-8", newline="\n") as f:
            for i in range(n):
                for k in range(int(last[i])):
                    if div[i] == k + 1:
                        rec = {"run": i, "step": k + 1, "diverged": f"diverged at step {k + 1}"}
                    else:
                        rec = {"run": i, "step": k + 1}
                        for name, a in cols:
                            v = a if a.ndim == 0 else a[i, k]
                            if _is_sensor(name) and np.isnan(v).any():
                                continue  # not measured at this step
                            rec[name] = v.tolist()
                    f.write(json.dumps(rec) + "\n")
    else:
        raise ValueError(f"{path}: unknown records extension {ext!r} (use .npz, .csv or .jsonl)")
