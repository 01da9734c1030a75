"""Measure the binary stream's size and speed on realistic synthetic prints.

    python benchmarks/stream_bench.py

Prints bytes per sample for several coding choices (zig-zag varints of first or
second differences; per-block bit packing with first, second or per-block best
order; block sizes), the CSV size of the same samples, and the time to encode
and decode one hour at 1 kHz (3.6 M samples). Results go in docs/benchmarks.md.
"""

from __future__ import annotations

import io
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from trajectories import blocks, long_print, printer, realistic  # noqa: E402

from deltaslice.emit import csv as csvfmt  # noqa: E402
from deltaslice.emit import stream  # noqa: E402
from deltaslice.samples import to_counts  # noqa: E402
from deltaslice.verify import verify_samples  # noqa: E402


def varint_size(counts, order):
    d = np.diff(counts, n=order, axis=0)
    u = stream.zigzag(d).ravel()
    nbytes = np.ones(u.shape, dtype=np.int64)
    for k in range(1, 10):
        nbytes += u >= (np.uint64(1) << np.uint64(7 * k))
    return int(nbytes.sum())


def main():
    cases = [
        ("delta_etitc", "feed (30/60/130 mm/s, 1500 mm/s^2)", dict(accel=1500.0), (30.0, 60.0, 130.0)),
        ("delta_etitc", "fast (60/120/300 mm/s, 5000 mm/s^2)", dict(accel=5000.0), (60.0, 120.0, 300.0)),
        ("linear_kossel", "feed", dict(accel=1500.0), (30.0, 60.0, 130.0)),
        ("linear_kossel", "fast", dict(accel=3000.0), (60.0, 120.0, 300.0)),
        ("delta_ucb", "feed", dict(accel=1500.0), (30.0, 60.0, 130.0)),
        ("delta_ucb", "fast", dict(accel=5000.0), (60.0, 120.0, 300.0)),
        ("fivebar_atlas", "feed", dict(accel=1500.0), (30.0, 60.0, 130.0)),
        ("fivebar_atlas", "fast", dict(accel=3000.0), (60.0, 120.0, 300.0)),
    ]
    print("| printer | profile | samples | varint d1 | varint d2 | bits d1 | bits d2 | bits best | 256/blk | 512/blk (default) | CSV |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, label, kw, feeds in cases:
        s, _ = realistic(name, layers=2, feeds=feeds, **kw)
        p = printer(name)
        assert verify_samples(s, p, rate=1000.0, fmt="csv").ok, f"{name} {label}: synthetic trajectory breaks a limit"
        c = to_counts(p, s)
        n = len(s)

        def bits(orders, bs=stream.BLOCK_SAMPLES):
            return sum(len(r) for r in stream.encode_blocks(c, bs, orders=orders)) / n

        csv_size = len(csvfmt.format_rows(s.t, s.q, s.e, s.tool).encode()) / n
        print(
            f"| {name} | {label} | {n} | {varint_size(c, 1) / n:.2f} | {varint_size(c, 2) / n:.2f} | {bits((1,)):.2f} | "
            f"{bits((2,)):.2f} | {bits((1, 2)):.2f} | {bits((1, 2), 256):.2f} | {bits((1, 2), 512):.2f} | {csv_size:.1f} |"
        )

    p = printer("delta_etitc")
    s, _ = realistic("delta_etitc", layers=2)
    n_hour = 3_600_000
    buf = io.BytesIO()
    t0 = time.perf_counter()
    w = stream.StreamWriter(buf, p, 1000.0, {"planner": "bench"})
    for b in long_print(s, n_hour):
        for part in blocks(b, 4096):
            w.write(part)
    size = w.close()
    t_enc = time.perf_counter() - t0
    buf.seek(0)
    t0 = time.perf_counter()
    r = stream.StreamReader(buf)
    total = sum(len(cnt) for _i, _f, cnt in r.blocks())
    t_dec = time.perf_counter() - t0
    print(f"\n1 h at 1 kHz ({total} samples, delta_etitc): {size / 1e6:.2f} MB, {size / total:.3f} B/sample, "
          f"encode {t_enc:.1f} s (incl. to_counts and checks), decode {t_dec:.1f} s")


if __name__ == "__main__":
    main()
