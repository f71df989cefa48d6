#!/usr/bin/env python3
"""pykalman's EM against `autotune estimate` on the same cv2d measurement records.

For each seed: `autotune simulate` writes a 5000-step record, pykalman's EM estimates the
full process and measurement covariances from the problem's starting values, and
`autotune estimate` fits the four structured parameters by maximum likelihood. Both
log-likelihoods are put on one scale by evaluating pykalman's at autotune's estimate.

    python em_baseline.py --autotune target/release/autotune --seeds 7 8 9 \
        --out examples/python/em/results.json
"""

import argparse
import json
import subprocess
import time
import tomllib
from pathlib import Path

import numpy as np
import pykalman
import scipy
from pykalman import KalmanFilter

FULL = ["transition_covariance", "observation_covariance"]
# What `kf.em(z)` estimates when em_vars is not given.
PYKALMAN_DEFAULT = FULL + ["initial_state_mean", "initial_state_covariance"]


def load_problem(path):
    doc = tomllib.loads(Path(path).read_text())
    t, start = doc["truth"], {name: p["value"] for name, p in doc["params"].items()}
    return {"F": np.array(t["F"]), "H": np.array(t["H"]), "x0": np.array(t["x0"]),
            "P0": np.array(t["P0"]), "dt": doc["dt"], "filter": doc["filter"], "truth": t,
            "start": start}


def dwna_basis(dt):
    # Q of one axis for unit acceleration variance (discrete white noise acceleration).
    return np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])


def build(blocks, value, n, dt):
    """A covariance from the problem's block list; value(block) gives the block's number."""
    M = np.zeros((n, n))
    for b in blocks:
        i = b["indices"]
        if b["kind"] == "dwna":
            M[np.ix_(i, i)] += value(b) * dwna_basis(dt)
        elif b["kind"] == "diag":
            M[i[0], i[0]] += value(b)
        else:
            raise ValueError(f"block kind {b['kind']} not handled here")
    return M


def filter_QR(prob, theta):
    """Q and R of the problem's filter at the named parameter values theta."""
    (n, m), f, dt = prob["H"].shape[::-1], prob["filter"], prob["dt"]
    return (build(f["Q"], lambda b: theta[b["param"]], n, dt),
            build(f["R"], lambda b: theta[b["param"]], m, dt))


def structured(prob, Q, R):
    """The filter's parameters implied by full Q and R: each DWNA block projected on its
    basis by least squares (Frobenius), each diagonal entry read off."""
    out = {}
    for b, M in [(b, Q) for b in prob["filter"]["Q"]] + [(b, R) for b in prob["filter"]["R"]]:
        i = b["indices"]
        if b["kind"] == "dwna":
            B = dwna_basis(prob["dt"])
            out[b["param"]] = float(np.sum(M[np.ix_(i, i)] * B) / np.sum(B * B))
        else:
            out[b["param"]] = float(M[i[0], i[0]])
    return out


def read_record(path):
    """z as pykalman wants it, with one masked row in front.

    autotune's x0, P0 are the estimate at step 0 and the first measurement is at step 1
    (predict, then update). pykalman's initial state is the state at its first row. A
    masked (missing) row 0 makes pykalman's time 0 autotune's step 0: same model, same
    likelihood, and EM's Q update sees all T transitions."""
    d = np.loadtxt(path, delimiter=",", skiprows=1)
    assert np.all(d[:, 0] == 0), "one run per record"
    z = np.ma.masked_all((len(d) + 1, d.shape[1] - 2))
    z[1:] = d[:, 2:]
    return z


def kalman(prob, Q, R):
    return KalmanFilter(transition_matrices=prob["F"], observation_matrices=prob["H"],
                        transition_covariance=Q, observation_covariance=R,
                        initial_state_mean=prob["x0"], initial_state_covariance=prob["P0"])


def min_eig(M):
    # Of the symmetric part: numpy's eigvalsh would read one triangle only.
    return float(np.min(np.linalg.eigvalsh((M + M.T) / 2)))


def asym(M):  # pykalman never symmetrizes; how far apart the triangles have drifted
    return float(np.max(np.abs(M - M.T)))


def first(trace, test):
    return next((t["iter"] for t in trace if test(t)), None)


def run_em(prob, z, Q0, R0, em_vars, max_iter, symmetrize=False, rel=1e-6, abs_=1e-3):
    """EM one iteration at a time, as a user monitoring convergence would: em(n_iter=1),
    then loglikelihood. Runs on to max_iter (to see what happens after the stopping rule
    fires), recording where the rule fired. Nothing guards Q or R unless symmetrize."""
    kf = kalman(prob, Q0, R0)
    trace = [{"iter": 0, "loglik": float(kf.loglikelihood(z)), "min_eig_Q": min_eig(Q0),
              "min_eig_R": min_eig(R0), "asym_Q": 0.0, "asym_R": 0.0, "em_s": 0, "loglik_s": 0}]
    failure = None
    for k in range(1, max_iter + 1):
        t0 = time.perf_counter()
        try:
            kf.em(z, n_iter=1, em_vars=em_vars)
        except Exception as e:  # a failed Cholesky or SVD inside pykalman
            failure = {"iter": k, "what": f"{type(e).__name__}: {e}"}
            break
        Q, R = kf.transition_covariance, kf.observation_covariance
        if symmetrize:  # the one-line guard: pykalman never symmetrizes its updates
            kf.transition_covariance, kf.observation_covariance = (Q + Q.T) / 2, (R + R.T) / 2
        t1 = time.perf_counter()
        ll = float(kf.loglikelihood(z))
        t2 = time.perf_counter()
        trace.append({"iter": k, "loglik": ll, "min_eig_Q": min_eig(Q), "min_eig_R": min_eig(R),
                      "asym_Q": asym(Q), "asym_R": asym(R), "em_s": t1 - t0, "loglik_s": t2 - t1})
        if not np.isfinite(ll) or not np.all(np.isfinite(Q)):
            failure = {"iter": k, "what": "non-finite log-likelihood or Q"}
            break
    ll = [t["loglik"] for t in trace]
    dll = lambda t: t["loglik"] - ll[t["iter"] - 1]  # noqa: E731
    stop = first(trace[1:], lambda t: abs(dll(t)) < max(rel * abs(t["loglik"]), abs_))
    end = stop if stop is not None else trace[-1]["iter"]
    Q, R = kf.transition_covariance, kf.observation_covariance
    big_Q = max(np.linalg.eigvalsh((Q + Q.T) / 2))
    return {
        "em_vars": em_vars, "symmetrized": symmetrize, "Q0": Q0.tolist(), "R0": R0.tolist(),
        "iterations_run": trace[-1]["iter"], "failure": failure,
        "stopping_rule_at": stop,
        "at_stop": {"em_s": sum(t["em_s"] for t in trace[1:end + 1]),
                    "with_loglik_s": sum(t["em_s"] + t["loglik_s"] for t in trace[1:end + 1]),
                    "loglik": ll[end]},
        "first_abs_change_below_1e-3": first(trace[1:], lambda t: abs(dll(t)) < 1e-3),
        "first_within_1e-2_of_final": first(trace, lambda t: ll[-1] - t["loglik"] < 1e-2),
        "median_s_per_iter": {"em": float(np.median([t["em_s"] for t in trace[1:]])),
                              "loglik": float(np.median([t["loglik_s"] for t in trace[1:]]))},
        "final": {"loglik": ll[-1], "Q": Q.tolist(), "R": R.tolist(),
                  "eig_Q": np.linalg.eigvalsh((Q + Q.T) / 2).tolist(),
                  "eig_R": np.linalg.eigvalsh((R + R.T) / 2).tolist(),
                  "structured": structured(prob, Q, R),
                  "x0": np.asarray(kf.initial_state_mean).tolist(),
                  "eig_P0": np.linalg.eigvalsh(kf.initial_state_covariance).tolist()},
        # Definiteness: the first iteration the smallest eigenvalue of Q is negative at all,
        # and the first it is negative beyond round-off (1e-9 of the largest).
        "first_min_eig_Q_negative": first(trace, lambda t: t["min_eig_Q"] < 0),
        "first_min_eig_Q_below_-1e-9_rel": first(trace, lambda t: t["min_eig_Q"] < -1e-9 * big_Q),
        "lowest_min_eig_Q": min(t["min_eig_Q"] for t in trace),
        "largest_asym": {"Q": max(t["asym_Q"] for t in trace),
                         "R": max(t["asym_R"] for t in trace)},
        "loglik_decreases": [t["iter"] for t in trace[1:] if dll(t) < -1e-9 * abs(t["loglik"])],
        "largest_loglik_drop": max([0.0] + [-dll(t) for t in trace[1:]]),
        "trace": trace,
    }


def run_autotune(exe, problem, record):
    t0 = time.perf_counter()
    r = json.loads(subprocess.run([exe, "estimate", problem, "--measurements", record, "--json"],
                                  check=True, capture_output=True, text=True).stdout)
    wall, est = time.perf_counter() - t0, r["estimate"]
    return {"theta": dict(zip(r["params"], est["theta"])), "std_errors": est["std_errors"],
            "neg_log_likelihood": est["neg_log_likelihood"], "iterations": est["iterations"],
            "evaluations": est["evaluations"], "converged": est["converged"],
            "seconds": r["seconds"], "wall_s": wall}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--autotune", required=True, help="path to the autotune binary")
    ap.add_argument("--problem", default="problems/cv2d.toml")
    ap.add_argument("--seeds", type=int, nargs="+", default=[7, 8, 9])
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--max-iter", type=int, default=500)
    ap.add_argument("--variants-seeds", type=int, nargs="*", default=[7],
                    help="seeds on which the other EM variants are also run")
    ap.add_argument("--records", default="/tmp/em_records", help="where records are written")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()

    prob = load_problem(a.problem)
    Q0, R0 = filter_QR(prob, prob["start"])
    n, m, truth = prob["F"].shape[0], prob["H"].shape[0], prob["truth"]
    truth_Q = build(truth["Q"], lambda b: b["value"], n, prob["dt"])
    truth_R = build(truth["R"], lambda b: b["value"], m, prob["dt"])
    # The start's Q is DWNA per axis, rank 2 of 4, and EM's Q update stays in its range; so
    # a full-rank (diagonal) start is tried too, and, to tell EM from pykalman's arithmetic,
    # that start again with Q and R symmetrized after each step.
    variants = {  # name: (start Q, em_vars, symmetrize)
        "dwna_start_full_QR": (Q0, FULL, False),
        "dwna_start_pykalman_default_em_vars": (Q0, PYKALMAN_DEFAULT, False),
        "diagonal_start_full_QR": (np.diag(np.diag(Q0)), FULL, False),
        "diagonal_start_full_QR_symmetrized": (np.diag(np.diag(Q0)), FULL, True),
    }
    Path(a.records).mkdir(parents=True, exist_ok=True)
    results = {"versions": {"pykalman": pykalman.__version__, "numpy": np.__version__,
                            "scipy": scipy.__version__},
               "problem": a.problem, "steps": a.steps, "start": prob["start"],
               "truth": structured(prob, truth_Q, truth_R), "max_iter": a.max_iter,
               "stopping_rule": "|dLL| < max(1e-6 |LL|, 1e-3); every run goes on to max_iter",
               "seeds": {}}
    for seed in a.seeds:
        rec = f"{a.records}/cv2d_T{a.steps}_s{seed}.csv"
        subprocess.run([a.autotune, "simulate", a.problem, "--out", rec, "--steps",
                        str(a.steps), "--seed", str(seed)], check=True, capture_output=True)
        z = read_record(rec)
        at = run_autotune(a.autotune, a.problem, rec)
        # pykalman's log-likelihood at autotune's optimum: same model, so it must be
        # -(autotune's -log L). Also how far the unaligned (no masked row) reading is.
        Qa, Ra = filter_QR(prob, at["theta"])
        ll_at = float(kalman(prob, Qa, Ra).loglikelihood(z))
        ll_unaligned = float(kalman(prob, Qa, Ra).loglikelihood(z[1:]))
        nll = at["neg_log_likelihood"]
        check = {"pykalman_loglik_at_autotune_theta": ll_at, "minus_autotune_nll": -nll,
                 "rel_diff": abs(ll_at + nll) / nll, "pykalman_loglik_unaligned": ll_unaligned}
        s = {"record": rec, "autotune": at, "loglik_check": check, "em": {}}
        for name, (Qs, em_vars, sym) in variants.items():
            if name != "dwna_start_full_QR" and seed not in a.variants_seeds:
                continue
            r = run_em(prob, z, Qs, R0, em_vars, a.max_iter, symmetrize=sym)
            r["loglik_gain_over_autotune"] = {"at_stop": r["at_stop"]["loglik"] - ll_at,
                                              "final": r["final"]["loglik"] - ll_at}
            s["em"][name] = r
            print(f"seed {seed} {name}: rule stops at {r['stopping_rule_at']} "
                  f"({r['at_stop']['em_s']:.1f} s), LL {r['at_stop']['loglik']:.4f}, after "
                  f"{r['iterations_run']} LL {r['final']['loglik']:.4f} (autotune {ll_at:.4f}), "
                  f"drops {len(r['loglik_decreases'])}, failure {r['failure']}", flush=True)
        results["seeds"][str(seed)] = s
        Path(a.out).write_text(json.dumps(results, indent=1) + "\n")  # after each seed


if __name__ == "__main__":
    main()
