#!/usr/bin/env bash
# The Python package (issue #25): build its wheel, install it into a fresh virtual
# environment, and check what it gives a Python user.
#
#   python/ci.sh path/to/autotune        (from the repository root; needs maturin on PATH)
#
#   1. `pip install` of the wheel gives a working `autotune` command (`--version`, and
#      `check` of a shipped problem) and `import autotune`;
#   2. the numpy cv2d worker (examples/python/cv2d_numpy.py) answering with sums through the
#      package gives `check --json` output byte-identical to the same worker answering with
#      records files (the statistics equal bit for bit);
#   3. `tune` through the package lands on the same tuned config as through records files,
#      and the wall time of both is printed.
# Exits nonzero with a message on the first failure.
set -euo pipefail

if [[ $# -ne 1 || ! -x $1 ]]; then
    echo "usage: $0 path/to/autotune (an executable)" >&2
    exit 2
fi
autotune=$(cd "$(dirname "$1")" && pwd)/$(basename "$1")
[[ -f python/pyproject.toml ]] || { echo "ci.sh: run me from the repository root" >&2; exit 2; }
command -v maturin >/dev/null || { echo "ci.sh: needs maturin on PATH (pip install maturin)" >&2; exit 2; }

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
fail() {
    echo "python/ci.sh: FAIL: $*" >&2
    exit 1
}
now() { date +%s.%N; }
elapsed() { python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.1f}')" "$1" "$(now)"; }

t0=$(now)
python/build_wheel.sh "$tmp/wheels" "$autotune" >"$tmp/build.log" 2>&1 || { tail -n 30 "$tmp/build.log" >&2; fail "the wheel did not build"; }
wheel=$(ls "$tmp"/wheels/autotune-*.whl)
echo "python: built $(basename "$wheel") ($(du -h "$wheel" | cut -f1)) in $(elapsed "$t0") s"

t0=$(now)
python3 -m venv "$tmp/venv"
venv=$tmp/venv/bin
"$venv/pip" install --quiet --disable-pip-version-check "$wheel" numpy
echo "python: installed into a fresh virtual environment in $(elapsed "$t0") s"

# 1. The command and the module.
[[ -x $venv/autotune ]] || fail "the wheel installed no $venv/autotune"
"$venv/autotune" --version | grep -q '^autotune ' || fail "autotune --version"
status=0
"$venv/autotune" check problems/cv2d.toml --runs 64 --steps 50 >"$tmp/check.txt" 2>&1 || status=$?
[[ $status -le 1 ]] && grep -q "ANEES" "$tmp/check.txt" || { cat "$tmp/check.txt" >&2; fail "autotune check problems/cv2d.toml exited $status"; }
"$venv/python" -c 'import autotune; assert callable(autotune.serve) and autotune.Chunk' || fail "import autotune"
echo "python: the installed autotune command checks problems/cv2d.toml (exit $status); import autotune works"

# 2. The same worker through records files and through the package's sums.
example=$(pwd)/examples/python
for mode in records sums; do
    flag=""
    [[ $mode == sums ]] && flag=', "--sums"'
    sed -e "s|^command = .*|command = [\"$venv/python\", \"$example/cv2d_numpy.py\"$flag]|" \
        "$example/cv2d_numpy.toml" >"$tmp/$mode.toml"
    grep -q "cv2d_numpy.py\"$flag]" "$tmp/$mode.toml" || fail "could not point $mode.toml at the venv"
    "$venv/autotune" check "$tmp/$mode.toml" --json >"$tmp/$mode.json" 2>"$tmp/$mode.err" || true
    [[ -s $tmp/$mode.json ]] || { cat "$tmp/$mode.err" >&2; fail "check through $mode gave no JSON"; }
done
# The same statistics, every digit: the reports differ only in the problem file they name
# (and its hash).
same_json() {
    python3 - "$1" "$2" <<'PY'
import json, sys
def load(p):
    d = json.load(open(p))
    del d["file"], d["problem_hash"]
    return json.dumps(d, sort_keys=True)
sys.exit(0 if load(sys.argv[1]) == load(sys.argv[2]) else 1)
PY
}
same_json "$tmp/records.json" "$tmp/sums.json" || fail "check --json differs between records and sums"
echo "python: check --json through sums and through records files: the same statistics, every digit ($(wc -c <"$tmp/sums.json") bytes)"

# 3. A tune through each.
for mode in records sums; do
    t0=$(now)
    status=0
    "$venv/autotune" tune "$tmp/$mode.toml" --out "$tmp/tuned_$mode.toml" --quiet >/dev/null 2>"$tmp/tune_$mode.err" || status=$?
    [[ $status -eq 0 ]] || { cat "$tmp/tune_$mode.err" >&2; fail "tune through $mode exited $status"; }
    echo "python: tune through $mode in $(elapsed "$t0") s"
done
# The tuned configs name their problem file (and its hash); the values must agree to the
# last digit.
strip_names() { grep -v -e "$tmp" -e '_sha256 = ' "$1" | sed -e 's/records/MODE/g' -e 's/sums/MODE/g'; }
if ! diff <(strip_names "$tmp/tuned_records.toml") <(strip_names "$tmp/tuned_sums.toml") >"$tmp/tuned.diff"; then
    head -n 10 "$tmp/tuned.diff" >&2
    fail "the tuned configs through records and through sums differ"
fi
echo "python: the tuned configs through sums and through records files agree"
