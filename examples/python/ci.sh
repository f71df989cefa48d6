#!/usr/bin/env bash
# Tune the Python worker examples with autotune and check the result.
#
#   examples/python/ci.sh path/to/autotune        (from the repository root)
#
# For cv2d_numpy.toml and cv2d_filterpy.toml: `autotune tune` from the shipped wrong start;
# every tuned [params] value within 5% of the truth in the file's [external] truth table;
# `autotune check` of the tuned config on a fresh seed exits 0 (consistent). Prints the
# wall time of each step; exits nonzero with a message on the first failure.
set -euo pipefail

if [[ $# -ne 1 ]]; then
    echo "usage: $0 path/to/autotune" >&2
    exit 2
fi
autotune=$1
if [[ ! -x $autotune ]]; then
    echo "ci.sh: $autotune is not an executable" >&2
    exit 2
fi
autotune=$(cd "$(dirname "$autotune")" && pwd)/$(basename "$autotune")
here=examples/python
if [[ ! -f $here/cv2d_numpy.toml ]]; then
    echo "ci.sh: run me from the repository root (no $here/cv2d_numpy.toml here)" >&2
    exit 2
fi
python3 -c 'import numpy, scipy, filterpy' || {
    echo "ci.sh: needs python3 with numpy, scipy and filterpy" >&2
    exit 2
}

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
# A fresh seed for the check: neither the search's (2) nor the confirmation's (2^40 + 3
# onwards). Fixed, so that a run is reproducible (a consistent filter fails the gate on a
# given seed with probability about α = 5%); AUTOTUNE_CI_SEED picks another.
check_seed=${AUTOTUNE_CI_SEED:-2026}

fail() {
    echo "ci.sh: FAIL: $*" >&2
    exit 1
}

now() { date +%s.%N; }
elapsed() { python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.1f}')" "$1" "$(now)"; }

for example in cv2d_numpy cv2d_filterpy; do
    problem=$here/$example.toml
    tuned=$tmp/$example.toml

    t0=$(now)
    status=0
    "$autotune" tune "$problem" --out "$tuned" --report "$tmp/$example" --quiet || status=$?
    echo "$example: autotune tune exit $status in $(elapsed "$t0") s"
    if [[ $status -ne 0 ]]; then
        [[ -f $tmp/$example/report.md ]] && head -n 40 "$tmp/$example/report.md" >&2
        fail "$example: autotune tune $problem exited $status (0 = tuned filter confirmed)"
    fi
    [[ -f $tuned ]] || fail "$example: autotune tune wrote no $tuned"

    python3 - "$problem" "$tuned" <<'EOF' || fail "$example: tuned parameters not within 5% of the truth"
import sys, tomllib
with open(sys.argv[1], "rb") as f:
    truth = tomllib.load(f)["external"]["truth"]
with open(sys.argv[2], "rb") as f:
    tuned = tomllib.load(f)["params"]
bad = 0
for name, want in truth.items():
    got = tuned.get(name)
    off = float("inf") if got is None else got / want - 1.0
    ok = abs(off) <= 0.05
    bad += not ok
    print(f"  {name:<10} tuned {got!s:<22} truth {want:<6} {100 * off:+.2f}%  {'ok' if ok else 'OFF'}")
sys.exit(1 if bad or set(tuned) != set(truth) else 0)
EOF

    t0=$(now)
    status=0
    "$autotune" check "$problem" --config "$tuned" --seed "$check_seed" >"$tmp/check.txt" 2>&1 || status=$?
    echo "$example: autotune check --config <tuned> --seed $check_seed exit $status in $(elapsed "$t0") s"
    [[ $status -eq 0 ]] || { cat "$tmp/check.txt" >&2; fail "$example: the tuned filter fails autotune check on seed $check_seed (exit $status)"; }
done
echo "ci.sh: both Python examples tuned to within 5% of the truth and pass the check"
