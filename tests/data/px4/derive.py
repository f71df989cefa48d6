#!/usr/bin/env python3
"""Trim the two real PX4 logs down to what `autotune nis` reads.

The originals (3.4 MB together) live outside the repository. This script walks
the ULog byte stream itself (rather than re-serialising through pyulog) so the
kept messages are byte-for-byte the ones PX4 wrote, then uses pyulog only as an
independent check that nothing the nis command reads has changed.

Usage: derive.py [SOURCE_DIR]   (default /work/shared/data/px4)
Writes v1_13_three_ekf.ulg and v1_15_events.ulg next to this script.
"""
import os
import struct
import sys

import pyulog

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_SOURCE = "/work/shared/data/px4"
OUTPUTS = {
    "sample_logging_tagged_and_default_params.ulg": "v1_13_three_ekf.ulg",
    "sample_px4_events.ulg": "v1_15_events.ulg",
}
KEEP_TOPICS = {"estimator_innovations", "estimator_innovation_variances", "vehicle_land_detected"}
MAGIC = b"ULog\x01\x12\x35"   # 7 bytes, then 1 version byte, then u64 start time
MAX_INFO_PAYLOAD = 1024       # larger info messages (e.g. boot console dumps) are not needed


def walk(buf):
    """Yield (offset, type char, payload) for every message after the header.

    A log that ends in the middle of a message is treated as an error: the
    fixtures must be complete so that the Rust reader and this script agree on
    every row."""
    pos = 16
    while pos < len(buf):
        if pos + 3 > len(buf):
            raise ValueError(f"truncated message header at offset {pos}")
        size, mtype = struct.unpack_from("<HB", buf, pos)
        end = pos + 3 + size
        if end > len(buf):
            raise ValueError(f"truncated message payload at offset {pos}")
        yield pos, chr(mtype), buf[pos + 3:end]
        pos = end


def check_flag_bits(payload):
    """The 'B' message may announce data appended after the end of the normal
    stream (offsets into the file). Trimming would silently invalidate those
    offsets, so refuse such a log instead of producing a subtly broken file."""
    if len(payload) < 40:
        raise ValueError(f"flag bits message too short ({len(payload)} bytes)")
    incompat = payload[8:16]
    offsets = struct.unpack_from("<3Q", payload, 16)
    if any(offsets):
        raise ValueError(f"appended-data offsets are set: {offsets}; cannot trim")
    if any(incompat):
        raise ValueError(f"incompatible flags set: {incompat.hex()}; cannot trim")


def trim(buf):
    """Return (trimmed bytes, counts of kept/dropped messages per type)."""
    if buf[:7] != MAGIC:
        raise ValueError("not a ULog file (bad magic)")
    out = bytearray(buf[:16])          # header kept verbatim (version + start time)
    kept_ids = set()                   # msg_ids subscribed to a kept topic
    kept, dropped = {}, {}
    first = True
    for pos, mtype, payload in walk(buf):
        if first:
            # The spec requires 'B' to be the first message; without it we
            # could not have checked for appended data.
            if mtype != "B":
                raise ValueError(f"first message is '{mtype}', expected flag bits 'B'")
            check_flag_bits(payload)
            first = False
            keep = True
        elif mtype == "B":
            raise ValueError(f"second flag bits message at offset {pos}")
        elif mtype == "F":
            keep = True                # formats are tiny and nested types may be needed
        elif mtype == "I":
            keep = len(payload) <= MAX_INFO_PAYLOAD
        elif mtype == "A":
            multi_id, msg_id = struct.unpack_from("<BH", payload, 0)
            topic = payload[3:].decode("ascii")
            keep = topic in KEEP_TOPICS
            if keep:
                kept_ids.add(msg_id)
            elif msg_id in kept_ids:
                # an id reused for a dropped topic would make us keep foreign data
                raise ValueError(f"msg_id {msg_id} re-subscribed as {topic}")
        elif mtype == "D":
            (msg_id,) = struct.unpack_from("<H", payload, 0)
            keep = msg_id in kept_ids
        elif mtype == "R":
            (msg_id,) = struct.unpack_from("<H", payload, 0)
            if msg_id in kept_ids:
                raise ValueError(f"kept msg_id {msg_id} unsubscribed; not handled")
            keep = False
        else:
            keep = False               # P, Q, M, L, C, S, O and anything unknown
        tally = kept if keep else dropped
        tally[mtype] = tally.get(mtype, 0) + 1
        if keep:
            out += buf[pos:pos + 3 + len(payload)]
    return bytes(out), kept, dropped


def topic_map(ulog):
    return {(d.name, d.multi_id): d for d in ulog.data_list}


def verify(src_path, dst_path):
    """Every field of every kept (topic, multi_id) must be bit-identical.

    Comparing raw bytes (not values) makes NaN rows compare equal and catches
    any change of dtype."""
    orig_log = pyulog.ULog(src_path)
    trimmed_log = pyulog.ULog(dst_path)
    orig, trimmed = topic_map(orig_log), topic_map(trimmed_log)
    want = {k for k in orig if k[0] in KEEP_TOPICS}
    if set(trimmed) != want:
        raise AssertionError(f"topic set differs: {sorted(set(trimmed) ^ want)}")
    for key in sorted(want):
        a, b = orig[key].data, trimmed[key].data
        if list(a) != list(b):
            raise AssertionError(f"{key}: field lists differ")
        for field in a:
            if a[field].dtype != b[field].dtype or a[field].tobytes() != b[field].tobytes():
                raise AssertionError(f"{key} {field}: values differ")
        print(f"    {key[0]}[{key[1]}]: {len(a['timestamp'])} rows, "
              f"{len(a)} fields identical")
    if trimmed_log.has_data_appended:
        raise AssertionError("trimmed file claims appended data")
    # kept info messages (version strings etc.) must read back unchanged
    for key, value in trimmed_log.msg_info_dict.items():
        if orig_log.msg_info_dict.get(key) != value:
            raise AssertionError(f"info {key} differs")
    return trimmed_log


def main():
    source = sys.argv[1] if len(sys.argv) > 1 else DEFAULT_SOURCE
    for src_name, dst_name in OUTPUTS.items():
        src = os.path.join(source, src_name)
        dst = os.path.join(HERE, dst_name)
        with open(src, "rb") as f:
            data = f.read()
        out, kept, dropped = trim(data)
        with open(dst, "wb") as f:
            f.write(out)
        print(f"{src_name} ({len(data)} B) -> {dst_name} ({len(out)} B)")
        print(f"    kept    {dict(sorted(kept.items()))}")
        print(f"    dropped {dict(sorted(dropped.items()))}")
        log = verify(src, dst)
        print(f"    info kept: {sorted(log.msg_info_dict)}")
    print("ok")


if __name__ == "__main__":
    main()
