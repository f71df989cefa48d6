"""A unified diff (standard input) with the lines that only moved marked unchanged (standard
output), for `cargo mutants --in-diff` (.ci/mutants.sh).

An added line whose text, whitespace aside, is also a removed line of the same diff was
moved (a function split, a module renamed), not written: its mutants were already judged
where it came from. It becomes a context line, so the new side of every hunk still matches
the tree; each hunk's old side is renumbered to stay in order, which cargo-mutants checks
but never reads against a file. Each removed line pays for one added line, so a line
duplicated by the change still counts once as new.

An added line of brackets alone (`}`, `});`, `)),`), or a bare `Ok(())`, is never new: it
holds no operator or value to mutate, and the removed lines of a change that moves code between files have too
few copies of each to pay for every one, which would mark the moved function that holds it
as written.

Moved blocks are paired first: a run of at least MIN_RUN added lines that stands, in the
same order, among the removed lines (difflib's matching blocks over the whole diff) moved
with its neighbours, and pays for its own lines there. Only the added lines left over are
paired one by one, so a common line of new code (`mc: &McConfig,`) does not use up the
copy that a moved function needed."""
import difflib
import re
import sys

MIN_RUN = 3


def key(line):
    return re.sub(r"\s+", "", line[1:])


def brackets_only(line):
    return re.fullmatch(r"(Ok\(\(\)\))?[(){}\[\];,]*", key(line)) is not None and key(line) != ""


lines = sys.stdin.read().split("\n")
removed = {}
for line in lines:
    if line.startswith("-") and not line.startswith("---"):
        removed[key(line)] = removed.get(key(line), 0) + 1

# Moved blocks: the added lines (by index into `lines`) inside a long enough run that the
# removed lines hold in the same order.
minus = [key(x) for x in lines if x.startswith("-") and not x.startswith("---")]
plus_at = [i for i, x in enumerate(lines) if x.startswith("+") and not x.startswith("+++")]
plus = [key(lines[i]) for i in plus_at]
moved = set()
matcher = difflib.SequenceMatcher(None, minus, plus, autojunk=False)
for block in matcher.get_matching_blocks():
    if block.size >= MIN_RUN:
        for j in range(block.b, block.b + block.size):
            moved.add(plus_at[j])
            removed[plus[j]] -= 1

out = []
hunk = None  # (header, body lines)
shift = 0  # new-side lines minus old-side lines in the file's hunks so far


def close():
    global shift
    if hunk is None:
        return
    header, body = hunk
    old = sum(1 for b in body if b[:1] in (" ", "-"))
    new = sum(1 for b in body if b[:1] in (" ", "+"))
    m = re.match(r"@@ -\d+(?:,\d+)? \+(\d+)(?:,\d+)? @@(.*)", header)
    start = int(m.group(1))
    out.append(f"@@ -{start - shift},{old} +{start},{new} @@{m.group(2)}")
    out.extend(body)
    shift += new - old


for at, line in enumerate(lines):
    if line.startswith("@@"):
        close()
        hunk = (line, [])
        continue
    if hunk is None or line.startswith("diff "):
        close()
        hunk = None
        if line.startswith("diff "):
            shift = 0
        out.append(line)
        continue
    if at in moved or (line.startswith("+") and brackets_only(line)):
        line = " " + line[1:]
    elif line.startswith("+") and key(line) and removed.get(key(line), 0) > 0:
        removed[key(line)] -= 1
        line = " " + line[1:]
    hunk[1].append(line)
close()
sys.stdout.write("\n".join(out))
