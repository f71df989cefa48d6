#!/usr/bin/env bash
# Mutation testing of this submission's change (issue #24): cargo-mutants on the lines of
# src/ (every folder a change touches, since issue 40) that differ from the last landed commit (.ci/mutants-base), each
# mutant built with the `mutants` profile and judged by the fast tests .cargo/mutants.toml
# chooses. Fails when the tests miss a mutant. See docs/src/mutation-testing.md.
#
#   .ci/mutants.sh                   run (what .ci/run does)
#   .ci/mutants.sh --list            list the change's mutants, build and run nothing
#   .ci/mutants.sh --set-base REV    rewrite .ci/mutants-base for REV (at each landing)
set -euo pipefail
cd "$(dirname "$0")/.."

version=27.1.0
paths=(src)
base_file=.ci/mutants-base

# git's blob id of a file, without git or a repository: sha1 of "blob <size>\0<content>".
blob_id() {
  { printf 'blob %d\0' "$(wc -c <"$1")"; cat "$1"; } | sha1sum | cut -d' ' -f1
}

if [ "${1:-}" = "--set-base" ]; then
  rev=$(git rev-parse --verify "${2:?usage: .ci/mutants.sh --set-base REV}^{commit}")
  {
    sed -n '/^#/p' "$base_file"
    echo "commit $rev"
    git ls-tree -r "$rev" -- "${paths[@]}" | awk '{print "blob " $3 " " $4}'
  } >"$base_file.new"
  mv "$base_file.new" "$base_file"
  echo "$base_file: $rev"
  exit 0
fi

commit=$(awk '$1 == "commit" {print $2}' "$base_file")
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# What to mutate: the lines changed since the base commit.
select=()
if git rev-parse -q --verify "$commit^{commit}" >/dev/null 2>&1; then
  git diff --no-ext-diff --no-color "$commit" -- "${paths[@]}" | python3 .ci/unmoved.py >"$work/change.diff"
  # Only context left (the change moved lines, or touched nothing here): nothing is new.
  if grep -q '^+[^+]' "$work/change.diff"; then
    select=(--in-diff "$work/change.diff")
  fi
  what="the lines of ${paths[*]} changed since $commit (moved lines aside: .ci/unmoved.py)"
else
  # Without the base commit (a tarball, a shallow clone) the changed lines are unknown. The
  # files whose content differs from the base's blobs are listed, but not mutated whole: that
  # would judge every line of them, most of which this change never touched (hundreds of
  # mutants, hours on two cores).
  changed=()
  while IFS= read -r f; do
    want=$(awk -v p="$f" '$1 == "blob" && $3 == p {print $2}' "$base_file")
    if [ "$want" != "$(blob_id "$f")" ]; then
      changed+=("$f")
    fi
  done < <(find "${paths[@]}" -name '*.rs' | sort)
  echo "mutants: SKIPPED: this checkout does not hold the base commit $commit, so the changed" >&2
  echo "lines of ${paths[*]} cannot be told; run .ci/mutants.sh in a clone with history." >&2
  echo "Files that differ from the base: ${changed[*]:-none}" >&2
  exit 0
fi
if [ ${#select[@]} -eq 0 ]; then
  echo "mutants: nothing in ${paths[*]} changed since $commit; no mutants to test"
  exit 0
fi

if [ "$(cargo mutants --version 2>/dev/null || true)" != "cargo-mutants $version" ]; then
  cargo install cargo-mutants --version "$version" --locked --quiet
fi

if [ "${1:-}" = "--list" ]; then
  cargo mutants --list "${select[@]}"
  exit 0
fi

echo "mutants: $what"
# Each mutant is built as Cargo.toml's `mutants` profile builds it (release settings; this
# crate unoptimized, rebuilt incrementally, no debug info), but under the name `release` with
# those three settings overridden for this crate alone: the dependencies are then release's own, and
# copied from the release build that .ci/run has just made (or that a developer has) into
# cargo-mutants' own target directory they are up to date there. A new profile would build
# them all again first (about 7 CPU-minutes); cargo's fingerprints name the profile's
# directory, so release's dependencies can seed only a directory called `release`.
# cargo-mutants builds in a copy of this tree, whose artifacts a build of the tree itself in
# the same directory could mistake for its own: its directory is used by nothing else.
target=$PWD/target/cargo-mutants
if [ -d target/release/deps ]; then
  for d in deps build .fingerprint; do
    mkdir -p "$target/release/$d"
    find "target/release/$d" -mindepth 1 -maxdepth 1 ! -name '*autotune*' \
      \( -type d -o -name 'lib*' -o -name '*.d' \) -exec cp -au -t "$target/release/$d/" {} +
  done
fi
out=$target/mutants.out
rm -rf "$out"
code=0
CARGO_TARGET_DIR=$target cargo mutants --jobs 1 --colors never --output "$target" \
  --profile release \
  --cargo-arg=--config=profile.release.incremental=true \
  --cargo-arg=--config=profile.release.package.autotune.debug=false \
  --cargo-arg=--config=profile.release.package.autotune.opt-level=0 \
  "${select[@]}" || code=$?
# cargo-mutants exits 3 when a test timed out even if it also missed mutants, so the lists
# decide: any missed mutant fails.
if [ "$code" = 0 ] || [ "$code" = 2 ] || [ "$code" = 3 ]; then
  if [ -s "$out/timeout.txt" ]; then
    # Tests that ran past the timeout under a mutant hung or crawled: the mutant was noticed,
    # so it is not a survivor; listed for a look.
    echo "mutants: these mutants made the tests time out (caught, but worth a look):" >&2
    cat "$out/timeout.txt" >&2
  fi
  if [ -s "$out/missed.txt" ]; then
    echo "mutants: the fast tests missed these mutants of the change; add a test that fails" >&2
    echo "under each, or exclude one that cannot matter in .cargo/mutants.toml with the" >&2
    echo "reason (docs/src/mutation-testing.md):" >&2
    cat "$out/missed.txt" >&2
    exit 1
  fi
  exit 0
fi
echo "mutants: cargo mutants failed (exit $code); see $out/debug.log" >&2
exit 1
