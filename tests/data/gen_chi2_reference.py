#!/usr/bin/env python3
"""Generate the scipy reference quantiles for tests/chi2_reference.rs.

Regenerate (from the crate root) with:

    python3 tests/data/gen_chi2_reference.py > tests/data/chi2_scipy.csv

The CSV has `#` comment lines recording the scipy and numpy versions, then a header
`p,dof,quantile` and one row per (dof, p). `quantile` is `scipy.stats.chi2.ppf(p, dof)`
printed with Python's `repr`, the shortest decimal that round-trips to the same f64
(at most 17 significant digits), so the Rust test parses back the exact scipy value.

The p values are alpha/2 and 1 - alpha/2 for alpha = 0.05 and 0.01.
"""

import sys

import numpy
import scipy
from scipy.stats import chi2

DOFS = [1, 2, 3, 4, 6, 100, 200, 1000, 20000]
PS = [0.005, 0.025, 0.975, 0.995]


def main() -> None:
    out = sys.stdout
    out.write("# scipy.stats.chi2.ppf reference quantiles for tests/chi2_reference.rs\n")
    out.write(f"# scipy {scipy.__version__}, numpy {numpy.__version__}, "
              f"python {sys.version.split()[0]}\n")
    out.write("# regenerate: python3 tests/data/gen_chi2_reference.py > tests/data/chi2_scipy.csv\n")
    out.write("p,dof,quantile\n")
    for dof in DOFS:
        for p in PS:
            q = float(chi2.ppf(p, dof))
            assert float(repr(q)) == q
            out.write(f"{p!r},{dof},{q!r}\n")


if __name__ == "__main__":
    main()
