#!/usr/bin/env python3
"""Issue 37, item 11: Cargo.toml's `rust-version` is not below what any locked crate
declares (their `rust-version`), so the stated minimum Rust is true. Reads
`cargo metadata --locked` on stdin."""
import json
import sys

meta = json.load(sys.stdin)


def version(text):
    parts = [int(p) for p in text.split(".")]
    return tuple(parts + [0] * (3 - len(parts)))


ours = next(p for p in meta["packages"] if p["name"] == "autotune")
ours_v = version(ours["rust_version"])
newest = max(
    (version(p["rust_version"]), p["name"], p["version"])
    for p in meta["packages"]
    if p.get("rust_version") and p["name"] != "autotune"
)
if newest[0] > ours_v:
    sys.exit(
        f"msrv: Cargo.toml says rust-version {ours['rust_version']}, but {newest[1]} {newest[2]} "
        f"needs {'.'.join(map(str, newest[0]))}"
    )
print(f"msrv: rust-version {ours['rust_version']}; the newest any locked crate needs is "
      f"{'.'.join(map(str, newest[0]))} ({newest[1]} {newest[2]})")
