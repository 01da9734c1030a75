"""Send a stream to a board that plays it (the players in ``examples/firmware``) over a serial
link, with their credit flow control:

    board -> host   ``>``           one credit: room for one more chunk
    host  -> board  n, n bytes      one chunk per credit: its length n (1..CHUNK; the last one
                                    may be shorter), then n bytes of the stream
                    ``p`` ``r`` ``x``  between chunks: feed hold (pause: the board ramps its
                                    clock to a stop; repeated every second while paused, the
                                    host's sign of life), resume, abort (everything off at once)
    board -> host   ``OK <n>\\n``    the stream ended intact after n samples
                    ``ERR <msg>\\n`` the board refused or stopped
                    ``# <text>\\n``  information (the Mega player's ``# heating`` once a second
                                    while a heater wait holds the stream): ignored, but as any
                                    byte from the board it restarts the timeout, for at most
                                    ``wait_limit`` seconds of one wait

The host never sends more than it has credit for, so a board with a 2 KB RAM can play a print of
any length. :func:`send_stream` takes an open serial-like object (``read(n)`` returning ``b""``
when its timeout passes, ``write(data)``); ``pipeline.send_file`` opens the port.
:func:`keyboard_commands` reads pause/resume/abort from the terminal.
"""

from __future__ import annotations

import queue
import sys
import threading
import time
from dataclasses import dataclass

from .errors import SendError

CHUNK = 64
CREDIT = b">"
CONTROL = {"pause": b"p", "resume": b"r", "abort": b"x"}
PAUSE_REPEAT = 1.0  # s between the repeated feed-hold bytes (the board's host_timeout is >= 1 s)
WAIT_LIMIT = 960.0  # s: the players' default heating-wait limit ([safety] wait_timeout, 900 s) and a minute


@dataclass(frozen=True)
class SendResult:
    """bytes_sent: the whole stream; samples: what the board reports having played; seconds: wall time."""

    bytes_sent: int
    samples: int
    seconds: float


def keyboard_commands(stream=None, echo=None):
    """A ``commands()`` for :func:`send_stream` fed by a thread reading lines from ``stream``
    (stdin): ``p`` pause, ``r`` resume, ``x`` or ``q`` abort. echo: called with what was understood."""
    stream = sys.stdin if stream is None else stream
    lines = queue.Queue()
    names = {"p": "pause", "r": "resume", "x": "abort", "q": "abort"}

    def read():
        for line in stream:
            key = line.strip().lower()[:1]
            if key in names:
                lines.put(names[key])
                if echo:
                    echo(names[key])

    threading.Thread(target=read, daemon=True).start()

    def commands():
        try:
            return lines.get_nowait()
        except queue.Empty:
            return None

    return commands


def send_stream(data: bytes, port, *, timeout: float = 10.0, progress=None, name: str = "stream",
                wait_limit: float = WAIT_LIMIT, commands=None) -> SendResult:
    """Send ``data`` (a whole, checked stream) to ``port`` and wait for the board's verdict.

    timeout: seconds without a byte from the board before giving up (any byte counts: a board
    waiting for its heaters sends a ``#`` line now and then; one that does not needs a longer timeout). progress: ``progress(done, total)`` in bytes.
    wait_limit: seconds of ``# heating`` lines in a row (no credit between them) after which the
    board is taken for stuck in its heating wait: the keep-alive cannot hold the sender longer.
    commands: a callable polled a few times a second, returning ``"pause"``, ``"resume"``,
    ``"abort"`` or None (:func:`keyboard_commands`); Ctrl-C aborts too.
    Raises :class:`SendError` on a timeout, a closed port, a wait over ``wait_limit``, an abort or
    an ``ERR`` line (its message ends with the board's line)."""
    t0 = time.monotonic()
    sent, line, last = 0, bytearray(), time.monotonic()
    heating_since = paused = aborted = None
    while True:
        try:
            command = commands() if commands and not aborted else None
            if command in CONTROL:
                port.write(CONTROL[command])  # whole chunks are written at once: this is between two
                paused = time.monotonic() if command == "pause" else None
                aborted = command == "abort" or None
            elif paused is not None and time.monotonic() - paused >= PAUSE_REPEAT:
                port.write(CONTROL["pause"])
                paused = time.monotonic()
            b = port.read(1)
        except KeyboardInterrupt:
            port.write(CONTROL["abort"])
            raise SendError(f"{name}: aborted from the keyboard after {sent} of {len(data)} bytes: the board "
                            "switches its heaters and motors off") from None
        if not b:
            if paused is not None:
                last = time.monotonic()  # a board in a feed hold asks for nothing: not a dead one
            elif time.monotonic() - last >= timeout:
                raise SendError(f"{name}: no answer from the board for {timeout:g} s after {sent} of {len(data)} bytes"
                                " (is it running a deltaslice player at this baud rate?)")
            continue
        last = time.monotonic()
        if b == CREDIT and not line:
            heating_since = None
            if sent < len(data):
                chunk = data[sent:sent + CHUNK]
                port.write(bytes([len(chunk)]) + chunk)
                sent += len(chunk)
                if progress:
                    progress(sent, len(data))
            continue
        if b != b"\n":
            line += b
            continue
        text = line.decode("ascii", "replace").strip()
        line.clear()
        if text.startswith("OK"):
            try:
                samples = int(text.split()[1])
            except (IndexError, ValueError):
                raise SendError(f"{name}: the board answered {text!r}") from None
            return SendResult(sent, samples, time.monotonic() - t0)
        if text.startswith("ERR"):
            raise SendError(f"{name}: the board stopped after {sent} of {len(data)} bytes: {text[3:].strip()}")
        if text.startswith("# heating"):
            heating_since = heating_since if heating_since is not None else last
            if last - heating_since > wait_limit:
                raise SendError(f"{name}: the board has been heating for over {wait_limit:g} s after {sent} of "
                                f"{len(data)} bytes (its keep-alive does not extend the wait): check its heaters "
                                "and thermistors")
        # anything else (a boot banner) is not part of the protocol: ignored
