"""Benchmark (not a test): the timing of ``deltaslice play``'s goal packets on this machine, a
pseudo-terminal standing in for the Dynamixel bus (drained by another process, as a USB adapter
would be), at real-time priority (SCHED_FIFO, where allowed) and at ordinary priority:

    python benchmarks/bench_play.py [--seconds 20] [--rounds 1]

A stretch of an ESPE engraving (1 kHz, three AX-12 goals per packet) is played through
``deltaslice.play.play``, the code the command runs. Prints per run: the packets written, how
late each was written after the time it was meant for (median, 99th and 99.9th percentiles,
max), how many were written more than 1 and 10 ms late, and how many were skipped (the player
woke after the next one was due and sent the sample due then), with the load average. Then what
a real bus carries: the packet's time on the wire at 1 Mbps and 57600 baud, protocol 1.0 and 2.0.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import tty
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from trajectories import blocks, printer, realistic  # noqa: E402

from deltaslice.pipeline import read_counts, write_samples  # noqa: E402
from deltaslice.play import BUSES, bus_seconds, decimation, open_bus, play  # noqa: E402


def run(counts, rate, realtime: bool) -> str:
    master, slave = os.openpty()
    tty.setraw(slave)
    child = os.fork()
    if child == 0:  # the bus's far end, in its own process
        try:
            while os.read(master, 65536):
                pass
        finally:
            os._exit(0)
    bus = open_bus(os.ttyname(slave), 1_000_000)
    try:
        r = play(counts, [], rate=rate, n_joints=3, bus_port=bus, baud=1_000_000, ids=[1, 2, 3], realtime=realtime)
    finally:
        bus.closePort()
        os.close(slave)
        os.kill(child, 9)
        os.waitpid(child, 0)
        os.close(master)
    ms = r.late * 1e3
    return (f"{'real-time' if r.realtime else 'ordinary '} {r.packets} packets of {len(counts)} samples in "
            f"{r.seconds:.3f} s (job {(len(counts) - 1) / rate:.3f} s); late median {np.median(ms):.3f} ms, "
            f"p99 {np.percentile(ms, 99):.3f}, p99.9 {np.percentile(ms, 99.9):.3f}, max {ms.max():.1f}; "
            f"over 1 ms {(ms > 1).sum()}, over 10 ms {(ms > 10).sum()}; skipped {r.skipped}; load {os.getloadavg()[0]:.1f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rounds", type=int, default=1)
    args = ap.parse_args()
    p = printer("delta_espe_laser")
    s, _ = realistic("delta_espe_laser", layers=2)
    n = min(len(s), int(args.seconds * p.planning.output_rate))
    s = s.__class__(s.t[:n], s.q[:n], s.e[:n], s.tool[:n])
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "espe.dsl"
        write_samples(blocks(s, 2500), p, path, fmt="stream", rate=p.planning.output_rate)
        header, counts = read_counts(path)
    for _ in range(args.rounds):
        for realtime in (True, False):
            print(run(counts, header.rate, realtime), flush=True)
    for proto in (1, 2):
        nbytes = BUSES[proto].packet_bytes(3)
        for baud in (1_000_000, 57_600):
            us = bus_seconds(nbytes, baud) * 1e6
            k = decimation(BUSES[proto], 3, baud, header.rate)
            print(f"protocol {proto}.0, 3 servos: {nbytes} bytes, {us:.0f} us at {baud} baud: at most "
                  f"{1e6 / us:.0f} packets/s, every {k} sample(s) at {header.rate:g} Hz "
                  f"({us * header.rate / 1e4 / k:.0f} % of the bus)")


if __name__ == "__main__":
    main()
