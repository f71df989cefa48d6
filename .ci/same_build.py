#!/usr/bin/env python3
"""Issue 37, item 12: the README's two commands share one build (and the C ABI library and
the Python package's wheel share it too).

    same_build.py snapshot TARGET_DIR STATE   after the first command (`cargo run --release`)
    same_build.py compare  TARGET_DIR STATE   after the second's build (`cargo test --release`)

The first records the libraries it finds in TARGET_DIR/release/deps (rlib, rmeta and the
shared objects of proc-macros), by crate name and file. The second fails when the build
since then wrote a library of a crate the first command had built: another copy of that
crate (other features or profile) or the same file rebuilt. New crates (the
dev-dependencies) and the test executables are what the second command should compile.
"""
import json
import os
import re
import sys

LIB = re.compile(r"^lib(.+)-([0-9a-f]{16})\.(rlib|rmeta|so)$")
# A registry crate's sources in its dep-info: .../registry/src/<index>/<package>-<version>/
SOURCE = re.compile(r"/registry/src/[^/]+/([^/]+?)-(\d+\.\d+\.\d+[^/]*)/")


def crate_of(deps, name, digest):
    """The crate and its version (two versions of one crate are two crates), from the
    dep-info file beside the library."""
    try:
        with open(os.path.join(deps, f"{name}-{digest}.d")) as f:
            m = SOURCE.search(f.read())
    except OSError:
        m = None
    return f"{name} {m.group(2)}" if m else name


def libraries(target):
    deps = os.path.join(target, "release", "deps")
    found = {}
    for file in os.listdir(deps):
        m = LIB.match(file)
        if m:
            crate = crate_of(deps, m.group(1), m.group(2))
            found[file] = (crate, os.stat(os.path.join(deps, file)).st_mtime_ns)
    return found


def main():
    mode, target, state = sys.argv[1:4]
    now = libraries(target)
    if mode == "snapshot":
        with open(state, "w") as f:
            json.dump(now, f)
        crates = sorted({c for c, _ in now.values()})
        print(f"same_build: {len(crates)} crates built so far")
        return
    with open(state) as f:
        before = json.load(f)
    first = {c for c, _ in before.values()}
    again = sorted(
        {
            crate
            for name, (crate, mtime) in now.items()
            if crate in first and (name not in before or before[name][1] != mtime)
        }
    )
    new = sorted({c for n, (c, _) in now.items() if n not in before and c not in first})
    if again:
        sys.exit(
            f"same_build: the build since the snapshot compiled {len(again)} crates built before it: "
            + ", ".join(again)
        )
    print(f"same_build: the build since the snapshot compiled only crates not built before it ({len(new)})")


main()
