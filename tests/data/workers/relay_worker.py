#!/usr/bin/env python3
"""A worker for tests/worker_sums.rs that answers from a table the test wrote: for each range
of runs, the records (JSON Lines, sent inline) and the sums a worker library computed from
the same records. argv: the table's path, then "records", "sums" or a way to spoil the sums
("flip", "short", "text"). In "sums" mode it first checks that the request states the layout
and lags the table was computed for."""
import json
import sys

table = json.load(open(sys.argv[1]))
mode = sys.argv[2]
for line in sys.stdin:
    req = json.loads(line)
    key = "%d,%d" % tuple(req["runs"])
    entry = table["answers"][key]
    rid = req["id"]
    if mode == "records":
        for rec in entry["records"]:
            sys.stdout.write(rec + "\n")
        sys.stdout.write(json.dumps({"id": rid, "done": True}) + "\n")
    else:
        stated = {"lags": req.get("lags"), "layout": req.get("layout")}
        if stated != table["request"]:
            sys.stdout.write(json.dumps({"id": rid, "error": "request states %r" % stated}) + "\n")
            sys.stdout.flush()
            continue
        sums = entry["sums"]
        if mode == "flip":  # a count no records give: one of them set to 10^9
            import base64, struct
            raw = bytearray(base64.b64decode(sums))
            # nees_count[0]: after the 8-byte magic, 6 header numbers and 3 vectors of T.
            at = 8 + 6 * 8 + 3 * table["steps"] * 8
            raw[at:at + 8] = struct.pack("<d", 1e9)
            sums = base64.b64encode(bytes(raw)).decode()
        elif mode == "short":
            sums = sums[: len(sums) // 2]
        elif mode == "text":
            sums = 12
        sys.stdout.write(json.dumps({"id": rid, "sums": sums}) + "\n")
    sys.stdout.flush()
