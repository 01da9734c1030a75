"""The reference C player (examples/firmware/dsl_player.h), built for the host, prints
exactly what the Python decoder prints, on good, corrupt and truncated streams."""

from __future__ import annotations

import io
import shutil
import subprocess

import pytest
from streamtools import record_offsets
from trajectories import ROOT, blocks, printer, realistic

from deltaslice.pipeline import write_samples
from deltaslice.emit import stream
from deltaslice.pipeline import decode_stream
from deltaslice.errors import StreamError

FIRMWARE = ROOT / "examples" / "firmware"
CC = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")


@pytest.fixture(scope="module")
def players(tmp_path_factory):
    if CC is None:
        pytest.skip("no C compiler (cc, gcc or clang) on PATH: cannot build examples/firmware/dsl_player_host.c")
    d = tmp_path_factory.mktemp("player")
    out = {}
    for buffers in (1, 2):
        exe = d / f"dsl_player_host_{buffers}"
        subprocess.run(
            [CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", f"-DDSL_BUFFERS={buffers}",
             "-o", str(exe), str(FIRMWARE / "dsl_player_host.c")],
            check=True, capture_output=True, text=True,
        )
        out[buffers] = exe
    return out


@pytest.fixture(scope="module")
def streams(tmp_path_factory):
    d = tmp_path_factory.mktemp("streams")
    out = {}
    for name in ("delta_etitc", "linear_kossel"):
        p = printer(name)
        s, _ = realistic(name, layers=1)
        path = d / f"{name}.dsl"
        write_samples(blocks(s, 2500), p, path, fmt="stream", rate=p.planning.output_rate, metadata={"planner": "t"})
        out[name] = path
    return out


def python_decode(path):
    buf = io.StringIO()
    try:
        decode_stream(path, buf)
        return buf.getvalue(), None
    except StreamError as exc:
        return buf.getvalue(), str(exc)


def run(exe, path, chunk=4096):
    return subprocess.run([str(exe), str(path), "--chunk", str(chunk)], capture_output=True, text=True)


@pytest.mark.parametrize("name", ["delta_etitc", "linear_kossel"])
def test_host_player_matches_python_decoder(players, streams, name):
    ref, err = python_decode(streams[name])
    assert err is None and ref.count("\n") > 10000
    for buffers, exe in players.items():
        r = run(exe, streams[name])
        assert r.returncode == 0, r.stderr
        assert r.stdout == ref


def test_host_player_byte_by_byte(players, streams):
    ref, _ = python_decode(streams["linear_kossel"])
    for exe in players.values():
        r = run(exe, streams["linear_kossel"], chunk=1)
        assert r.returncode == 0 and r.stdout == ref


def _damaged(data: bytes, how: str) -> tuple[bytes, str]:
    recs = record_offsets(data)
    blocks_ = [r for r in recs if r[2] == stream.REC_BLOCK]
    if how == "flip":
        off, length, _ = blocks_[5]
        b = bytearray(data)
        b[off + length - 9] ^= 0x04
        return bytes(b), f"block 5 at byte offset {off}"
    if how == "flip_length":
        off, length, _ = blocks_[3]
        b = bytearray(data)
        b[off + 2] ^= 0x80
        return bytes(b), f"block 3 at byte offset {off}"
    if how == "flip_type":
        off, length, _ = blocks_[4]
        b = bytearray(data)
        b[off] = 0x00
        return bytes(b), f"block 4 at byte offset {off}"
    if how == "cut_mid_block":
        off, length, _ = blocks_[6]
        return data[: off + length // 2], f"block 6 at byte offset {off}"
    if how == "cut_before_end":
        return data[: recs[-1][0]], f"block {len(blocks_)} at byte offset {recs[-1][0]}"
    if how == "cut_in_end":
        return data[:-3], f"block {len(blocks_)} at byte offset {recs[-1][0]}"
    if how == "drop_block":
        off, length, _ = blocks_[2]
        return data[:off] + data[off + length :], "end record"
    if how == "trailing":
        return data + b"x", "after the end record"
    if how == "magic":
        return b"\x89DSX" + data[4:], "not a deltaslice stream"
    if how == "header_crc":
        b = bytearray(data)
        b[40] ^= 1
        return bytes(b), "header"
    if how == "cut_header":
        return data[:30], "truncated"
    raise ValueError(how)


@pytest.mark.parametrize(
    "how",
    ["flip", "flip_length", "flip_type", "cut_mid_block", "cut_before_end", "cut_in_end", "drop_block", "trailing",
     "magic", "header_crc", "cut_header"],
)
def test_host_player_on_damaged_streams(players, streams, tmp_path, how):
    data, where = _damaged(streams["delta_etitc"].read_bytes(), how)
    bad = tmp_path / "bad.dsl"
    bad.write_bytes(data)
    ref, err = python_decode(bad)
    assert err is not None
    for buffers, exe in players.items():
        for chunk in (4096, 7):
            r = run(exe, bad, chunk)
            assert r.returncode == 1, (buffers, chunk, r.stderr)
            assert r.stdout == ref, (buffers, chunk)  # same samples before the error, none from the bad block
            assert where in r.stderr and where in err, (r.stderr, err)
