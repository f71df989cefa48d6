"""A unified diff (standard input) with the lines that only moved marked unchanged (standard
output), for `cargo mutants --in-diff` (.ci/mutants.sh).

An added line whose text, whitespace aside, is also a removed line of the same diff was
moved (a function split, a module renamed), not written: its mutants were already judged
where it came from. It becomes a context line, so the new side of every hunk still matches
the tree; each hunk's old side is renumbered to stay in order, which cargo-mutants checks
but never reads against a file. Each removed line pays for one added line, so a line
duplicated by the change still counts once as new."""
import re
import sys


def key(line):
    return re.sub(r"\s+", "", line[1:])


lines = sys.stdin.read().split("\n")
removed = {}
for line in lines:
    if line.startswith("-") and not line.startswith("---"):
        removed[key(line)] = removed.get(key(line), 0) + 1

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


for line in lines:
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
    if line.startswith("+") and key(line) and removed.get(key(line), 0) > 0:
        removed[key(line)] -= 1
        line = " " + line[1:]
    hunk[1].append(line)
close()
sys.stdout.write("\n".join(out))
