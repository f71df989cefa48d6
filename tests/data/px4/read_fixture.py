#!/usr/bin/env python3
"""Read ULog files with pyulog and print what tests/px4_fixtures_issue23.rs compares.

Independent of autotune and of the Rust writer: for each file, a JSON object with
ver_sw_release, the initial parameters, and per topic/multi_id the row count and the
sum of every field over all rows (as float64). Usage: read_fixture.py FILE...
"""
import json
import sys

import pyulog

out = {}
for path in sys.argv[1:]:
    u = pyulog.ULog(path)
    topics = {}
    for d in u.data_list:
        sums = {k: float(v.astype("float64").sum()) for k, v in d.data.items()}
        topics[f"{d.name}/{d.multi_id}"] = {"rows": int(len(d.data["timestamp"])), "sums": sums}
    out[path] = {
        "ver_sw_release": u.msg_info_dict.get("ver_sw_release"),
        "params": {k: float(v) for k, v in u.initial_parameters.items()},
        "topics": topics,
    }
json.dump(out, sys.stdout)
