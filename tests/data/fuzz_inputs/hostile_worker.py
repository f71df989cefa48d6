#!/usr/bin/env python3
"""A hostile worker for tests/fuzz_inputs.rs: pure Python (no NumPy), one behaviour per run.

    hostile_worker.py MODE SEED

A scalar random walk and its Kalman filter (as tests/data/workers/fake_worker.py) give
valid records; MODE says how the answers go wrong, SEED (an integer) drives every random
choice, so that a failing case reruns exactly. The first GOOD answers (0 or 1, from SEED)
are valid, so that a hostile answer may also land on the seed-contract check's request.

Files the answers point at outside the scratch directory: `<dir>/../victim.csv` (the
scratch directory's parent, the test's TMPDIR) and $AUTOTUNE_FUZZ_VICTIM (a file in the
test's own directory). The test checks that both survive unchanged.

Every sleep is bounded (at most 5 s), so that nothing this script starts outlives a case
by much, whatever autotune does.
"""
import json
import math
import os
import random
import struct
import subprocess
import sys
import time
import zipfile

# MODE may end in ":EXT" to force the extension of the file it names (csv, jsonl, npz,
# npy), so that a fixed case reaches the reader it is meant for.
MODE, _, EXT = (sys.argv[1] if len(sys.argv) > 1 else "good_inline").partition(":")
SEED = int(sys.argv[2]) if len(sys.argv) > 2 else 1
rng = random.Random(SEED)
GOOD = rng.randrange(2)

# Values that have broken readers before, as JSON text.
HOSTILE_VALUES = [
    "1e308", "-1e308", "NaN", "Infinity", "-Infinity", "-0", "1e-320", "1e400",
    "18446744073709551616", "123456789012345678901234567890", "2.5", "0.5", "-1",
    "null", "true", '"x"', '""', "[]", "[[]]", "[1, 2]", "[[1, 2], [3]]", "{}",
]
HOSTILE_CELLS = [
    "", "NaN", "nan", "inf", "-0", "1e308", "1e-320", "9e15", "2.5", "-1",
    "18446744073709551616", "garbage", '"q"',
]
KEYS = ["run", "step", "e", "P", "nu_z", "S_z", "nees", "nees_dof", "nis_z", "nis_dof_z",
        "diverged", "x", "xhat", "nu", "S", "u_z", "e2p", ""]


def run_records(theta, seed, i, steps):
    r = random.Random(f"{seed}:{i}")
    q, rr = float(theta.get("q", 0.5)), float(theta.get("r", 2.0))
    x = r.gauss(0.0, 1.0)
    xh, p = 0.0, 1.0
    out = []
    for k in range(1, steps + 1):
        x += r.gauss(0.0, math.sqrt(0.5))
        z = x + r.gauss(0.0, math.sqrt(2.0))
        p += q
        s = p + rr
        nu = z - xh
        g = p / s
        xh += g * nu
        p = (1.0 - g) * p
        out.append({"run": i, "step": k, "e": [x - xh], "P": [[p]], "nu_z": [nu], "S_z": [[s]]})
    return out


def mutate_records(recs):
    """One to three structural mutations of a list of record dicts."""
    recs = [dict(r) for r in recs]
    for _ in range(1 + rng.randrange(3)):
        if not recs:
            recs.append({"run": 0})
        i = rng.randrange(len(recs))
        c = rng.randrange(7)
        if c <= 1:
            k = rng.choice(list(recs[i].keys()) or ["run"])
            recs[i][k] = json.loads(rng.choice(HOSTILE_VALUES))
        elif c == 2:
            keys = list(recs[i].keys())
            if keys:
                del recs[i][rng.choice(keys)]
        elif c == 3:
            recs[i][rng.choice(KEYS)] = json.loads(rng.choice(HOSTILE_VALUES))
        elif c == 4:
            recs.insert(rng.randrange(len(recs) + 1), dict(recs[i]))
        elif c == 5:
            del recs[i]
        else:
            j = rng.randrange(len(recs))
            recs[i], recs[j] = recs[j], recs[i]
    return recs


def mutate_bytes(b):
    b = bytearray(b)
    for _ in range(1 + rng.randrange(3)):
        if not b:
            b += b"x"
        c = rng.randrange(4)
        i = rng.randrange(len(b))
        if c == 0:
            b[i] = rng.randrange(256)
        elif c == 1:
            del b[i:i + 1 + rng.randrange(16)]
        elif c == 2:
            b[i:i] = bytes(rng.randrange(256) for _ in range(1 + rng.randrange(16)))
        else:
            del b[i:]
    return bytes(b)


def jsonl_bytes(recs):
    return "".join(json.dumps(r) + "\n" for r in recs).encode()


def csv_bytes(recs):
    lines = ["run,step,e_1,P_1_1,nu_z_1,S_z_1_1"]
    for r in recs:
        try:
            lines.append(",".join(str(v) for v in [r["run"], r["step"], r["e"][0], r["P"][0][0],
                                                   r["nu_z"][0], r["S_z"][0][0]]))
        except (KeyError, IndexError, TypeError):
            lines.append(",".join(rng.choice(HOSTILE_CELLS) for _ in range(6)))
    if rng.random() < 0.5:
        # A cell replaced by a hostile one.
        i = rng.randrange(len(lines))
        cells = lines[i].split(",")
        cells[rng.randrange(len(cells))] = rng.choice(HOSTILE_CELLS)
        lines[i] = ",".join(cells)
    return ("\n".join(lines) + "\n").encode()


def npy_bytes(shape, values, descr="<f8", fortran=False):
    header = "{'descr': '%s', 'fortran_order': %s, 'shape': (%s), }" % (
        descr, "True" if fortran else "False",
        "".join("%s," % d for d in shape) if len(shape) == 1 else ", ".join(str(d) for d in shape))
    while (10 + len(header) + 1) % 64:
        header += " "
    header += "\n"
    data = b"".join(struct.pack("<d", v) for v in values)
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + data


def npz_bytes(recs, a, b, steps, path):
    n = b - a
    def grid(f):
        out = []
        for i in range(a, b):
            for k in range(1, steps + 1):
                hit = [r for r in recs if r.get("run") == i and r.get("step") == k]
                try:
                    out.append(float(f(hit[0])) if hit else float("nan"))
                except (KeyError, IndexError, TypeError, ValueError):
                    out.append(float("nan"))
        return out
    arrays = {
        "e": ((n, steps, 1), grid(lambda r: r["e"][0])),
        "P": ((n, steps, 1, 1), grid(lambda r: r["P"][0][0])),
        "nu_z": ((n, steps, 1), grid(lambda r: r["nu_z"][0])),
        "S_z": ((n, steps, 1, 1), grid(lambda r: r["S_z"][0][0])),
    }
    hostile = MODE == "mutated_file"
    compression = zipfile.ZIP_DEFLATED if rng.random() < 0.5 else zipfile.ZIP_STORED
    with zipfile.ZipFile(path, "w", compression) as zf:
        names = list(arrays)
        if hostile and rng.random() < 0.3:
            names.remove(rng.choice(names))
        for name in names:
            shape, values = arrays[name]
            if hostile and rng.random() < 0.2:
                shape = tuple(rng.choice([0, 1, 2, 3, 4294967296, 10 ** 9]) for _ in shape)
            zf.writestr(name + ".npy", npy_bytes(shape, values))
        if hostile and rng.random() < 0.3:
            zf.writestr(rng.choice(names or ["e"]) + ".npy", npy_bytes((1,), [1.0]))
        if hostile and rng.random() < 0.2:
            # A compressed bomb: 64 MB of zeros in a few tens of kilobytes.
            big = n * steps
            zf.writestr(zipfile.ZipInfo("nu_z.npy"),
                        npy_bytes((big, 1 << 20, 1), []) + bytes(64 << 20),
                        compress_type=zipfile.ZIP_DEFLATED)


def send(obj):
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def write_file(req, recs, a, b):
    """A records file in the scratch directory, in a format picked by SEED."""
    fmt = EXT or rng.choice(["csv", "jsonl", "npz"])
    path = os.path.join(req["dir"], "%d.%s" % (req["id"], fmt))
    if fmt == "npz":
        npz_bytes(recs, a, b, req["steps"], path)
        if MODE == "mutated_file" and rng.random() < 0.3:
            with open(path, "rb") as f:
                data = mutate_bytes(f.read())
            with open(path, "wb") as f:
                f.write(data)
        return path
    data = csv_bytes(recs) if fmt == "csv" else jsonl_bytes(recs)
    if MODE == "mutated_file" and rng.random() < 0.4:
        data = mutate_bytes(data)
    with open(path, "wb") as f:
        f.write(data)
    return path


def hostile(req, recs, a, b):
    """Answer `req` in the way MODE names."""
    rid, d = req["id"], req["dir"]
    victim = os.environ.get("AUTOTUNE_FUZZ_VICTIM", "/nonexistent")
    if MODE == "mutated_inline":
        for r in mutate_records(recs):
            sys.stdout.write(json.dumps(r) + "\n")
        send({"id": rid, "done": True})
    elif MODE == "mutated_file":
        send({"id": rid, "file": write_file(req, mutate_records(recs) if rng.random() < 0.6 else recs, a, b)})
    elif MODE == "garbage":
        lines = [b"iteration 1: P = 3.2", b"\xff\xfe\x00", b"{", b"[]", b'{"id": "%d"}' % rid,
                 b'{"id": %d}' % rid, b'{"id": %d, "done": false}' % rid, b"\r", b"{}" * 1000,
                 b'{"id": %d, "file": 7}' % rid, b'{"id": %d, "file": ""}' % rid,
                 b'{"id": %d, "error": ""}' % rid, b'{"id": %d, "done": true, "file": "x"}' % rid]
        for _ in range(1 + rng.randrange(3)):
            sys.stdout.buffer.write(rng.choice(lines) + b"\n")
        sys.stdout.flush()
    elif MODE == "wrong_id":
        other = rng.choice([rid + 1, rid - 1, -1, 0, 2 ** 64, 1e308, None, "17"])
        for r in recs:
            sys.stdout.write(json.dumps(r) + "\n")
        send({"id": other, "done": True})
    elif MODE == "huge_line":
        n = rng.choice([1, 8, 32, 64]) << 20
        body = rng.choice([b" ", b"1", b"[", b"x"])
        sys.stdout.buffer.write(b'{"run": 0, "step": 1, "e": [' + body * n + b"\n")
        sys.stdout.flush()
    elif MODE == "error_answer":
        msg = rng.choice(["line one\nline two\r\nline three", "", "x" * 100000, "\x00\x1b[31mred"])
        send({"id": rid, "error": msg})
    elif MODE == "dotdot":
        # The scratch directory's sibling, by `..`.
        target = os.path.join(d, "..", "victim.csv")
        send({"id": rid, "file": target})
    elif MODE == "absolute":
        # Only paths the test owns: an autotune that deleted what it is named would delete
        # them, not a system file. A symlink planted beside the victim leads to /dev/zero.
        zero = os.path.join(os.path.dirname(victim), "zero.csv")
        if not os.path.lexists(zero):
            os.symlink("/dev/zero", zero)
        send({"id": rid, "file": rng.choice([victim, os.path.dirname(victim), d, zero])})
    elif MODE == "symlink_zero":
        link = os.path.join(d, "%d.%s" % (rid, EXT or rng.choice(["csv", "jsonl", "npz", "npy"])))
        os.symlink("/dev/zero", link)
        send({"id": rid, "file": link})
    elif MODE == "symlink_victim":
        link = os.path.join(d, "%d.csv" % rid)
        os.symlink(rng.choice([victim, os.path.join(d, "..", "victim.csv")]), link)
        send({"id": rid, "file": link})
    elif MODE == "symlink_dir":
        # A directory inside the scratch directory that is the scratch directory's parent.
        link = os.path.join(d, "up")
        os.symlink(os.path.join(d, ".."), link)
        send({"id": rid, "file": os.path.join(link, "victim.csv")})
    elif MODE == "fifo":
        path = os.path.join(d, "%d.%s" % (rid, EXT or rng.choice(["csv", "jsonl", "npz"])))
        os.mkfifo(path)
        send({"id": rid, "file": path})
    elif MODE == "exit_mid":
        text = jsonl_bytes(recs)
        sys.stdout.buffer.write(text[: rng.randrange(len(text) + 1)])
        sys.stdout.flush()
        print("Traceback: ZeroDivisionError in update()\n  more\n  lines", file=sys.stderr, flush=True)
        os._exit(rng.choice([0, 1, 3]))
    elif MODE == "child_holds_stdout":
        # A child inherits stdout and outlives this process by a few seconds.
        subprocess.Popen(["sleep", "4"], stdout=sys.stdout, stderr=sys.stderr)
        os._exit(1)
    elif MODE == "sleep_past_timeout":
        time.sleep(5)
        send({"id": rid, "done": True})
    else:
        raise SystemExit("unknown mode %s" % MODE)


def main():
    served = 0
    for line in sys.stdin:
        req = json.loads(line)
        a, b = req["runs"]
        recs = [r for i in range(a, b) for r in run_records(req["theta"], req["seed"], i, req["steps"])]
        if MODE == "good_inline" or (served < GOOD and MODE != "good_file"):
            for r in recs:
                sys.stdout.write(json.dumps(r) + "\n")
            send({"id": req["id"], "done": True})
        elif MODE == "good_file":
            send({"id": req["id"], "file": write_file(req, recs, a, b)})
        else:
            hostile(req, recs, a, b)
        served += 1


main()
