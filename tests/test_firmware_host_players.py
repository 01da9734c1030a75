"""The Dynamixel, DC-motor and UCB players (examples/firmware), built for the host and fed compiled
streams: the bus bytes checked byte for byte against the protocol's documented layout written
here independently, the laser following the tool channel, the PID driving a simulated gear
motor along a stream within a stated error, and the UCB's power-up step (potentiometers to the
rest pose) and step playback counted pulse by pulse."""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np
import pytest
from trajectories import ROOT, blocks, printer, realistic

from deltaslice.pipeline import compile_part, read_counts, write_samples

FIRMWARE = ROOT / "examples" / "firmware"
PID_FOLLOWING_BOUND = 2  # counts (0.48 deg of the UADY's output shaft), on a compiled part


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    if not (shutil.which("cc") or shutil.which("gcc")) or not shutil.which("make"):
        if os.environ.get("CI"):
            pytest.fail("no C compiler or make under CI")
        pytest.skip("no C compiler or make")
    out = tmp_path_factory.mktemp("host")
    r = subprocess.run(["make", "-C", str(FIRMWARE), f"BUILD={out}", "host"], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    return out


def protocol1_packet(ident: int, instruction: int, params: list[int]) -> bytes:
    """Dynamixel protocol 1.0 instruction packet as the ROBOTIS e-Manual lays it out:
    FF FF ID LENGTH INSTRUCTION PARAMS CHECKSUM, LENGTH = len(params) + 2,
    CHECKSUM = ~(ID + LENGTH + INSTRUCTION + sum(PARAMS)) & 0xFF."""
    length = len(params) + 2
    checksum = ~(ident + length + instruction + sum(params)) & 0xFF
    return bytes([0xFF, 0xFF, ident, length, instruction, *params, checksum])


def sync_write_goals(ids, goals) -> bytes:
    params = [30, 2]  # GOAL_POSITION, 2 bytes per servo
    for i, g in zip(ids, goals):
        g = min(max(int(g), 0), 1023)
        params += [i, g & 0xFF, g >> 8]
    return protocol1_packet(0xFE, 0x83, params)


@pytest.fixture(scope="module")
def espe_stream(tmp_path_factory):
    p = printer("delta_espe_laser")
    s, _ = realistic("delta_espe_laser", layers=1)
    path = tmp_path_factory.mktemp("espe") / "espe.dsl"
    write_samples(blocks(s, 2500), p, path, fmt="stream", rate=p.planning.output_rate,
                  events=[(0, 6, 4.0), (4000, 6, 0.0), (4500, 6, 3.0)])
    return path


def run_dxl(build, stream, *args):
    r = subprocess.run([str(build / "dynamixel_player"), str(stream), *args], capture_output=True, text=True, check=True)
    return [ln.split() for ln in r.stdout.splitlines()]


def test_manual_example_torque_enable():
    # the e-Manual's WRITE_DATA example: torque on for ID 1 (address 24, value 1)
    assert protocol1_packet(1, 0x03, [24, 1]).hex(" ").upper() == "FF FF 01 04 03 18 01 DE"


@pytest.mark.parametrize("baud, decimation", [(1_000_000, 1), (57_600, 3)])
def test_dynamixel_packets_byte_for_byte(build, espe_stream, baud, decimation):
    _, counts = read_counts(espe_stream)
    lines = run_dxl(build, espe_stream, "--baud", str(baud), "--ids", "1,2,3")
    info = next(ln for ln in lines if ln[0] == "#")
    assert info[1:3] == ["decimation", str(decimation)]
    # 17 bytes a packet for three servos: 170 us at 1 Mbps, 2.95 ms at 57600 baud (> 1 ms period)
    assert info[3:5] == ["packet", "17"]
    torque = [bytes.fromhex("".join(ln[2:])) for ln in lines if ln[0] == "T"]
    assert torque == [protocol1_packet(i, 0x03, [24, 1]) for i in (1, 2, 3)]
    packets = [(int(ln[1]), bytes.fromhex("".join(ln[2:]))) for ln in lines if ln[0] == "P"]
    expect_idx = list(range(0, len(counts), decimation))
    if expect_idx[-1] != len(counts) - 1:
        expect_idx.append(len(counts) - 1)  # the last sample always goes out
    assert [i for i, _ in packets] == expect_idx
    for i, pkt in packets:
        assert pkt == sync_write_goals((1, 2, 3), counts[i, :3]), i


def test_laser_duty_follows_the_tool_channel_and_the_mode(build, espe_stream):
    _, counts = read_counts(espe_stream)
    lines = run_dxl(build, espe_stream)
    changes = [(int(ln[1]), int(ln[2])) for ln in lines if ln[0] == "L"]
    duty = np.zeros(len(counts), int)
    for k, (i, d) in enumerate(changes):
        end = changes[k + 1][0] if k + 1 < len(changes) else len(counts)
        duty[i:end] = d
    mode_on = np.ones(len(counts), bool)
    mode_on[4000:4500] = False  # M5 between the two mode events
    expect = np.where(mode_on, np.clip(counts[:, 3], 0, 255), 0)
    assert np.array_equal(duty, expect)
    assert (expect > 0).any() and (expect[4000:4500] == 0).all() and (counts[4000:4500, 3] > 0).any()


def tiny_part(d, name):
    """A one-layer 5 x 5 x 0.5 mm pad compiled for printer ``name``: the move from rest, the layer, the park."""
    import trimesh
    from meshes import write

    write(trimesh.creation.box((5, 5, 0.5)), d / "pad.stl")
    compile_part(d / "pad.stl", printer(name), output=d / "pad.dsl", workers=1)
    return d / "pad.dsl"


@pytest.fixture(scope="module")
def pid_run(build, tmp_path_factory):
    path = tiny_part(tmp_path_factory.mktemp("uady"), "delta_uady")
    r = subprocess.run([str(build / "dc_pid_player"), str(path)], capture_output=True, text=True, check=True)
    return read_counts(path)[1], np.loadtxt(r.stdout.splitlines(), dtype=np.int64)


def test_pid_follows_the_stream(pid_run):
    counts, out = pid_run
    assert len(out) == len(counts)
    assert np.array_equal(counts[0, :3], counts[-1, :3])  # a compiled stream: from rest, parked at rest
    for j in range(3):
        sp, pos = out[:, 1 + 3 * j], out[:, 2 + 3 * j]
        assert np.array_equal(sp, counts[:, j] - counts[0, j])  # setpoints are the stream's counts
        assert np.abs(sp - pos).max() <= PID_FOLLOWING_BOUND, (j, np.abs(sp - pos).max())
        assert np.abs(np.diff(sp)).sum() > 200  # the joint did move


def test_pid_saturates_without_windup(build):
    # a 1000-count step saturates the drive for ~0.5 s: conditional integration keeps the
    # overshoot under 1 % and the motor settles within 1 count
    r = subprocess.run([str(build / "dc_pid_player"), "--step", "1000", "--ms", "800"], capture_output=True, text=True,
                       check=True)
    a = np.loadtxt(r.stdout.splitlines(), dtype=np.int64)
    pos, duty = a[:, 2], a[:, 3]
    assert (duty[1:200] == 255).all() and np.abs(duty).max() <= 255
    assert pos.max() - 1000 <= 8, pos.max()  # 7; 11 counts when it integrates while saturated
    assert np.abs(pos[-100:] - 1000).max() <= 1


@pytest.fixture(scope="module")
def ucb_stream(tmp_path_factory):
    return tiny_part(tmp_path_factory.mktemp("ucb"), "delta_ucb")


@pytest.mark.parametrize("readings, steps", [((1790, 1810, 2000), -800), ((3200, 3160, 3160), 0)])
def test_ucb_steps_from_the_pots_to_rest_then_plays_the_stream(build, ucb_stream, readings, steps):
    # the UCB document's calibration: 1790/1810/2000 are 90 deg (800 counts) on joints 1/2/3,
    # 3200/3160/3160 are 0 deg, the rest pose
    _, counts = read_counts(ucb_stream)
    r = subprocess.run([str(build / "ucb_stepper_player"), str(ucb_stream), *map(str, readings)],
                       capture_output=True, text=True, check=True)
    info = [ln.split()[1:] for ln in r.stdout.splitlines() if ln.startswith("#")]
    sensors = [[int(x) for x in i[1:]] for i in info if i[0] == "sensor"]
    assert [s[3] for s in sensors] == [steps] * 3
    home = next([int(x) for x in i[1:]] for i in info if i[0] == "home")
    assert home[1:] == list(counts[0, :3])  # the stream starts at rest, where the power-up move ends
    # the power-up move keeps to the joints' limits (it went from 0 to 3,460 deg/s in one period):
    # speed and acceleration over 20-period windows (the counts are whole)
    p = printer("delta_ucb")
    cpu = abs(p.limits.counts_per_unit[0])
    vmax, amax = p.limits.velocity[0] * cpu, p.limits.acceleration[0] * cpu  # counts/s, counts/s^2
    move = np.array([[int(x) for x in i[1:]] for i in info if i[0] == "move"])
    assert len(move) == home[0]
    if steps:
        w, dt = 20, 20e-3
        pos = move
        speed = (pos[w:] - pos[:-w]) / dt
        assert np.abs(speed).max() <= vmax * 1.02, (np.abs(speed).max(), vmax)
        acc = (speed[w:] - speed[:-w]) / dt
        assert np.abs(acc).max() <= amax * 1.05, (np.abs(acc).max(), amax)
        t_min = 2 * np.sqrt(abs(steps) / amax)  # a triangle at the acceleration limit (measured 183 ms)
        assert len(move) * 1e-3 >= t_min * 0.95, (len(move), t_min)  # per-period steps: a few ms less
    out = np.loadtxt([ln for ln in r.stdout.splitlines() if not ln.startswith("#")], dtype=np.int64)
    assert len(out) == len(counts) and np.array_equal(out[:, 0], np.arange(len(counts)))
    # the pulses counted at the end of every sample's period take each axis to the sample's counts
    assert np.array_equal(out[:, 1:], counts[:, :4])
    assert next(i for i in info if i[0] == "overruns") == ["overruns", "0"]  # nor in the power-up move
    assert (np.diff(counts[:, :3], axis=0) != 0).any()


def test_serial_credit_comes_while_the_board_decodes(build):
    # avr_serial.h on the host: a whole chunk received while the board is busy, the next credit
    # once it takes one byte (the accounting before counted received bytes as both used and
    # promised: 33); on a random schedule of arrivals and takes no byte is lost or reordered
    for seed in (1, 2, 3):
        r = subprocess.run([str(build / "serial_check"), str(seed)], capture_output=True, text=True, check=True)
        first, last = r.stdout.splitlines()
        assert first == "second_credit_after 1"
        n = dict(zip(last.split()[::2], map(int, last.split()[1::2])))
        assert n["lost"] == 0 and n["bytes"] > 100_000 and 64 < n["max_in_ring"] <= 127, n
