#!/usr/bin/env python3
"""Write synthetic ULog fixtures with known ground truth for `autotune nis`.

legacy_ekf2.ulg  old single-topic `ekf2_innovations` + `vehicle_land_detected`;
                 mag_innov[2] is deliberately overconfident (variance / 25).
white_new.ulg    new `estimator_innovations` / `estimator_innovation_variances`
                 pair, two instances, a consistent filter, with pairing quirks in
                 instance 1 and three gross baro outliers in instance 0.

The ULog writer below is deliberately minimal (header, 'B', 'F', 'A', 'D') and
independent of pyulog; pyulog is used afterwards only to prove the files load.
"""
import os
import struct

import numpy as np
import pyulog

HERE = os.path.dirname(os.path.abspath(__file__))
SEED = 20261123

# ULog type name -> numpy dtype. Little endian, and structured dtypes built from
# these are packed (no implicit padding), exactly like ULog data rows.
NP_TYPES = {"uint64_t": "<u8", "float": "<f4", "bool": "u1", "uint8_t": "u1"}


def parse_fields(spec):
    """'uint64_t timestamp;float[2] x;' -> [(type, count or 0, name), ...]"""
    out = []
    for item in filter(None, (s.strip() for s in spec.split(";"))):
        typ, name = item.split()
        count = 0
        if "[" in typ:
            typ, count = typ[:-1].split("[")
            count = int(count)
        out.append((typ, count, name))
    return out


def row_dtype(spec):
    return np.dtype([(name, NP_TYPES[t], (n,)) if n else (name, NP_TYPES[t])
                     for t, n, name in parse_fields(spec)])


class ULogWriter:
    def __init__(self, start_us=0):
        # magic, file version 1, logging start time
        self.buf = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", start_us))
        # flag bits: no compat/incompat flags, no appended data
        self._msg("B", bytes(40))
        self.formats = {}
        self.subs = []

    def _msg(self, mtype, payload):
        self.buf += struct.pack("<HB", len(payload), ord(mtype)) + payload

    def format(self, name, spec):
        self._msg("F", f"{name}:{spec}".encode("ascii"))
        self.formats[name] = row_dtype(spec)

    def subscribe(self, name, multi_id):
        msg_id = len(self.subs)
        self._msg("A", struct.pack("<BH", multi_id, msg_id) + name.encode("ascii"))
        self.subs.append(name)
        return msg_id

    def data(self, msg_id, row):
        raw = row.tobytes()
        dtype = self.formats[self.subs[msg_id]]
        # PX4 does not write the trailing _padding bytes of a row; do the same so
        # readers are exercised on short rows as found in real logs.
        if dtype.names[-1].startswith("_padding"):
            raw = raw[:dtype.fields[dtype.names[-1]][1]]
        self._msg("D", struct.pack("<H", msg_id) + raw)

    def write(self, path, rows):
        """rows: iterable of (timestamp, order, msg_id, record); written sorted so
        the file is in time order like a real log."""
        for _, _, msg_id, rec in sorted(rows, key=lambda r: r[:2]):
            self.data(msg_id, rec)
        with open(path, "wb") as f:
            f.write(self.buf)


def slow_variance(base, n, rng):
    """Per-row variance varying slowly within +-20 % so NIS must use each row's S."""
    phase = rng.uniform(0, 2 * np.pi)
    return base * (1 + 0.2 * np.sin(np.linspace(0, 6 * np.pi, n) + phase))


LEGACY_SPEC = ("uint64_t timestamp;float[6] vel_pos_innov;float[3] mag_innov;float heading_innov;"
               "float airspeed_innov;float[2] flow_innov;float hagl_innov;"
               "float[6] vel_pos_innov_var;float[3] mag_innov_var;float heading_innov_var;"
               "float airspeed_innov_var;float[2] flow_innov_var;float hagl_innov_var;")
# 8 + 28 * 4 = 120 bytes: already a multiple of 8, so no padding is needed.
LAND_SPEC = "uint64_t timestamp;bool landed;uint8_t[7] _padding0;"


def legacy(path, rng):
    n, dt = 1000, 20_000                       # 20 s of 50 Hz rows
    t = dt * np.arange(1, n + 1, dtype=np.uint64)  # 0.02 .. 20.00 s
    k = np.arange(n)
    w = ULogWriter()
    w.format("ekf2_innovations", LEGACY_SPEC)
    w.format("vehicle_land_detected", LAND_SPEC)
    mid = w.subscribe("ekf2_innovations", 0)
    lid = w.subscribe("vehicle_land_detected", 0)
    rec = np.zeros(n, w.formats["ekf2_innovations"])
    rec["timestamp"] = t

    def channel(field, j, true_var, fused, overconfidence=1.0):
        var = slow_variance(true_var, n, rng)
        nu = rng.standard_normal(n) * np.sqrt(var)
        # between fusions PX4 keeps publishing the last fused value: hold it
        last = np.maximum.accumulate(np.where(fused, k, 0))
        cols = (rec[f"{field}_innov"], rec[f"{field}_innov_var"])
        for col, val in zip(cols, (nu[last], var[last] / overconfidence)):
            if j is None:
                col[:] = val
            else:
                col[:, j] = val

    for j, v in enumerate([0.3, 0.3, 0.5, 2.0, 2.0, 4.0]):
        channel("vel_pos", j, v, k % 10 == 0)             # 5 Hz
    for j, v in enumerate([0.6, 0.7, 0.9]):
        channel("mag", j, v, np.ones(n, bool), 25.0 if j == 2 else 1.0)
    channel("heading", None, 1.5, k % 5 == 0)            # 10 Hz
    # airspeed and flow never fused: stay exactly 0/0 from np.zeros
    rec["hagl_innov"] = np.nan
    rec["hagl_innov_var"] = np.nan

    land = np.zeros(20, w.formats["vehicle_land_detected"])
    land["timestamp"] = 1_000_000 * np.arange(1, 21, dtype=np.uint64)   # 1 .. 20 s
    ts = land["timestamp"] / 1e6
    land["landed"] = (ts < 5) | (ts >= 15)
    rows = [(int(r["timestamp"]), 0, mid, r) for r in rec]
    rows += [(int(r["timestamp"]), 1, lid, r) for r in land]
    w.write(path, rows)


NEW_SPEC = ("uint64_t timestamp;uint64_t timestamp_sample;float[2] gps_hvel;float gps_vvel;"
            "float[2] gps_hpos;float gps_vpos;float baro_vpos;float heading;")
NEW_CHANNELS = {  # field -> true variance per element
    "gps_hvel": [0.3, 0.35], "gps_vvel": [0.5], "gps_hpos": [2.0, 2.5],
    "gps_vpos": [4.0], "baro_vpos": [1.2], "heading": [0.4]}
VAR_SHIFT_US = 12_000        # instance 1: variances logged 12 ms later
UNPAIRED_ROWS = [700, 1401]  # instance 1: one gps fusion row, one gps hold row


def white(path, rng):
    n, dt = 2000, 100_000                      # 200 s of 10 Hz rows
    k = np.arange(n)
    w = ULogWriter()
    w.format("estimator_innovations", NEW_SPEC)
    w.format("estimator_innovation_variances", NEW_SPEC)
    rows = []
    for inst in (0, 1):
        ids = [w.subscribe(name, inst) for name in
               ("estimator_innovations", "estimator_innovation_variances")]
        inn = np.zeros(n, w.formats["estimator_innovations"])
        var = np.zeros(n, w.formats["estimator_innovations"])
        sample = 500_000 + dt * k.astype(np.uint64) + 1000 * inst
        inn["timestamp_sample"] = var["timestamp_sample"] = sample
        inn["timestamp"] = var["timestamp"] = sample + 1500   # publication latency
        idle = np.zeros(n, bool)
        idle[rng.choice(n, n // 100, replace=False)] = True   # 1 % heading idle rows
        for field, bases in NEW_CHANNELS.items():
            for j, base in enumerate(bases):
                s = slow_variance(base, n, rng)
                nu = rng.standard_normal(n) * np.sqrt(s)
                if field.startswith("gps"):
                    last = k - (k % 2)                        # 5 Hz: every 2nd row held
                    nu, s = nu[last], s[last]
                if field == "baro_vpos" and inst == 0:
                    # gross outliers: NIS = 1600, far above any gate
                    for row, sign in ((400, 1), (1000, -1), (1600, 1)):
                        nu[row] = sign * 40 * np.sqrt(s[row])
                if field == "heading":
                    nu, s = np.where(idle, 0.0, nu), np.where(idle, 0.0, s)
                if inn[field].ndim == 2:
                    inn[field][:, j], var[field][:, j] = nu, s
                else:
                    inn[field], var[field] = nu, s
        if inst == 1:
            # a subsampling logger stamps the variances topic a bit later ...
            var["timestamp_sample"] += VAR_SHIFT_US
            var["timestamp"] += VAR_SHIFT_US
            # ... and sometimes misses one entirely
            var = np.delete(var, UNPAIRED_ROWS)
        rows += [(int(r["timestamp"]), 2 * inst, ids[0], r) for r in inn]
        rows += [(int(r["timestamp"]), 2 * inst + 1, ids[1], r) for r in var]
    w.write(path, rows)


def check(path, expect):
    """Load with pyulog and make sure the topics and row counts are as written."""
    log = pyulog.ULog(path)
    got = {(d.name, d.multi_id): len(d.data["timestamp"]) for d in log.data_list}
    if got != expect:
        raise AssertionError(f"{path}: {got} != {expect}")
    print(f"{os.path.basename(path)}: {os.path.getsize(path)} B, {got}")
    return log


def main():
    rng = np.random.default_rng(SEED)
    p = os.path.join(HERE, "legacy_ekf2.ulg")
    legacy(p, rng)
    log = check(p, {("ekf2_innovations", 0): 1000, ("vehicle_land_detected", 0): 20})
    d = log.get_dataset("ekf2_innovations").data
    assert np.all(np.isnan(d["hagl_innov"])) and not np.any(d["airspeed_innov_var"])
    p = os.path.join(HERE, "white_new.ulg")
    white(p, rng)
    check(p, {("estimator_innovations", 0): 2000, ("estimator_innovation_variances", 0): 2000,
              ("estimator_innovations", 1): 2000, ("estimator_innovation_variances", 1): 1998})
    print("ok")


if __name__ == "__main__":
    main()
