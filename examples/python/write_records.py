"""Write the cv2d filter's Monte Carlo records at θ for ``autotune check --records``.

    python3 write_records.py --theta q_accel_x=0.5,q_accel_y=0.1,r_pos_x=1,r_pos_y=4 \\
        --seed 2 --runs 200 --steps 200 --out cv2d.npz [--normalized]

The extension of --out picks the format: .npz, .csv or .jsonl (docs/external.md §1).
Parameters left out of --theta take the truth's values. The records are raw (e, P,
nu_pos, S_pos), or with --normalized precomputed in float64: nees, nees_dof, e2p,
nis_pos, nis_dof_pos, u_pos.
"""

from __future__ import annotations

import argparse
import sys

import cv2d_model as m
from autotune_worker import write_records
from cv2d_numpy import simulate


def parse_theta(text: str) -> dict:
    theta = dict(m.TRUTH)
    for item in filter(None, (s.strip() for s in text.split(","))):
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or name not in m.PARAMS:
            raise argparse.ArgumentTypeError(
                f"{item!r}: expected NAME=VALUE with NAME one of {', '.join(m.PARAMS)}"
            )
        theta[name] = float(value)
    return theta


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--theta", type=parse_theta, default=dict(m.TRUTH),
                    help="NAME=VALUE,... (default: the truth)")
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--out", required=True, help="FILE.npz, FILE.csv or FILE.jsonl")
    ap.add_argument("--normalized", action="store_true",
                    help="write nees/e2p/nis/u instead of e/P/nu/S")
    a = ap.parse_args(argv)
    if a.runs < 1 or a.steps < 1 or a.seed < 0:
        ap.error("--runs and --steps must be at least 1, --seed non-negative")
    rec = simulate(a.theta, a.seed, (0, a.runs), a.steps)
    if a.normalized:
        rec = m.normalize(rec)
    try:
        write_records(a.out, rec)
    except (OSError, ValueError) as exc:
        print(f"write_records.py: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
