#!/usr/bin/env bash
# Build the C++ worker example and tune it with autotune's defaults.
#
#   examples/cpp/ci.sh path/to/autotune [dir/of/libautotune.so]   (from the repository root)
#
# Builds pendulum_ekf.cpp with the system's C++ compiler (c++, else g++) into a scratch
# directory beside a copy of pendulum.toml, then:
#   1. `autotune check` of the shipped wrong start exits 1 (inconsistent);
#   2. `autotune tune` with no flags exits 0, its search did not stop on its budget, and
#      every parameter lies within its stated resolution of the truth in [external] truth
#      (report.json: the factor within which the runs determine it);
#   3. `autotune check --config <tuned>` on a fresh seed exits 0 (consistent).
# Given the directory of autotune's worker library (libautotune.so, from
# `cargo build --release -p autotune-cdylib`; the header is the repository's
# include/), it also builds the worker with -DAUTOTUNE_SUMS against it, and
#   4. (after step 1) `autotune check --json` of the wrong start with that worker answering
#      npz and answering sums exits 1 both times, with byte-identical reports but for the
#      problem file's path and hash (two copies of pendulum.toml, their commands given
#      `--format npz|sums`);
#   5. (after step 3) steps 2 and 3 again with the worker answering sums.
# Prints the wall time of each step; exits nonzero with a message on the first failure.
set -euo pipefail

if [[ $# -lt 1 || $# -gt 2 ]]; then
    echo "usage: $0 path/to/autotune [dir/of/libautotune.so]" >&2
    exit 2
fi
autotune=$1
if [[ ! -x $autotune ]]; then
    echo "ci.sh: $autotune is not an executable" >&2
    exit 2
fi
autotune=$(cd "$(dirname "$autotune")" && pwd)/$(basename "$autotune")
here=examples/cpp
if [[ ! -f $here/pendulum.toml ]]; then
    echo "ci.sh: run me from the repository root (no $here/pendulum.toml here)" >&2
    exit 2
fi
libdir=
if [[ $# -eq 2 ]]; then
    if [[ ! -f $2/libautotune.so ]]; then
        echo "ci.sh: no libautotune.so in $2 (build it: cargo build --release -p autotune-cdylib)" >&2
        exit 2
    fi
    if [[ ! -f include/autotune.h ]]; then
        echo "ci.sh: no include/autotune.h here (run me from the repository root)" >&2
        exit 2
    fi
    # Absolute, for the worker's rpath: it runs in the scratch directory.
    libdir=$(cd "$2" && pwd)
fi
cxx=$(command -v c++ || command -v g++ || true)
if [[ -z $cxx ]]; then
    echo "ci.sh: needs a C++17 compiler (c++ or g++; Debian: apt-get install g++)" >&2
    exit 2
fi
command -v python3 >/dev/null || { echo "ci.sh: needs python3 (to read report.json)" >&2; exit 2; }

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
# A fresh seed for the final check: neither the search's (7) nor the confirmation's
# (2^40 + 6 onwards). Fixed, so that a run is reproducible (a consistent filter fails the
# gate on a given seed with probability about α = 5%); AUTOTUNE_CI_SEED picks another.
check_seed=${AUTOTUNE_CI_SEED:-2026}

fail() {
    echo "ci.sh: FAIL: $*" >&2
    exit 1
}
now() { date +%s.%N; }
elapsed() { python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.1f}')" "$1" "$(now)"; }

t0=$(now)
"$cxx" -O2 -std=c++17 -Wall -Wextra -o "$tmp/pendulum_ekf" "$here/pendulum_ekf.cpp"
cp "$here/pendulum.toml" "$tmp/pendulum.toml"
problem=$tmp/pendulum.toml
echo "pendulum_cpp: built with $cxx in $(elapsed "$t0") s"

if [[ -n $libdir ]]; then
    t0=$(now)
    "$cxx" -O2 -std=c++17 -Wall -Wextra -DAUTOTUNE_SUMS -I include -o "$tmp/pendulum_ekf_sums" \
        "$here/pendulum_ekf.cpp" -L "$libdir" -lautotune -Wl,-rpath,"$libdir"
    for format in npz sums; do
        sed 's|^command = \["./pendulum_ekf"\]$|command = ["./pendulum_ekf_sums", "--format", "'"$format"'"]|' \
            "$here/pendulum.toml" >"$tmp/pendulum_$format.toml"
        grep -q -- '"--format", "'"$format"'"' "$tmp/pendulum_$format.toml" ||
            fail "pendulum.toml's command is not [\"./pendulum_ekf\"]: cannot give it --format $format"
    done
    echo "pendulum_cpp: built with $cxx -DAUTOTUNE_SUMS against $libdir/libautotune.so in $(elapsed "$t0") s"
fi

t0=$(now)
status=0
"$autotune" check "$problem" >"$tmp/start.txt" 2>&1 || status=$?
echo "pendulum_cpp: autotune check of the wrong start exit $status in $(elapsed "$t0") s"
[[ $status -eq 1 ]] || { cat "$tmp/start.txt" >&2; fail "the wrong start should be inconsistent (exit 1), got $status"; }

if [[ -n $libdir ]]; then
    # 4. The same check answered with records (npz) and with sums: the same statistics, bit
    # for bit. The reports name their problem file (its path and hash), which differs.
    for format in npz sums; do
        t0=$(now)
        status=0
        "$autotune" check "$tmp/pendulum_$format.toml" --json >"$tmp/check_$format.json" 2>"$tmp/check_$format.txt" || status=$?
        echo "pendulum_cpp: autotune check --json of the wrong start, worker answering $format, exit $status in $(elapsed "$t0") s"
        [[ $status -eq 1 ]] || { cat "$tmp/check_$format.txt" >&2; fail "the wrong start answered with $format should be inconsistent (exit 1), got $status"; }
        grep -v -e '^  "file": ' -e '^  "problem_hash": ' "$tmp/check_$format.json" >"$tmp/check_$format.cmp"
    done
    if cmp -s "$tmp/check_npz.cmp" "$tmp/check_sums.cmp"; then
        echo "pendulum_cpp: sums and npz reports identical: yes (all but the problem file's \"file\" and \"problem_hash\")"
    else
        echo "pendulum_cpp: sums and npz reports identical: no"
        { diff "$tmp/check_npz.cmp" "$tmp/check_sums.cmp" || true; } | head -20 | sed 's/^/  /' >&2
        fail "autotune check --json differs between the worker answering npz and answering sums"
    fi
fi

# Steps 2 and 3 on problem $1 (scratch files prefixed $2, messages tagged $3).
tune_steps() {
    local problem=$1 out=$tmp/$2 tag=$3
    t0=$(now)
    status=0
    "$autotune" tune "$problem" --out "$out.toml" --report "$out-report" >"$out-tune.txt" 2>&1 || status=$?
    echo "pendulum_cpp: autotune tune (no flags$tag) exit $status in $(elapsed "$t0") s"
    sed 's/^/  /' "$out-tune.txt"
    [[ $status -eq 0 ]] || fail "autotune tune$tag exited $status (0 = tuned filter confirmed)"

    python3 - "$problem" "$out-report/report.json" <<'PY' || fail "tuned parameters$tag not within their stated resolution of the truth"
import json, math, sys, tomllib
with open(sys.argv[1], "rb") as f:
    truth = tomllib.load(f)["external"]["truth"]
with open(sys.argv[2]) as f:
    result = json.load(f)["result"]
if result["resolution"] is None:
    print("  no resolution: the search stopped on its budget")
    sys.exit(1)
bad = 0
for name, tuned, res in zip(result["names"], result["tuned"], result["resolution"]):
    want = truth[name]
    off = abs(math.log(tuned / want))
    ok = res["factor"] is not None and off <= math.log(res["factor"])
    bad += not ok
    print(f"  {name:<3} tuned {tuned:<12.6g} truth {want:<8} {100 * (tuned / want - 1):+6.2f}%  resolution ×{res['factor']:.3f}  {'ok' if ok else 'OFF'}")
print(f"  local search: {result['local']}, {result['evaluations']} evaluations")
sys.exit(1 if bad else 0)
PY

    t0=$(now)
    status=0
    "$autotune" check "$problem" --config "$out.toml" --seed "$check_seed" >"$out-check.txt" 2>&1 || status=$?
    echo "pendulum_cpp: autotune check --config <tuned$tag> --seed $check_seed exit $status in $(elapsed "$t0") s"
    [[ $status -eq 0 ]] || { cat "$out-check.txt" >&2; fail "the tuned filter$tag fails autotune check on seed $check_seed (exit $status)"; }
}

tune_steps "$problem" tuned ""

if [[ -n $libdir ]]; then
    # 5. The tune and the final check with the worker answering sums.
    tune_steps "$tmp/pendulum_sums.toml" tuned_sums ", sums"
    echo "ci.sh: the C++ example tuned with no flags to within its resolution and passes the check, answering npz and answering sums (same check report)"
else
    echo "ci.sh: the C++ example tuned with no flags to within its resolution and passes the check"
fi
