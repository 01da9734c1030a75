"""``deltaslice play`` on pseudo-terminals standing in for a Dynamixel bus and the laser board:
every packet on the bus is a protocol 1.0 SYNC_WRITE with a valid checksum, torque on before
the first goal, the goals paced in real time (first to last within 10 % of the job's duration)
and equal to the stream's counts at the time each packet arrives within 1 count; the laser's
duty goes to the second port (its frames checked, off at every stop), and pause, abort and a
board's error each stop it cleanly."""

from __future__ import annotations

import contextlib
import os
import select
import subprocess
import sys
import threading
import time
import tty

import numpy as np
import pytest
from trajectories import ROOT, blocks, printer, realistic

from deltaslice.pipeline import read_counts, write_samples
from deltaslice.play import BUSES, decimation, laser_duty, laser_frame

try:
    import dynamixel_sdk  # noqa: F401
except ImportError:
    if os.environ.get("CI"):
        pytest.fail("dynamixel-sdk missing under CI: it is a dependency in pyproject.toml", pytrace=False)
    pytest.skip("dynamixel-sdk not installed (pip install dynamixel-sdk)", allow_module_level=True)

SECONDS = 3.0


def checksum_ok(packet: bytes) -> bool:
    """Protocol 1.0 (ROBOTIS e-Manual): CHECKSUM = ~(ID + LENGTH + INSTRUCTION + params) & 0xFF."""
    return (~sum(packet[2:-1]) & 0xFF) == packet[-1]


def split_packets(data: bytes, times: list[float]) -> list[tuple[float, bytes]]:
    """FF FF ID LENGTH ... packets with the arrival time of their last byte."""
    out, k = [], 0
    while k < len(data):
        assert data[k:k + 2] == b"\xff\xff", (k, data[k:k + 8].hex())
        end = k + 4 + data[k + 3]
        assert end <= len(data), "a packet cut short"
        out.append((times[end - 1], data[k:end]))
        k = end
    return out


class Pty:
    """A pseudo-terminal pair: the program opens ``name``; this side records what arrives, with times."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.name = os.ttyname(self.slave)
        self.data, self.times = bytearray(), []
        self.stop = False
        self.on_byte = None
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        # the times are the packets' times on the "bus": this reader must not lag behind the player
        with contextlib.suppress(AttributeError, OSError):
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(30))
        while not self.stop:
            if not select.select([self.master], [], [], 0.05)[0]:
                continue
            try:
                chunk = os.read(self.master, 4096)
            except OSError:
                continue
            now = time.monotonic()
            for b in chunk:
                self.data.append(b)
                self.times.append(now)
                if self.on_byte:
                    self.on_byte(b, now)

    def close(self):
        self.stop = True
        self.thread.join()
        os.close(self.master)
        os.close(self.slave)


class LaserBoard(Pty):
    """What uno_laser_player.c answers: its banner to a query, ``OK`` to the end frame; or an
    ``ERR`` line after ``fail_after`` frames."""

    def __init__(self, fail_after=None):
        super().__init__()
        self.frames: list[tuple[float, int, int]] = []
        self.pending = bytearray()
        self.fail_after = fail_after
        self.on_byte = self._byte

    def _byte(self, b, now):
        self.pending.append(b)
        if len(self.pending) < 3:
            return
        kind, value, check = self.pending
        self.pending.clear()
        assert check == (~(kind + value) & 0xFF), (kind, value, check)
        self.frames.append((now, kind, value))  # the time of the read that brought it
        if kind == ord("Q"):
            os.write(self.master, b"LASER 250\n")
        elif kind == ord("E"):
            os.write(self.master, f"OK {len(self.frames)}\n".encode())
        elif self.fail_after is not None and len(self.frames) == self.fail_after:
            os.write(self.master, b"ERR bad frame\n")


@pytest.fixture(scope="module")
def espe_stream(tmp_path_factory):
    """Three seconds of an ESPE engraving: the joints moving, the power varying, M5 for a while."""
    p = printer("delta_espe_laser")
    s, _ = realistic("delta_espe_laser", layers=1)
    n = int(SECONDS * p.planning.output_rate)
    s = s.__class__(s.t[:n], s.q[:n], s.e[:n], s.tool[:n])
    path = tmp_path_factory.mktemp("play") / "espe.dsl"
    write_samples(blocks(s, 1000), p, path, fmt="stream", rate=p.planning.output_rate,
                  events=[(0, 6, 4.0), (1800, 6, 0.0), (2200, 6, 4.0)])
    return path


def run_play(stream, bus, laser=None, *args, timeout=60):
    cmd = [sys.executable, "-m", "deltaslice", "play", str(stream), "--dynamixel", bus.name, "--quiet", *args]
    if laser is not None:
        cmd += ["--laser", laser.name]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT, stdin=subprocess.DEVNULL)
    time.sleep(0.1)  # the readers take the last bytes
    return r


def test_play_paces_goal_packets_and_the_laser(espe_stream):
    header, counts = read_counts(espe_stream)
    rate = header.rate
    bus, laser = Pty(), LaserBoard()
    try:
        r = run_play(espe_stream, bus, laser)
    finally:
        bus.close()
        laser.close()
    assert r.returncode == 0, r.stderr
    assert "played 3000 samples" in r.stdout, r.stdout
    packets = split_packets(bytes(bus.data), bus.times)
    assert all(checksum_ok(p) for _, p in packets)
    assert all(p[2] == 0xFE and p[4] == 0x83 for _, p in packets)  # SYNC_WRITE to the broadcast ID
    # the rest pose as goal, torque on for IDs 1, 2, 3, then the paced goals
    first, torque, paced = packets[0], packets[1], packets[2:]
    assert torque[1][5:7] == bytes([24, 1]) and list(torque[1][7:13]) == [1, 1, 2, 1, 3, 1]
    goals = np.array([[int.from_bytes(p[8 + 3 * s:10 + 3 * s], "little") for s in range(3)] for _, p in paced])
    assert all(p[5:7] == bytes([30, 2]) and list(p[7::3][:3]) == [1, 2, 3] for _, p in [first, *paced])
    assert np.array_equal(goals[0], counts[0, :3]) and np.array_equal(goals[-1], counts[-1, :3])
    assert decimation(BUSES[1], 3, 1_000_000, rate) == 1
    t = np.array([t for t, _ in paced]) - paced[0][0]
    duration = (len(counts) - 1) / rate
    assert abs(t[-1] - duration) <= 0.1 * duration, (t[-1], duration)
    # each packet's goals are the stream's counts at the time it arrived, within 1 count. The
    # reader stamps the packets of one read with one time: when it lagged (a process on a loaded
    # virtual machine, even at real-time priority, now and then stalls for 100 ms), a read holds
    # packets written since the read before, so each is held to the samples due from 3 ms before
    # that read to its own
    j = np.rint(t * rate).astype(int)
    reads = np.unique(t, return_inverse=True)[1]
    since = np.concatenate([[0], np.rint(np.unique(t) * rate).astype(int)[:-1]])[reads] - 3
    err = np.array([np.abs(goals[k] - counts[np.clip(np.arange(since[k], j[k] + 1), 0, len(counts) - 1), :3])
                    .max(axis=1).min() for k in range(len(goals))])
    bad = int(np.argmax(err))
    assert err.max() <= 1, (err.max(), bad, j[bad], since[bad], goals[bad])
    exact = np.abs(goals - counts[np.clip(j, 0, len(counts) - 1), :3]).max(axis=1) <= 1
    # a 1 kHz stream: a packet per sample, less the wake-ups that came after the next sample was due
    # (on this 2-vCPU virtual machine shared with other jobs: all but 0-10 %; the machine itself
    # stalls every process for ~100 ms now and then); no longer hole
    assert len(paced) > 0.5 * len(counts) and np.diff(t).max() < 0.25, (len(paced), np.diff(t).max())
    print(f"\npackets {len(paced)} arrived first to last in {t[-1]:.4f} s for {duration:.3f} s, longest gap "
          f"{np.diff(t).max() * 1e3:.1f} ms (as this reader saw them), {exact.mean():.1%} within 1 count of the "
          f"sample due at arrival; {r.stdout.strip()}")
    # the laser: a query, then duties, then off and the end
    frames = laser.frames
    assert frames[0][1] == ord("Q") and frames[-1][1:] == (ord("E"), 0) and frames[-2][1:] == (ord("L"), 0)
    duty = laser_duty(counts, [(0, 6, 4.0), (1800, 6, 0.0), (2200, 6, 4.0)], 3)
    assert (duty > 0).any() and (duty[1800:2200] == 0).all() and (counts[1800:2200, 3] > 0).any()
    sets = [(tm, v) for tm, k, v in frames[1:-2] if k == ord("L")]
    start = paced[0][0]
    reads = sorted({tm for tm, _ in sets})
    for tm, v in sets[1:]:  # (the first is the off before torque goes on)
        # as the goals: the samples due from 3 ms before the read before this frame's, to its own
        before = reads[max(0, reads.index(tm) - 1)]
        lo, hi = (int(np.clip(round((x - start) * rate), 0, len(counts) - 1)) for x in (before, tm))
        assert v in duty[max(0, lo - 3):hi + 2], (tm - start, v)
    seen = {v for _, v in sets}
    assert seen == set(np.unique(duty))  # every power the stream holds (on, off) went out


def test_checksum_and_frames():
    # the e-Manual's example: torque on for ID 1 is FF FF 01 04 03 18 01 DE
    assert checksum_ok(bytes.fromhex("FFFF0104031801DE"))
    assert laser_frame(ord("L"), 200) == bytes([76, 200, ~(76 + 200) & 0xFF])
    # 57600 baud: a 17-byte packet takes 2.95 ms, so every third 1 kHz sample
    assert decimation(BUSES[1], 3, 57_600, 1000.0) == 3
    assert decimation(BUSES[1], 3, 1_000_000, 1000.0, min_interval=0.0045) == 5


def test_a_laser_board_error_stops_playback_with_the_laser_off(espe_stream):
    bus, laser = Pty(), LaserBoard(fail_after=20)
    try:
        r = run_play(espe_stream, bus, laser, "--release")
    finally:
        bus.close()
        laser.close()
    assert r.returncode == 1 and "the laser board stopped: bad frame" in r.stderr, r.stderr
    assert r.stderr.count("\n") == 1  # one line, no traceback
    assert [k for _, k, _ in laser.frames[-2:]] == [ord("L"), ord("E")] and laser.frames[-2][2] == 0
    packets = split_packets(bytes(bus.data), bus.times)
    assert packets[-1][1][5:7] == bytes([24, 1]) and list(packets[-1][1][7:13]) == [1, 0, 2, 0, 3, 0]  # torque off


def test_pause_resume_and_abort_from_the_keys(espe_stream):
    from deltaslice.play import play

    header, counts = read_counts(espe_stream)

    class Script:
        """p at 0.5 s, r at 1.0 s, q at 1.5 s of wall time."""

        def __init__(self):
            self.t0 = time.monotonic()
            self.plan = [(0.5, "p"), (1.0, "r"), (1.5, "q")]

        def poll(self):
            if self.plan and time.monotonic() - self.t0 >= self.plan[0][0]:
                return self.plan.pop(0)[1]
            return ""

    import serial
    from deltaslice.errors import PlayError
    from deltaslice.play import open_bus

    bus, laser = Pty(), LaserBoard()
    port = open_bus(bus.name, 1_000_000)
    lport = serial.Serial(laser.name, 115200, timeout=0.05)
    try:
        with pytest.raises(PlayError, match="aborted at sample .*: laser off, servos holding their goal"):
            play(counts, [], rate=header.rate, n_joints=3, bus_port=port, baud=1_000_000, ids=[1, 2, 3],
                 laser_port=lport, keys=Script())
        time.sleep(0.1)
    finally:
        port.closePort()
        lport.close()
        bus.close()
        laser.close()
    paced = split_packets(bytes(bus.data), bus.times)[2:]
    t = np.array([tm for tm, _ in paced])
    gaps = np.diff(t)
    assert 0.4 < gaps.max() < 0.6  # no goal while paused
    # the timeline stopped while paused: about 1 s of samples (one packet each) in 1.5 s, and
    # the goals resume where they stopped
    assert 800 < len(paced) < 1250, len(paced)
    g = np.array([[int.from_bytes(p[8 + 3 * s:10 + 3 * s], "little") for s in range(3)] for _, p in paced])
    assert np.abs(g[np.argmax(gaps) + 1] - g[np.argmax(gaps)]).max() <= 1
    hole = t[np.argmax(gaps)] + 0.05, t[np.argmax(gaps) + 1] - 0.05
    during = [v for tm, kind, v in laser.frames if kind == ord("L") and hole[0] < tm < hole[1]]
    assert during and set(during) == {0}  # the keep-alive holds the laser off while paused
    assert laser.frames[-1][1] == ord("E")


def crc16_dxl2(data: bytes) -> int:
    """Protocol 2.0's CRC (ROBOTIS e-Manual): CRC-16, polynomial 0x8005, initial 0, not reflected."""
    crc = 0
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def test_protocol_2_packets_for_x_series(espe_stream):
    """Protocol 2.0 (X series: torque enable at 64, 4-byte goal positions at 116): every packet a
    broadcast SYNC_WRITE whose CRC is right, the goals the stream's counts."""
    from deltaslice.play import play

    header, counts = read_counts(espe_stream)
    counts = counts[:200]
    written = []

    class Port:  # what dynamixel_sdk's packet layer uses of a PortHandler
        is_using = False

        def clearPort(self):
            pass

        def writePort(self, packet):
            written.append(bytes(packet))
            return len(packet)

        def getPortName(self):
            return "bus"

    play(counts, [], rate=header.rate, n_joints=3, bus_port=Port(), baud=1_000_000, ids=[1, 2, 3], protocol=2,
         realtime=False)
    for p in written:
        assert p[:4] == b"\xff\xff\xfd\x00" and p[4] == 0xFE and p[7] == 0x83
        assert int.from_bytes(p[5:7], "little") == len(p) - 7
        assert int.from_bytes(p[-2:], "little") == crc16_dxl2(p[:-2])
    assert written[1][8:10] == (64).to_bytes(2, "little") and written[1][12::2][:3] == bytes([1, 2, 3])
    goals = [[int.from_bytes(p[13 + 5 * s:17 + 5 * s], "little") for s in range(3)] for p in written[2:]]
    assert all(p[8:10] == (116).to_bytes(2, "little") for p in written[2:])
    assert goals[0] == list(counts[0, :3]) and goals[-1] == list(counts[-1, :3]) and len(goals) > 50


def test_ctrl_c_stops_with_the_laser_off(espe_stream):
    import signal

    bus, laser = Pty(), LaserBoard()
    cmd = [sys.executable, "-m", "deltaslice", "play", str(espe_stream), "--dynamixel", bus.name, "--laser", laser.name,
           "--quiet"]
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                                stdin=subprocess.DEVNULL)
        deadline = time.monotonic() + 30
        while len(bus.data) < 17 * 200 and time.monotonic() < deadline:  # playing
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        time.sleep(0.1)
    finally:
        bus.close()
        laser.close()
    assert proc.returncode == 130, err
    assert err.count("\n") == 1 and "interrupted (Ctrl-C) at sample" in err and "laser off, servos holding" in err, err
    assert [(k, v) for _, k, v in laser.frames[-2:]] == [(ord("L"), 0), (ord("E"), 0)]
    packets = split_packets(bytes(bus.data), bus.times)
    assert packets[-1][1][5] == 30  # the last packet a goal: torque stays on (held)


@pytest.mark.parametrize("args, message", [
    (["--dynamixel", "/dev/nonexistent-bus"], "/dev/nonexistent-bus: cannot open the Dynamixel bus"),
    (["--dynamixel", "BUS", "--ids", "1,2"], "3 joints in the stream, 2 servo IDs given"),
    (["--dynamixel", "BUS", "--protocol", "1", "--printer", "delta_etitc"], "stream compiled for printer"),
])
def test_play_errors_are_one_line(espe_stream, args, message):
    bus = Pty()
    try:
        r = subprocess.run([sys.executable, "-m", "deltaslice", "play", str(espe_stream), "--quiet",
                            *[bus.name if a == "BUS" else a for a in args]], capture_output=True, text=True, cwd=ROOT,
                           timeout=60, stdin=subprocess.DEVNULL)
    finally:
        bus.close()
    assert r.returncode == 1 and message in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert not bus.data  # nothing reached the bus


def test_a_damaged_stream_is_refused_before_the_ports_open(espe_stream, tmp_path):
    data = bytearray(espe_stream.read_bytes())
    data[len(data) // 2] ^= 0x40
    bad = tmp_path / "bad.dsl"
    bad.write_bytes(bytes(data))
    bus, laser = Pty(), LaserBoard()
    try:
        r = run_play(bad, bus, laser)
    finally:
        bus.close()
        laser.close()
    assert r.returncode == 1 and "CRC mismatch" in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert not bus.data and not laser.data  # nothing moved, the laser board never heard from it
