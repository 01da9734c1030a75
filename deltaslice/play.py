"""Play a stream from the PC in real time: joint counts to Dynamixel servos as SYNC_WRITE goal
positions (ROBOTIS's ``dynamixel_sdk``), the laser's power to a board on a second serial port.

The PC is the clock. Sample ``i`` is due ``i / rate`` seconds after the start; at each packet
time the player writes the goals of the sample due then (a late wake-up sends the sample due
now, never a backlog), so the servos follow the stream's timeline whatever the PC's jitter. A
packet goes out every ``decimation`` samples: as often as the bus carries it (a 1 Mbps AX bus
every 1 kHz sample, 57600 baud every third), and the last sample always.

Laser link (the Uno's ``examples/firmware/uno_laser_player.c``), 115200 baud, 3-byte frames
``KIND VALUE CHECK`` with ``CHECK = ~(KIND + VALUE) & 0xFF``:

    host -> board   ``L d``  laser duty d (0..255), sent when it changes and as a keep-alive
                    ``E 0``  end: laser off, the board answers ``OK <frames>``
                    ``Q 0``  query: the board answers ``LASER <timeout ms>``
    board -> host   ``LASER <ms>\\n``  at power-up and to a query: ready, and its host time-out
                    ``ERR <msg>\\n``   a bad frame or a silent host: laser off until reset

The board switches the laser off by itself when no frame arrives within its time-out, so the
laser cannot stay on if this process dies; the keep-alive goes at a quarter of it.

Stops: at the end, on an error, on abort (``q``, or Ctrl-C) the laser goes off first, then the
servos hold their last goal (torque stays on: a delta's arms would fall) or, with ``release``,
torque goes off. ``p`` pauses (laser off, goals held, the timeline stopped), ``r`` resumes.
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from . import interrupt
from .errors import PlayError
from .tolerances import COUNT_ROUNDOFF

LASER_BAUD = 115200
LASER_SET, LASER_END, LASER_QUERY = ord("L"), ord("E"), ord("Q")
LASER_READY_WAIT = 5.0  # s: an Uno resets when its port opens; its bootloader takes up to ~2 s
EVENT_LASER_MODE = 6
REALTIME_PRIORITY = 20  # SCHED_FIFO: above every ordinary process, below the kernel's interrupt threads (50)


@dataclass(frozen=True)
class Bus:
    """A Dynamixel protocol and the control table it addresses: protocol 1.0 is the AX/MX series
    (the ESPE's AX-12), 2.0 the X series."""

    protocol: int
    torque_address: int
    goal_address: int
    goal_bytes: int
    goal_max: int

    def packet_bytes(self, servos: int) -> int:
        """Bytes of one SYNC_WRITE of the goals (2.0: before byte stuffing, which goals rarely need)."""
        if self.protocol == 1:
            return 8 + servos * (1 + self.goal_bytes)
        return 14 + servos * (1 + self.goal_bytes)


BUSES = {1: Bus(1, 24, 30, 2, 1023), 2: Bus(2, 64, 116, 4, 4095)}


def bus_seconds(nbytes: int, baud: int) -> float:
    """Time on the wire of ``nbytes`` at ``baud`` (8N1: 10 bits a byte)."""
    return 10.0 * nbytes / baud


def decimation(bus: Bus, servos: int, baud: int, rate: float, min_interval: float = 0.0) -> int:
    """Samples per packet: the fewest whole sample periods a packet fits in (and ``min_interval``)."""
    period = 1.0 / rate
    need = max(bus_seconds(bus.packet_bytes(servos), baud), min_interval)
    return max(1, math.ceil(need / period - COUNT_ROUNDOFF))


def laser_frame(kind: int, value: int) -> bytes:
    return bytes([kind, value, ~(kind + value) & 0xFF])


def laser_duty(counts: np.ndarray, events, n_joints: int) -> np.ndarray:
    """The laser's PWM duty (0..255) at every sample: the tool channel's count while the laser
    mode is on (M3/M4), 0 while it is off (M5); on when the stream has no mode event."""
    power = np.clip(counts[:, n_joints], 0, 255)
    on = np.ones(len(counts), bool)
    for i, kind, value in events:
        if kind == EVENT_LASER_MODE:
            on[i:] = value != 0
    return np.where(on, power, 0).astype(np.int64)


@dataclass
class PlayResult:
    """samples: the last sample sent + 1; packets: SYNC_WRITEs sent; seconds: from the first
    packet to the last, pauses included; late: each packet's write, done, after the time it was
    meant for (s): the PC's jitter; skipped: packets not sent because the player woke after the
    next one was due (the sample due then went instead); stopped: "end", "abort" or "interrupt"."""

    samples: int
    total: int
    packets: int
    decimation: int
    seconds: float
    late: np.ndarray = field(repr=False)
    laser_frames: int = 0
    stopped: str = "end"
    skipped: int = 0
    realtime: bool = False

    def timing(self) -> str:
        if not len(self.late):
            return "no packets"
        ms = self.late * 1e3
        return (f"packets written after their time: median {np.median(ms):.3f} ms, 99th percentile "
                f"{np.percentile(ms, 99):.3f} ms, max {ms.max():.3f} ms; {self.skipped} skipped (woke after the "
                "next was due); "
                f"{'real-time priority' if self.realtime else 'ordinary priority (no permission for real-time)'}")


class Keys:
    """Single key presses from the terminal, without Enter (no terminal: none)."""

    def __init__(self, stream=None):
        self.stream = stream if stream is not None else sys.stdin
        self.saved = None

    def __enter__(self):
        try:
            import termios
            import tty

            if self.stream.isatty():
                fd = self.stream.fileno()
                self.saved = termios.tcgetattr(fd)
                tty.setcbreak(fd)
        except (ImportError, OSError, ValueError, AttributeError):
            self.saved = None
        return self

    def __exit__(self, *exc):
        if self.saved is not None:
            import termios

            termios.tcsetattr(self.stream.fileno(), termios.TCSADRAIN, self.saved)
        return False

    def poll(self) -> str:
        if self.saved is None:
            return ""
        fd, out = self.stream.fileno(), ""
        while select.select([fd], [], [], 0)[0]:
            c = os.read(fd, 1)
            if not c:
                break
            out += c.decode("ascii", "replace")
        return out


class _Laser:
    """The laser board's side of the link: the handshake, duty changes, keep-alives, its errors."""

    def __init__(self, port, name: str, clock):
        self.port, self.name, self.clock = port, name, clock
        self.duty, self.last, self.frames, self.line = -1, 0.0, 0, bytearray()
        self.keepalive = 0.05

    def handshake(self, wait: float = LASER_READY_WAIT) -> None:
        end = self.clock() + wait
        asked = -1.0
        while self.clock() < end:
            if self.clock() - asked >= 0.25:
                self.port.write(laser_frame(LASER_QUERY, 0))
                asked = self.clock()
            for text in self.lines(0.05):
                if text.startswith("LASER"):
                    try:
                        self.keepalive = int(text.split()[1]) / 4000.0
                    except (IndexError, ValueError):
                        raise PlayError(f"{self.name}: the laser board answered {text!r}") from None
                    return
        raise PlayError(f"{self.name}: no answer from the laser board in {wait:g} s "
                        "(is it running uno_laser_player at 115200 baud?)")

    def lines(self, timeout: float = 0.0) -> list[str]:
        """Complete lines received; ``ERR`` lines raise."""
        out = []
        waiting = self.port.in_waiting
        data = self.port.read(waiting) if waiting else (self.port.read(1) if timeout else b"")
        for b in data:
            if b == 10:
                text = self.line.decode("ascii", "replace").strip()
                self.line.clear()
                if text.startswith("ERR"):
                    raise PlayError(f"{self.name}: the laser board stopped: {text[3:].strip()}")
                out.append(text)
            elif len(self.line) < 200:
                self.line.append(b)
        return out

    def set(self, duty: int) -> None:
        now = self.clock()
        if duty != self.duty or now - self.last >= self.keepalive:
            self.port.write(laser_frame(LASER_SET, int(duty)))
            self.duty, self.last = duty, now
            self.frames += 1

    def off(self) -> None:
        """Laser off and the job ended; never raises (it runs on the way out of an error)."""
        try:
            self.port.write(laser_frame(LASER_SET, 0) + laser_frame(LASER_END, 0))
            self.port.flush()
            self.frames += 2
        except Exception:  # noqa: BLE001 - the board's own time-out switches it off then
            pass


class _Servos:
    """SYNC_WRITEs on a Dynamixel bus through ROBOTIS's SDK (broadcast: no status packet comes
    back, so nothing answers on the half-duplex bus while the next packet goes out)."""

    def __init__(self, port, bus: Bus, ids):
        from dynamixel_sdk import COMM_SUCCESS, GroupSyncWrite, PacketHandler

        self.ok = COMM_SUCCESS
        self.port, self.bus, self.ids = port, bus, list(ids)
        self.handler = PacketHandler(float(bus.protocol))
        self.goals = GroupSyncWrite(port, self.handler, bus.goal_address, bus.goal_bytes)
        for i in self.ids:
            self.goals.addParam(i, [0] * bus.goal_bytes)

    def _send(self, group, what: str) -> None:
        result = group.txPacket()
        if result != self.ok:
            raise PlayError(f"{self.port.getPortName()}: {what}: {self.handler.getTxRxResult(result)}")

    def torque(self, on: bool) -> None:
        from dynamixel_sdk import GroupSyncWrite

        group = GroupSyncWrite(self.port, self.handler, self.bus.torque_address, 1)
        for i in self.ids:
            group.addParam(i, [1 if on else 0])
        self._send(group, "torque " + ("on" if on else "off"))

    def goal(self, counts) -> None:
        for i, c in zip(self.ids, counts):
            self.goals.changeParam(i, list(int(c).to_bytes(self.bus.goal_bytes, "little")))
        self._send(self.goals, "goal positions")


def play(counts: np.ndarray, events, *, rate: float, n_joints: int, bus_port, baud: int, ids, protocol: int = 1,
         laser_port=None, laser_name: str = "laser", release: bool = False, min_interval: float = 0.0, keys=None,
         clock=time.monotonic, sleep=time.sleep, progress=None, realtime: bool = True,
         name: str = "stream") -> PlayResult:
    """Play ``counts`` (n, C) in real time on an open ``dynamixel_sdk.PortHandler`` and, if
    given, an open serial port to the laser board (``write``, ``read``, ``in_waiting``).

    keys: an object whose ``poll()`` returns the keys pressed since ("p" pause, "r" resume, "q"
    abort), or None. progress: ``progress(sample, total)`` now and then. realtime: play at
    SCHED_FIFO where allowed (:func:`_realtime`). Raises
    :class:`PlayError` after the clean stop on an error or an abort (``.interrupted`` on Ctrl-C)."""
    bus = BUSES[protocol]
    ids = list(ids)
    joints = _checked_joints(counts, n_joints, ids, bus, protocol, name)
    duty = laser_duty(counts, events, n_joints) if laser_port is not None else None
    k = decimation(bus, len(ids), baud, rate, min_interval)
    n, period = len(counts), 1.0 / rate
    servos = _Servos(bus_port, bus, ids)
    laser = _Laser(laser_port, laser_name, clock) if laser_port is not None else None
    sent_at, late, skipped = [], [], 0
    i = -1
    stopped, paused_at = "end", None
    with _realtime(realtime) as got_rt:  # the stop below too: the laser goes off promptly
        try:
            if laser is not None:
                laser.handshake()
                laser.set(0)
            servos.goal(joints[0])  # the rest pose before torque: enabling it then does not jump
            servos.torque(True)
            t0 = clock()
            nxt = 0
            while True:
                pressed = keys.poll() if keys is not None else ""
                if "q" in pressed:
                    stopped = "abort"
                    break
                if paused_at is None and "p" in pressed:
                    paused_at = clock()
                    if laser is not None:
                        laser.set(0)
                elif paused_at is not None and "r" in pressed:
                    t0 += clock() - paused_at
                    paused_at = None
                if laser is not None:
                    laser.lines()
                if paused_at is not None:
                    if laser is not None:
                        laser.set(0)
                    sleep(0.02)
                    continue
                now = clock()
                due = t0 + nxt * period
                if now < due:
                    # short naps: the keys and the laser's keep-alive are served while waiting
                    if laser is not None:
                        laser.set(max(laser.duty, 0))
                    sleep(min(due - now, 0.02))
                    continue
                i = min(n - 1, max(nxt, int((now - t0) / period) // k * k))  # late: the sample due now
                if laser is not None:
                    laser.set(int(duty[i]))
                servos.goal(joints[i])
                done = clock()
                sent_at.append(done)
                late.append(done - due)
                skipped += (i - nxt) // k
                if progress is not None and (i // k) % 256 == 0:
                    progress(i, n)
                if i == n - 1:
                    break
                nxt = min(n - 1, (i // k + 1) * k)
        except KeyboardInterrupt:
            stopped = "interrupt"
        except PlayError:
            _stop(laser, servos, release)
            raise
        except Exception as exc:  # the serial layer's own errors (a pulled adapter), as one line
            _stop(laser, servos, release)
            raise PlayError(f"{name}: stopped at sample {max(i, 0)} of {n}: {exc}") from None
        _stop(laser, servos, release)
    if progress is not None:
        progress(max(i, 0), n)
    seconds = sent_at[-1] - sent_at[0] if len(sent_at) > 1 else 0.0
    result = PlayResult(max(i, 0) + 1, n, len(sent_at), k, seconds, np.array(late),
                        laser.frames if laser else 0, stopped, skipped, got_rt)
    if stopped != "end":
        hold = "torque off" if release else "servos holding their goal"
        how = "interrupted (Ctrl-C)" if stopped == "interrupt" else "aborted"
        err = PlayError(f"{name}: {how} at sample {result.samples} of {n} ({result.samples / rate:.2f} s): "
                        f"laser off, {hold}")
        err.interrupted = stopped == "interrupt"
        raise err
    return result


def _checked_joints(counts: np.ndarray, n_joints: int, ids: list, bus, protocol: int, name: str) -> np.ndarray:
    """(n, n_joints) the joints' goal counts, or PlayError: an ID per joint, samples, every count in
    the servos' goal range."""
    if len(ids) != n_joints:
        raise PlayError(f"{name}: {n_joints} joints in the stream, {len(ids)} servo IDs given")
    joints = counts[:, :n_joints]
    if len(joints) == 0:
        raise PlayError(f"{name}: the stream has no samples")
    lo, hi = int(joints.min()), int(joints.max())
    if lo < 0 or hi > bus.goal_max:
        raise PlayError(f"{name}: joint counts {lo}..{hi} leave the servos' goal range 0..{bus.goal_max} "
                        f"(protocol {protocol}): compiled for another servo?")
    return joints


@contextlib.contextmanager
def _realtime(wanted: bool):
    """The calling thread at SCHED_FIFO while it plays, where the system allows it (root, or an
    rtprio limit): measured here, on 2 cores shared with other jobs, it takes the packets written
    more than a sample period late from a quarter of them to none. Yields whether it got it."""
    if not wanted or not hasattr(os, "sched_setscheduler"):
        yield False
        return
    try:
        before = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
    except OSError:
        yield False
        return
    try:
        yield True
    finally:
        os.sched_setscheduler(0, before[0], before[1])


def _stop(laser, servos, release: bool) -> None:
    """The clean stop, whatever happened: laser off first, then torque off if asked; a second
    Ctrl-C waits until it is done."""
    with interrupt.held():
        if laser is not None:
            laser.off()
        if release:
            servos.port.is_using = False  # a Ctrl-C inside the SDK's write leaves its port marked busy
            try:
                servos.torque(False)
            except Exception:  # noqa: BLE001 - a dead bus: nothing more can be said to it
                pass


def open_bus(port_name: str, baud: int):
    """An open ``dynamixel_sdk.PortHandler`` at ``baud``."""
    try:
        from dynamixel_sdk import PortHandler
    except ImportError:
        raise PlayError("deltaslice play needs ROBOTIS's dynamixel-sdk (pip install dynamixel-sdk)") from None
    port = PortHandler(str(port_name))
    try:
        ok = port.setBaudRate(int(baud))
    except Exception as exc:  # noqa: BLE001 - pyserial's SerialException, OSError, ValueError
        raise PlayError(f"{port_name}: cannot open the Dynamixel bus: {exc}") from None
    if not ok:
        raise PlayError(f"{port_name}: baud rate {baud} is not one the Dynamixel SDK sets "
                        "(1000000, 57600, 115200, ...)")
    return port


def open_laser(port_name: str):
    import serial

    try:
        return serial.Serial(str(port_name), baudrate=LASER_BAUD, timeout=0.05, write_timeout=1.0)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise PlayError(f"{port_name}: cannot open the laser board's port: {exc}") from None
