"""The UADY's PID player on a Cortex-M0 (examples/firmware/m0_pid_player.c), built with
arm-none-eabi-gcc for the micro:bit QEMU emulates (`qemu-system-arm -M microbit`, an nRF51) and
sent a stream by `deltaslice send` over the emulated UART (QEMU's serial port on a TCP socket):
its setpoints are `deltaslice decode`'s counts relative to the first sample, its encoders (the
simulated motors of dc_motor_model.h) follow them within the bound the host build states, and
its whole log is the host build's (dc_pid_player.c) line for line.

They need gcc-arm-none-eabi, libnewlib-arm-none-eabi and qemu-system-arm (Debian); they skip
without them, except under CI (env CI set), where .ci/run installs them.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from trajectories import ROOT, blocks, printer, realistic

from deltaslice.pipeline import write_samples

FIRMWARE = ROOT / "examples" / "firmware"
PID_FOLLOWING_BOUND = 2  # counts, as tests/test_firmware_host_players.py states for the host build
SAMPLES = 4000


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    missing = [t for t in ("arm-none-eabi-gcc", "qemu-system-arm", "make", "cc") if not shutil.which(t)]
    if missing:
        if os.environ.get("CI"):
            pytest.fail(f"{', '.join(missing)} missing under CI: .ci/run installs the Debian packages")
        pytest.skip(f"{', '.join(missing)} not installed (apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi "
                    "qemu-system-arm)")
    out = tmp_path_factory.mktemp("m0")
    r = subprocess.run(["make", "-C", str(FIRMWARE), f"BUILD={out}", "m0", f"{out}/dc_pid_player"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    return out


@pytest.fixture(scope="module")
def uady_stream(tmp_path_factory):
    """Four seconds of a UADY print: the joints moving both ways."""
    p = printer("delta_uady")
    s, _ = realistic("delta_uady", layers=1)
    s = s.__class__(s.t[:SAMPLES], s.q[:SAMPLES], s.e[:SAMPLES], s.tool[:SAMPLES])
    path = tmp_path_factory.mktemp("uady") / "uady.dsl"
    write_samples(blocks(s, 1500), p, path, fmt="stream", rate=p.planning.output_rate, events=[(100, 5, 255.0)])
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def send_late(stream, port):
    """A host that opens the link a second after the board started and throws away what came
    (the board's first credit), as one does that opens a Bluetooth link to a running board."""
    import serial

    from deltaslice.send import send_stream

    link = serial.serial_for_url(f"socket://127.0.0.1:{port}", timeout=0.2)
    try:
        time.sleep(1.0)
        link.reset_input_buffer()
        return send_stream(stream.read_bytes(), link, timeout=10)
    finally:
        link.close()


def run_m0(build, stream, tmp_path, timeout=240, late=False):
    """QEMU with the player, its UART a TCP server; `deltaslice send` to it; QEMU ended once send
    has its verdict (the player halts, as a board does). Returns (send's result, the log lines)."""
    port, log = free_port(), tmp_path / "m0.log"
    qemu = subprocess.Popen(
        ["qemu-system-arm", "-M", "microbit", "-kernel", str(build / "m0_pid_player.elf"), "-display", "none",
         "-monitor", "none", "-chardev", f"file,id=log,path={log}",
         "-semihosting-config", "enable=on,target=native,chardev=log",
         "-serial", f"tcp:127.0.0.1:{port},server=on,wait=on"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # QEMU says it listens, then waits for the one connection before it starts the machine
        said = qemu.stderr.readline()
        assert "waiting for connection" in said, said + qemu.stderr.read()
        if late:
            sent = send_late(stream, port)
        else:
            sent = subprocess.run([sys.executable, "-m", "deltaslice", "send", str(stream), "--port",
                                   f"socket://127.0.0.1:{port}", "--quiet", "--timeout", "30"],
                                  capture_output=True, text=True, timeout=timeout, cwd=ROOT, stdin=subprocess.DEVNULL)
        deadline = time.monotonic() + 30  # the player logs that it halted just after its verdict
        while "# halted" not in log.read_text() and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        qemu.kill()
        qemu.wait()
    return sent, log.read_text().splitlines()


def test_m0_pid_player_follows_the_stream_sent_to_it(build, uady_stream, tmp_path):
    sent, log = run_m0(build, uady_stream, tmp_path)
    assert sent.returncode == 0, sent.stderr
    assert f"the board played {SAMPLES} samples" in sent.stdout, sent.stdout
    assert log[-1] == "# halted: done"
    decoded = subprocess.run([sys.executable, "-m", "deltaslice", "decode", str(uady_stream)], capture_output=True,
                             text=True, check=True, cwd=ROOT).stdout
    counts = np.loadtxt([ln for ln in decoded.splitlines() if not ln.startswith("#")], dtype=np.int64)[:, 1:]
    samples = [ln for ln in log if not ln.startswith("#")]
    assert "# held 0 periods (late bytes)" in log  # QEMU's time is the samples': no tick without one
    out = np.loadtxt(samples, dtype=np.int64)
    assert len(out) == len(counts) == SAMPLES and np.array_equal(out[:, 0], np.arange(SAMPLES))
    for j in range(3):
        sp, pos = out[:, 1 + 3 * j], out[:, 2 + 3 * j]
        assert np.array_equal(sp, counts[:, j] - counts[0, j])  # the setpoints are decode's counts
        assert np.abs(sp - pos).max() <= PID_FOLLOWING_BOUND, (j, np.abs(sp - pos).max())
        assert (np.diff(sp) > 0).any() and (np.diff(sp) < 0).any()  # both ways
    # the same integer PID and motor model as the host build: the same numbers, line for line
    host = subprocess.run([str(build / "dc_pid_player"), str(uady_stream)], capture_output=True, text=True,
                          check=True).stdout.splitlines()
    assert host == samples


def test_m0_refuses_a_stream_for_another_printer(build, tmp_path):
    p = printer("delta_etitc")
    s, _ = realistic("delta_etitc", layers=1)
    path = tmp_path / "etitc.dsl"
    write_samples(blocks(s.__class__(s.t[:300], s.q[:300], s.e[:300], s.tool[:300]), 300), p, path, fmt="stream",
                  rate=p.planning.output_rate)
    sent, log = run_m0(build, path, tmp_path)
    assert sent.returncode == 1 and "stream made for another printer" in sent.stderr, sent.stderr
    assert log[-1] == "# halted: failed" and not [ln for ln in log if not ln.startswith("#")]  # no sample played


def test_make_builds_the_m0_and_laser_players_by_default(tmp_path):
    # `make -C examples/firmware` (its first target, all): a dry run lists both builds
    if not shutil.which("make"):
        (pytest.fail if os.environ.get("CI") else pytest.skip)("no make")
    r = subprocess.run(["make", "-n", "-C", str(FIRMWARE), f"BUILD={tmp_path}"], capture_output=True, text=True,
                       check=True)
    assert f"-o {tmp_path}/m0_pid_player.elf" in r.stdout and f"-o {tmp_path}/uno_laser_player.elf" in r.stdout
    assert f"{tmp_path}/uno_laser_player.hex" in r.stdout


def test_m0_credits_again_until_the_host_listens(build, uady_stream, tmp_path):
    # the board does not reset when the host opens its link: its first credit went to no one, so
    # it sends it again until a byte comes
    result, log = run_m0(build, uady_stream, tmp_path, late=True)
    assert result.samples == SAMPLES and result.bytes_sent == uady_stream.stat().st_size
    assert log[-1] == "# halted: done"
