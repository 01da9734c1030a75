"""deltaslice send: a checked stream to a board with the credit flow control of the firmware
players, against a fake board on a pseudo-terminal (the same serial stack as a real port)."""

from __future__ import annotations

import os
import threading
import time
import tty

import pytest
from click.testing import CliRunner
from trajectories import blocks, printer, realistic

from deltaslice.cli import main
from deltaslice.errors import SendError, StreamError
from deltaslice.pipeline import send_file, write_samples
from deltaslice.send import CHUNK

RING = 128  # avr_serial.h's SERIAL_RING: it holds 127 bytes

serial = pytest.importorskip("serial")


class FakeBoard(threading.Thread):
    """A board with avr_serial.h's 128-byte receive ring (127 bytes usable) that drains slowly,
    granting credits as avr_serial.h does;
    ``mode``: "ok" (answers OK <samples> after the last byte), "err" (ERR after err_after bytes),
    "silent" (never answers). ``hold``: (after_bytes, seconds, keepalive) stops taking bytes and
    granting credits once after_bytes have arrived, for seconds, as the Mega player does during a
    heater wait, sending its "# heating" line every keepalive seconds (None: silent)."""

    def __init__(self, expected: int, mode="ok", err_after=0, samples=1234, hold=None):
        super().__init__(daemon=True)
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self.slave = slave
        self.expected, self.mode, self.err_after, self.samples = expected, mode, err_after, samples
        self.received = bytearray()
        self.max_outstanding = 0
        self.max_buffered = 0
        self.stop = False
        self.hold = hold
        self.keepalives = 0
        self.chunk_left = 0
        self.chunks, self.controls = [], []

    def unframe(self, raw: bytes) -> bytes:
        """The stream bytes of what arrived, as avr_serial.h's RX interrupt takes them: a length
        byte opens each chunk; between chunks ``p``/``r``/``x`` are controls (kept in ``controls``)."""
        out = bytearray()
        for b in raw:
            if self.chunk_left:
                out.append(b)
                self.chunk_left -= 1
            elif 1 <= b <= CHUNK:
                self.chunk_left = b
                self.chunks.append(b)
            else:
                self.controls.append(chr(b))
        return bytes(out)

    def run(self):
        # like an Arduino reset by the port opening (DTR): silent while it boots, so the host has
        # opened the port (which flushes its input) before the first credit
        time.sleep(0.5)
        os.set_blocking(self.master, False)
        granted, buffered = 0, 0  # bytes credited; bytes received and not yet taken
        while not self.stop:
            if self.mode == "silent":
                time.sleep(0.01)
                continue
            if self.hold and len(self.received) >= self.hold[0]:
                _, seconds, keepalive = self.hold
                self.hold = None
                end = time.monotonic() + seconds
                while time.monotonic() < end:
                    if keepalive:
                        time.sleep(min(keepalive, max(0.0, end - time.monotonic())))
                        os.write(self.master, b"# heating\n")
                        self.keepalives += 1
                    else:
                        time.sleep(0.01)
            # as avr_serial.h: a credit while a chunk fits in the 127 bytes of the ring that are
            # neither received nor credited and on their way
            while buffered + (granted - len(self.received)) + CHUNK <= RING - 1:
                os.write(self.master, b">")
                granted += CHUNK
            self.max_outstanding = max(self.max_outstanding, -(-(granted - len(self.received)) // CHUNK))
            try:
                data = self.unframe(os.read(self.master, 256))
            except BlockingIOError:
                data = b""
            if data:
                self.received += data
                buffered += len(data)
                self.max_buffered = max(self.max_buffered, buffered)  # over RING - 1: bytes lost
            buffered = max(0, buffered - 32)  # the player takes bytes as it plays
            if "x" in self.controls:
                os.write(self.master, b"ERR aborted by the host: heaters off, motors off\n")
                return
            if self.mode == "err" and len(self.received) >= self.err_after:
                os.write(self.master, b"ERR block 3 at byte offset 999: CRC mismatch: block is corrupt\n")
                return
            if self.mode == "ok" and len(self.received) >= self.expected:
                os.write(self.master, f"OK {self.samples}\n".encode())
                return
            time.sleep(0.001)


@pytest.fixture(scope="module")
def stream(tmp_path_factory):
    p = printer("delta_etitc")
    s, _ = realistic("delta_etitc", layers=1)
    path = tmp_path_factory.mktemp("send") / "part.dsl"
    write_samples(blocks(s, 2500), p, path, fmt="stream", rate=p.planning.output_rate)
    return path


def test_every_byte_arrives_in_credited_chunks(stream):
    data = stream.read_bytes()
    board = FakeBoard(len(data))
    board.start()
    result = send_file(stream, board.path, timeout=5)
    board.join(5)
    assert bytes(board.received) == data
    assert result.bytes_sent == len(data) and result.samples == 1234
    assert board.max_outstanding <= 2  # never more than the board granted
    assert 0 < board.max_buffered <= RING - 1  # the ring never overflowed
    assert set(board.chunks[:-1]) == {CHUNK} and board.chunks[-1] == len(data) - CHUNK * (len(board.chunks) - 1)
    assert not board.controls


def test_cli_reports_and_exits_zero(stream):
    data = stream.read_bytes()
    board = FakeBoard(len(data))
    board.start()
    r = CliRunner().invoke(main, ["send", str(stream), "--port", board.path, "--quiet"])
    board.join(5)
    assert r.exit_code == 0, r.output
    assert f"sent {len(data)} bytes; the board played 1234 samples" in r.output


def test_board_error_is_reported(stream):
    board = FakeBoard(10**9, mode="err", err_after=600)
    board.start()
    with pytest.raises(SendError, match=r"the board stopped after \d+ of \d+ bytes: block 3 at byte offset 999"):
        send_file(stream, board.path, timeout=5)
    r = CliRunner().invoke(main, ["send", str(stream), "--port", FakeBoard(1, mode="silent").path, "--timeout", "0.5",
                                  "--quiet"])
    assert r.exit_code == 1 and "no answer from the board for 0.5 s after 0 of" in r.output


def test_corrupt_stream_refused_before_the_port_is_opened(stream, tmp_path):
    data = bytearray(stream.read_bytes())
    data[len(data) // 2] ^= 0xFF
    bad = tmp_path / "bad.dsl"
    bad.write_bytes(bytes(data))
    with pytest.raises(StreamError, match="block"):
        send_file(bad, "/dev/does-not-exist")  # the port would fail: the stream is checked first


def test_wrong_printer_and_missing_port(stream):
    with pytest.raises(StreamError, match="fingerprint|printer"):
        send_file(stream, "/dev/does-not-exist", printer="linear_kossel")
    with pytest.raises(SendError, match="cannot open the serial port"):
        send_file(stream, "/dev/does-not-exist")


def test_heater_wait_keepalive_keeps_the_sender_waiting(stream):
    # the Mega player holds the stream during a heater wait (tens of seconds on a machine) and
    # says "# heating" once a second: send ignores the line but takes it as a sign of life
    data = stream.read_bytes()
    board = FakeBoard(len(data), hold=(600, 2.5, 0.5))
    board.start()
    result = send_file(stream, board.path, timeout=1.0)
    board.join(5)
    assert bytes(board.received) == data and result.samples == 1234
    assert board.keepalives >= 4
    # the same wait without the keep-alive is taken for a dead board
    board = FakeBoard(len(data), hold=(600, 2.5, None))
    board.start()
    with pytest.raises(SendError, match=r"no answer from the board for 1 s after \d+ of"):
        send_file(stream, board.path, timeout=1.0)
    board.stop = True


def test_heating_keepalive_cannot_hold_the_sender_past_the_wait_limit(stream):
    # a board stuck in its heating wait (an old player without its own limit) says "# heating"
    # for ever: the sender gives up after wait_limit, though every line restarts its timeout
    data = stream.read_bytes()
    board = FakeBoard(len(data), hold=(600, 4.0, 0.2))
    board.start()
    t0 = time.monotonic()
    with pytest.raises(SendError, match=r"heating for over 1\.5 s after \d+ of \d+ bytes \(its keep-alive does not"):
        send_file(stream, board.path, timeout=1.0, wait_limit=1.5)
    assert time.monotonic() - t0 < 3.5
    board.stop = True


def test_board_fault_line_ends_the_send_with_a_non_zero_exit(stream):
    class FaultBoard(FakeBoard):
        def run(self):
            time.sleep(0.5)
            os.write(self.master, b">ERR hot end: thermistor open (ADC 1023)\n")

    board = FaultBoard(1)
    board.start()
    r = CliRunner().invoke(main, ["send", str(stream), "--port", board.path, "--quiet"])
    assert r.exit_code == 1
    assert r.output.rstrip().endswith("the board stopped after 64 of "
                                      f"{len(stream.read_bytes())} bytes: hot end: thermistor open (ADC 1023)"), r.output


def test_pause_resume_and_abort_go_between_chunks(stream):
    # the keyboard's commands: a feed hold repeated every second while it lasts (the host's sign of
    # life), a resume, an abort; each between two chunks (the board's RX interrupt would take a
    # control inside a chunk for data), answered by the board's ERR line
    data = stream.read_bytes()
    board = FakeBoard(len(data), hold=(600, 5.0, 0.5))  # busy for 5 s: the commands wait on the wire
    board.start()
    t0 = time.monotonic()
    plan = [(1.0, "pause"), (3.5, "resume"), (4.0, "abort")]

    def commands():
        if plan and time.monotonic() - t0 >= plan[0][0]:
            return plan.pop(0)[1]
        return None

    import serial as pyserial

    from deltaslice.send import send_stream

    with pytest.raises(SendError, match=r"the board stopped after \d+ of \d+ bytes: aborted by the host"):
        with pyserial.Serial(board.path, 115200, timeout=0.2) as port:
            send_stream(data, port, timeout=3.0, commands=commands)
    board.stop = True
    assert board.controls[0] == "p" and board.controls.count("p") >= 2, board.controls  # repeated while paused
    assert board.controls[-2:] == ["r", "x"], board.controls
    assert bytes(board.received) == data[:len(board.received)]  # the stream bytes intact around them


def test_keyboard_commands_read_lines():
    import io

    from deltaslice.send import keyboard_commands

    heard = []
    commands = keyboard_commands(io.StringIO("p\nresume\nhello\nq\n"), echo=heard.append)
    time.sleep(0.2)
    assert [commands() for _ in range(4)] == ["pause", "resume", "abort", None]
    assert heard == ["pause", "resume", "abort"]
