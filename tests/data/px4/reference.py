#!/usr/bin/env python3
"""Independent reference numbers for `autotune nis` (written without looking at
the Rust implementation). pyulog only parses; every statistic is computed here
with numpy/scipy, following the rules in README.md literally.

Usage: reference.py   (reads the four .ulg fixtures next to it, writes reference.json)
"""
import json
import os
import platform
from importlib.metadata import version
import re

import numpy as np
import pyulog
import scipy
from scipy.stats import chi2

HERE = os.path.dirname(os.path.abspath(__file__))
FILES = ["v1_13_three_ekf.ulg", "v1_15_events.ulg", "legacy_ekf2.ulg", "white_new.ulg"]
IN_AIR_FILES = ["legacy_ekf2.ulg"]
MAX_PAIR_US = 50_000
GATE = chi2.isf(1e-5, 1)                      # outlier gate on a 1-dof NIS
IN95 = (chi2.ppf(0.025, 1), chi2.ppf(0.975, 1))
LEVEL, MAX_LAG, WINDOW = 0.05, 10, 50
WIN_BOUNDS = (chi2.ppf(0.025, WINDOW) / WINDOW, chi2.ppf(0.975, WINDOW) / WINDOW)


def num(x):
    """JSON has no NaN: undefined numbers become null."""
    return None if x is None or not np.isfinite(x) else float(x)


def topics(log):
    return {(d.name, d.multi_id): d for d in log.data_list}


def float_fields(d):
    return [f.field_name for f in d.field_data if f.type_str == "float"]


def pair(inn_ts, var_ts):
    """Index of the variances row for each innovations row, -1 if unpaired, plus
    a per-row kind: 0 exact, 1 near, 2 unpaired."""
    order = np.argsort(var_ts, kind="stable")   # earliest row first among equal stamps
    sorted_ts = var_ts[order].astype(np.int64)
    idx = np.full(len(inn_ts), -1)
    kind = np.full(len(inn_ts), 2)
    for r, ts in enumerate(inn_ts.astype(np.int64)):
        pos = np.searchsorted(sorted_ts, ts, side="left")
        if pos < len(sorted_ts) and sorted_ts[pos] == ts:
            idx[r], kind[r] = order[pos], 0
            continue
        # candidates: nearest below (pos-1) and above (pos); the tie goes to
        # the earlier one, so test the lower candidate first with <=
        best = None
        for c in (pos - 1, pos):
            if 0 <= c < len(sorted_ts):
                # among rows sharing that stamp, take the first one in the file
                c = np.searchsorted(sorted_ts, sorted_ts[c], side="left")
                gap = abs(sorted_ts[c] - ts)
                if gap <= MAX_PAIR_US and (best is None or gap < best[1]):
                    best = (c, gap)
        if best is not None:
            idx[r], kind[r] = order[best[0]], 1
    return idx, kind


def check_pairing_rule():
    """Guard the tie and window semantics that the Rust side must match."""
    v = np.array([100, 200, 200, 300, 400_000], dtype=np.uint64)
    i = np.array([200, 150, 250, 60_000, 50_300, 349_999], dtype=np.uint64)
    idx, kind = pair(i, v)
    assert list(idx) == [1, 0, 1, -1, 3, -1] and list(kind) == [0, 1, 1, 2, 1, 2], (idx, kind)


def channels(log):
    """Return ({instance: pairing counts}, [(instance, channel, times, nu, S)])
    with nu and S float32 arrays restricted to paired rows, in file field order."""
    t, pairing, out = topics(log), {}, []
    for (name, inst), inn in sorted(t.items()):
        rows = len(inn.data["timestamp"])
        if name == "estimator_innovations":
            var = t.get(("estimator_innovation_variances", inst))
            if var is None:      # no variances logged at all: nothing can pair
                idx, kind, fields = np.full(rows, -1), np.full(rows, 2), []
            else:
                idx, kind = pair(inn.data["timestamp_sample"], var.data["timestamp_sample"])
                common = set(float_fields(var))
                fields = [f for f in float_fields(inn) if f in common
                          and f not in ("timestamp", "timestamp_sample")
                          and not f.startswith("_padding")]
            pairing[inst] = {"rows": rows, "paired_exact": int(np.sum(kind == 0)),
                             "paired_near": int(np.sum(kind == 1)),
                             "unpaired": int(np.sum(kind == 2))}
            keep = idx >= 0
            times = inn.data["timestamp_sample"][keep]
            exact = kind[keep] == 0
            out += [(inst, f"ekf{inst}.{f}", times, inn.data[f][keep], var.data[f][idx[keep]],
                     exact) for f in fields]
        elif name == "ekf2_innovations":
            # one topic holds both; there is no timestamp_sample, so t = timestamp
            pairing[inst] = {"rows": rows, "paired_exact": rows, "paired_near": 0, "unpaired": 0}
            names = float_fields(inn)
            for f in names:
                m = re.fullmatch(r"(.+)_innov(\[\d+\])?", f)
                if m and f"{m.group(1)}_innov_var{m.group(2) or ''}" in names:
                    out.append((inst, f"ekf{inst}.{m.group(1)}{m.group(2) or ''}",
                                inn.data["timestamp"], inn.data[f],
                                inn.data[f"{m.group(1)}_innov_var{m.group(2) or ''}"],
                                np.ones(rows, dtype=bool)))
    return pairing, out


def classify(nu32, s32, exact):
    """Per-row class: 'idle', 'invalid', 'zero', 'repeat' or 'update'. An
    innovation of exactly 0 (either sign) beside a positive variance is 'zero':
    no draw of N(0, S) is exactly 0. Repeats compare
    the float32 bit patterns with the previous paired row, whatever its class:
    innovation and variance for a row paired exactly, the innovation alone for a
    row paired with the nearest variances row (its variance is from another
    filter cycle, so a change in it says nothing about a fusion)."""
    nu_bits, s_bits = nu32.view(np.uint32), s32.view(np.uint32)
    nu, s = nu32.astype(np.float64), s32.astype(np.float64)
    out = []
    for k in range(len(nu)):
        if nu[k] == 0 and s[k] == 0:
            out.append("idle")
        elif not (np.isfinite(nu[k]) and np.isfinite(s[k])) or s[k] <= 0:
            out.append("invalid")
        elif nu[k] == 0:
            out.append("zero")
        elif k > 0 and nu_bits[k] == nu_bits[k - 1] and (s_bits[k] == s_bits[k - 1] or not exact[k]):
            out.append("repeat")
        else:
            out.append("update")
    return out


def truncated_interval(k_gated):
    """Moments of chi2(1) truncated at GATE and the scaled-chi2 interval of the
    mean of k_gated such variables."""
    m = 1
    f_m = chi2.cdf(GATE, m)
    mu = m * chi2.cdf(GATE, m + 2) / f_m
    second = m * (m + 2) * chi2.cdf(GATE, m + 4) / f_m
    if k_gated == 0:
        return mu, None
    big_m, big_v = k_gated * mu, k_gated * (second - mu * mu)
    c, h = big_v / (2 * big_m), 2 * big_m * big_m / big_v
    return mu, [c * chi2.ppf(LEVEL / 2, h) / k_gated, c * chi2.ppf(1 - LEVEL / 2, h) / k_gated]


def whiteness(u):
    """u: normalised innovations, NaN where an outlier left a gap."""
    rho, pairs, q, dof = [], [], 0.0, 0
    for lag in range(1, MAX_LAG + 1):
        a, b = u[lag:], u[:-lag]
        ok = ~np.isnan(a) & ~np.isnan(b)
        n = int(ok.sum())
        den = np.sqrt(np.sum(a[ok] ** 2) * np.sum(b[ok] ** 2)) if n else 0.0
        r = float(np.sum(a[ok] * b[ok]) / den) if n and den > 0 else None
        rho.append(r)
        pairs.append(n)
        if r is not None:
            q += n * r * r
            dof += 1
    return rho, pairs, q, dof


def stats(cls, nu32, s32, times, keep_update=None):
    """All per-channel numbers. keep_update(t) filters updates (in-air mode);
    idle/invalid/repeat counts always describe the whole paired sequence."""
    nu, s = nu32.astype(np.float64), s32.astype(np.float64)
    upd = [k for k, c in enumerate(cls) if c == "update"]
    dropped = 0
    if keep_update is not None:
        kept = [k for k in upd if keep_update(int(times[k]))]
        dropped, upd = len(upd) - len(kept), kept
    nis = np.array([nu[k] ** 2 / s[k] for k in upd])
    outlier = nis > GATE
    gated = nis[~outlier]
    mu, interval = truncated_interval(len(gated))
    u = np.array([nu[k] / np.sqrt(s[k]) for k in upd])
    u[outlier] = np.nan
    rho, pairs, q, dof = whiteness(u)
    wins = [gated[i - WINDOW + 1:i + 1].mean() for i in range(WINDOW - 1, len(gated))]
    out = {
        "idle": cls.count("idle"), "invalid": cls.count("invalid"),
        "zero_innovation": cls.count("zero"), "repeats": cls.count("repeat"), "updates": len(upd), "fused": len(upd) > 0,
        "outliers": int(outlier.sum()), "gated": len(gated),
        "nis_mean": num(gated.mean()) if len(gated) else None,
        "nis_mean_all": num(nis.mean()) if len(nis) else None,
        "inside_95": num(np.mean((nis >= IN95[0]) & (nis <= IN95[1]))) if len(nis) else None,
        "gated_target": mu, "interval_05": interval,
        "rho": rho, "pairs": pairs, "Q": q, "Q_dof": dof,
        "windows": len(wins),
        "windows_outside": int(sum(w < WIN_BOUNDS[0] or w > WIN_BOUNDS[1] for w in wins)),
        "window_max": num(max(wins)) if wins else None,
        "window_min": num(min(wins)) if wins else None,
    }
    # Updates per second over the span of the judged updates: n updates span n - 1 gaps.
    t = [int(times[k]) for k in upd]
    span = (max(t) - min(t)) * 1e-6 if t else 0.0
    out["update_hz"] = (len(upd) - 1) / span if len(upd) > 1 and span > 0 else 0.0
    if keep_update is not None:
        out["updates_dropped_landed"] = dropped
    return out


def in_air_filter(log):
    """Update at time t is kept if the latest land row with timestamp <= t says
    not landed; before the first land row the vehicle counts as landed."""
    land = topics(log)[("vehicle_land_detected", 0)].data
    ts, landed = land["timestamp"].astype(np.int64), land["landed"]

    def keep(t):
        i = np.searchsorted(ts, t, side="right") - 1
        return i >= 0 and not landed[i]
    return keep


def landed_at(log):
    """Whether the land detector says landed at t (no row yet: landed); None when the
    log has no land detector."""
    land = topics(log).get(("vehicle_land_detected", 0))
    if land is None:
        return None
    ts, landed = land.data["timestamp"].astype(np.int64), land.data["landed"]

    def at(t):
        i = np.searchsorted(ts, t, side="right") - 1
        return i < 0 or bool(landed[i])
    return at


def analyse(log, keep_update=None):
    """Every channel's numbers. The vertical gravity component (second order in the
    tilt error) is never judged; the horizontal ones only away from rest (these logs
    carry no status flags, so rest is the land detector's landed)."""
    pairing, chans = channels(log)
    result, not_fused, not_judged = {}, {}, []
    landed = landed_at(log)
    for inst, name, times, nu, s, exact in chans:
        keep = keep_update
        if name.endswith(".gravity[0]") or name.endswith(".gravity[1]"):
            if landed is not None:
                keep = (lambda t, k=keep_update: not landed(t) and (k is None or k(t)))
        st = result[name] = stats(classify(nu, s, exact), nu, s, times, keep)
        if name.endswith(".gravity[2]") and st["fused"]:
            st["fused"] = False
            not_judged.append(name)
        elif name.endswith((".gravity[0]", ".gravity[1]")) and not st["fused"]:
            if stats(classify(nu, s, exact), nu, s, times, keep_update)["fused"]:
                not_judged.append(name)    # updates only at rest
        elif not st["fused"]:
            not_fused[name] = {"idle": st["idle"], "invalid": st["invalid"]}
    result["_pairing"] = {f"ekf{i}": c for i, c in pairing.items()}
    result["_not_fused"] = not_fused
    result["_not_judged"] = not_judged
    return result


def table(key, res):
    print(f"\n== {key}")
    print(f"{'channel':24} {'upd':>5} {'rep':>5} {'out':>4} {'nis_mean':>10} {'rho_1':>7} {'Q':>8}")
    for name, st in res.items():
        if name.startswith("_") or not st["fused"]:
            continue
        fmt = lambda x, w, p: f"{x:>{w}.{p}f}" if x is not None else f"{'-':>{w}}"
        print(f"{name:24} {st['updates']:>5} {st['repeats']:>5} {st['outliers']:>4} "
              f"{fmt(st['nis_mean'], 10, 4)} {fmt(st['rho'][0], 7, 3)} {fmt(st['Q'], 8, 2)}")
    print(f"not fused: {', '.join(res['_not_fused']) or '-'}")
    print(f"pairing: {res['_pairing']}")


def main():
    check_pairing_rule()
    ref = {"_versions": {"python": platform.python_version(), "pyulog": version("pyulog"),
                         "numpy": np.__version__, "scipy": scipy.__version__},
           "_constants": {"gate": GATE, "inside_95": list(IN95), "window": WINDOW,
                          "window_bounds": list(WIN_BOUNDS), "max_pair_us": MAX_PAIR_US,
                          "interval_level": LEVEL, "max_lag": MAX_LAG}}
    for fn in FILES:
        log = pyulog.ULog(os.path.join(HERE, fn))
        ref[fn] = analyse(log)
        if fn in IN_AIR_FILES:
            ref[fn + "#in_air"] = analyse(log, in_air_filter(log))
    with open(os.path.join(HERE, "reference.json"), "w") as f:
        json.dump(ref, f, indent=1, allow_nan=False)
        f.write("\n")
    for key, res in ref.items():
        if not key.startswith("_"):
            table(key, res)
    print("\nfixture sizes:", {fn: os.path.getsize(os.path.join(HERE, fn)) for fn in FILES})


if __name__ == "__main__":
    main()
