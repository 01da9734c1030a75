"""The ESPE's laser player on the Uno (examples/firmware/uno_laser_player.c) in simavr, its laser
pin's PWM duty measured (examples/firmware/sim_laser.c: the pin's high time in windows of 8 PWM
periods):

* fed the frames ``deltaslice play`` sends for a stream, at the times it sends them (its own
  code, run on a virtual clock), the pin's duty equals the stream's power channel (0 while the
  laser mode is off) at every moment, and the laser is off after the end;
* the laser goes off on a host time-out (250 ms without a frame) and on a damaged frame, and
  stays off, saying so, whatever the host sends next.

They need avr-gcc, avr-libc and simavr (Debian: gcc-avr avr-libc simavr libsimavr-dev
libelf-dev); they skip without them, except under CI (env CI set), where .ci/run installs them.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from trajectories import ROOT, blocks, printer, realistic

from deltaslice.pipeline import read_counts, write_samples
from deltaslice.play import laser_duty, laser_frame, play

FIRMWARE = ROOT / "examples" / "firmware"
CYCLES_PER_MS = 16000
WINDOW_MS = 16384 / CYCLES_PER_MS
EVENTS = [(0, 6, 4.0), (1800, 6, 0.0), (2200, 6, 4.0)]


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    missing = None if shutil.which("avr-gcc") and shutil.which("make") else "avr-gcc or make"
    if not missing and not Path("/usr/include/simavr/sim_avr.h").exists():
        missing = "libsimavr-dev"
    if missing:
        if os.environ.get("CI"):
            pytest.fail(f"{missing} missing under CI: .ci/run installs the Debian packages")
        pytest.skip(f"{missing} not installed (apt-get install gcc-avr avr-libc simavr libsimavr-dev libelf-dev)")
    out = tmp_path_factory.mktemp("laser")
    r = subprocess.run(["make", "-C", str(FIRMWARE), f"BUILD={out}", f"{out}/uno_laser_player.elf", f"{out}/sim_laser"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    return out


def simulate(build, tmp_path, writes, seconds):
    """writes: [(ms, bytes)]. Returns (duty per 1.024 ms window, [(ms, line)])."""
    script = tmp_path / "script.txt"
    script.write_text("".join(f"{ms:.4f} {data.hex(' ')}\n" for ms, data in writes))
    r = subprocess.run([str(build / "sim_laser"), str(build / "uno_laser_player.elf"), str(script), "--seconds",
                        str(seconds)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    high = np.array([int(ln.split()[2]) for ln in r.stdout.splitlines() if ln.startswith("D ")])
    lines = [(int(ln.split()[1]) / CYCLES_PER_MS, ln.split(" ", 2)[2]) for ln in r.stdout.splitlines()
             if ln.startswith("L ")]
    # a duty d held over a window is high 8 periods x d ticks x 8 cycles (simavr: +-2 cycles)
    duty = high / 64.0
    held = np.abs(duty - np.rint(duty)) < 0.1
    return np.where(held, np.rint(duty), -1).astype(int), lines


class Clock:
    """Virtual time for play(): sleeping advances it."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t

    def sleep(self, s):
        self.t += max(s, 1e-5)


class FakeBus:
    """What dynamixel_sdk's packet layer uses of a PortHandler."""

    is_using = False

    def clearPort(self):
        pass

    def writePort(self, packet):
        return len(packet)

    def getPortName(self):
        return "bus"


class LaserLink:
    """The laser port: records (virtual ms, bytes); answers a query as the board does."""

    def __init__(self, clock):
        self.clock, self.writes, self.rx = clock, [], bytearray()

    def write(self, data):
        self.writes.append((self.clock() * 1e3, bytes(data)))
        if data[:1] == b"Q":
            self.rx += b"LASER 250\n"
        return len(data)

    @property
    def in_waiting(self):
        return len(self.rx)

    def read(self, n):
        out, self.rx = bytes(self.rx[:n]), self.rx[n:]
        return out

    def flush(self):
        pass


@pytest.fixture(scope="module")
def espe(tmp_path_factory):
    p = printer("delta_espe_laser")
    s, _ = realistic("delta_espe_laser", layers=1)
    n = 3000
    s = s.__class__(s.t[:n], s.q[:n], s.e[:n], s.tool[:n])
    path = tmp_path_factory.mktemp("espe") / "espe.dsl"
    write_samples(blocks(s, 1000), p, path, fmt="stream", rate=p.planning.output_rate, events=EVENTS)
    return read_counts(path)


def test_laser_duty_follows_the_stream_as_play_sends_it(build, tmp_path, espe):
    header, counts = espe
    clock = Clock()
    link = LaserLink(clock)
    start = []
    bus = FakeBus()
    real = bus.writePort

    def goal(packet):  # the time of the first paced goal packet: sample 0 is due then
        if packet[5] == 30 and len(start) < 2:
            start.append(clock() * 1e3)
        return real(packet)

    bus.writePort = goal
    res = play(counts, EVENTS, rate=header.rate, n_joints=3, bus_port=bus, baud=1_000_000, ids=[1, 2, 3],
               laser_port=link, clock=clock, sleep=clock.sleep, realtime=False)
    assert res.samples == len(counts)
    t0 = start[1]  # the first is the rest goal written before torque goes on
    end_ms = link.writes[-1][0]
    duty_w, lines = simulate(build, tmp_path, link.writes, seconds=(end_ms + 600) / 1e3)
    assert lines[0][1] == "LASER 250" and lines[-1][1].startswith("OK ")
    assert not [ln for _, ln in lines if ln.startswith("ERR")]  # no time-out after the end either
    expect = laser_duty(counts, EVENTS, 3)
    assert (expect > 0).any() and (expect[1800:2200] == 0).all() and (counts[1800:2200, 3] > 0).any()
    # the end frame goes right after the last sample's: from its time on, off
    timeline = np.append(expect[:-1], 0)
    compared = 0
    for w, d in enumerate(duty_w):
        a, b = w * WINDOW_MS, (w + 1) * WINDOW_MS
        # the sample played from each time (a frame takes 0.26 ms on the wire): those the window sees
        lo, hi = int(np.floor(a - t0 - 0.5)), int(np.floor(b - t0 + 0.5))
        if hi < 0:
            assert d == 0, w  # before the job: off
            continue
        seen = timeline[np.clip(np.arange(lo, hi + 1), 0, len(counts) - 1)]
        if (seen == seen[0]).all():
            assert d == seen[0], (w, d, seen[0])
            compared += 1
    assert compared > 0.9 * len(counts) / WINDOW_MS


def frames(*items):
    return [(ms, laser_frame(ord(k), v)) for ms, k, v in items]


def test_laser_off_on_a_host_time_out_and_stays_off(build, tmp_path):
    writes = frames((10, "L", 200), (60, "L", 200), (110, "L", 200), (500, "L", 50), (520, "Q", 0))
    duty, lines = simulate(build, tmp_path, writes, seconds=0.7)
    t = (np.arange(len(duty)) + 0.5) * WINDOW_MS
    assert (duty[(t > 12) & (t < 355)] == 200).all()
    assert (duty[t > 362] == 0).all()  # 250 ms after the last frame (110 ms)
    errs = [(ms, ln) for ms, ln in lines if ln.startswith("ERR")]
    # (the line ends 3.3 ms after it starts)
    assert errs[0][1] == "ERR host silent: laser off until reset" and 360 < errs[0][0] < 364.5, errs
    assert len(errs) == 3 and all(ln == errs[0][1] for _, ln in errs)  # to every later frame, the query too


def test_laser_off_on_a_damaged_frame(build, tmp_path):
    bad = bytes([ord("L"), 100, 0x00])
    writes = frames((10, "L", 100)) + [(50, bad)] + frames((60, "L", 100), (80, "L", 100))
    duty, lines = simulate(build, tmp_path, writes, seconds=0.2)
    t = (np.arange(len(duty)) + 0.5) * WINDOW_MS
    assert (duty[(t > 12) & (t < 49)] == 100).all() and (duty[t > 52] == 0).all()
    errs = [ln for _, ln in lines if ln.startswith("ERR")]
    assert errs == ["ERR bad frame (check byte): laser off until reset"] * 3


def test_play_keeps_the_laser_alive_between_sparse_packets(espe):
    # packets 300 ms apart (--interval 300): the board's 250 ms time-out still never fires
    header, counts = espe
    clock = Clock()
    link = LaserLink(clock)
    play(counts, EVENTS, rate=header.rate, n_joints=3, bus_port=FakeBus(), baud=1_000_000, ids=[1, 2, 3],
         laser_port=link, clock=clock, sleep=clock.sleep, realtime=False, min_interval=0.3)
    times = np.array([ms for ms, data in link.writes if data[:1] in (b"L", b"E")])
    assert times[-1] - times[0] > 2900 and np.diff(times).max() <= 0.25 * 250 + 20, np.diff(times).max()
