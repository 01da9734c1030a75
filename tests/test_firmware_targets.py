"""The AVR players run in simavr, fed a compiled stream through the simulated UART with the
credit flow control `deltaslice send` uses (examples/firmware/sim_harness.c):

* Arduino Uno, hobby servos (ETITC): static RAM within 1,536 bytes; every 20 ms frame's pulse
  widths equal, within 1 us, the joint counts of the sample being played at the frame start; the
  servos hold the rest pose before the stream starts; the sample clock keeps time at 115200 baud.
* Arduino Mega 2560 + RAMPS, step/dir (Atlas five-bar, Kossel): the step count of every axis
  equals the stream's count difference at every sample, both directions, and at the end; the
  sample clock keeps time at 115200 baud (no sample more than 5 ms behind its slot). Its heater
  control against the harness's thermal model (every Mega run uses the `make sim` builds, with the
  thermistors on A5/A6, which simavr has; the harness refuses the others): a compiled Atlas stream's set-and-wait events switch the heater pins, hold the
  first sample until the temperatures are reached, and leave the step counts exact.

They need avr-gcc, avr-libc and simavr (Debian: gcc-avr avr-libc simavr libsimavr-dev
libelf-dev); they skip without them, except under CI (env CI set), where .ci/run installs them.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh
from meshes import write
from trajectories import ROOT, blocks, printer, realistic

from deltaslice.pipeline import compile_part, read_counts, write_samples

FIRMWARE = ROOT / "examples" / "firmware"
UNO_RAM_BUDGET = 1536
CYCLES_PER_US = 16


def _missing() -> str | None:
    if not shutil.which("avr-gcc") or not shutil.which("make"):
        return "avr-gcc or make"
    if not Path("/usr/include/simavr/sim_avr.h").exists():
        return "libsimavr-dev"
    return None


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    missing = _missing()
    if missing:
        if os.environ.get("CI"):
            pytest.fail(f"{missing} missing under CI: .ci/run installs the Debian packages")
        pytest.skip(f"{missing} not installed (apt-get install gcc-avr avr-libc simavr libsimavr-dev libelf-dev)")
    out = tmp_path_factory.mktemp("firmware")
    # the AVR boards and their harness (the Cortex-M0 build, also in `all`, is test_firmware_m0.py's)
    r = subprocess.run(["make", "-C", str(FIRMWARE), f"BUILD={out}", "avr", "host", "sim"], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    return out


def endstops_at_rest(name, offset=(0, 0, 0)):
    """sim_harness --endstops for a Mega build of printer ``name`` that powers up at its rest pose
    moved by ``offset`` steps: each switch where the printer file's [homing] puts it."""
    p = printer(name)
    J = p.n_joints
    values = np.zeros((2, len(p.limits.counts_per_unit)))
    values[0, :J], values[1, :J] = p.homing.position, p.rest_pose
    home, rest = p.limits.to_counts(values)[:, :J]
    sides = np.array(p.homing.endstop) * np.sign(p.limits.counts_per_unit[:J])
    at = home - rest - np.asarray(offset)
    return ",".join(f"{'h' if s > 0 else 'l'}{int(a)}" if s else "n" for s, a in zip(sides, at))


def simulate(build, mcu, elf, stream, seconds=60, *options):
    """Run the harness; a Mega build gets end stops as if the machine powered up at rest (unless
    the options give them): homing then takes it back there before the first sample."""
    if mcu == "atmega2560" and "--endstops" not in options:
        options = (*options, "--endstops", endstops_at_rest("linear_kossel" if "kossel" in str(elf) else "fivebar_atlas"))
    r = subprocess.run([str(build / "sim_harness"), mcu, str(build / elf), str(stream), "--seconds", str(seconds),
                        *options], capture_output=True, text=True, timeout=300)
    kinds = ("P ", "S ", "T ", "L ", "F ", "H ", "K ", "I ", "N ", "X ")
    lines = [ln.split(" ", 1) for ln in r.stdout.splitlines() if ln[:2] in kinds]
    out = {k: [] for k in "PSTLFHKINX"}
    for k, rest in lines:
        out[k].append(rest)
    return r.returncode, out


def _pad_stream(directory, printer_name):
    """A 5 x 5 x 0.5 mm pad (one layer) compiled for a printer: starts at rest, heater events at sample 0."""
    part = directory / "pad.stl"
    write(trimesh.creation.box((5, 5, 0.5)), part)
    out = directory / "pad.dsl"
    compile_part(part, printer(printer_name), output=out, workers=1)
    return out


@pytest.fixture(scope="module")
def etitc_stream(tmp_path_factory):
    """The pad compiled for the ETITC."""
    return _pad_stream(tmp_path_factory.mktemp("uno"), "delta_etitc")


def test_uno_static_ram_fits_with_room_for_the_stack(build):
    r = subprocess.run(["avr-size", "-A", str(build / "uno_servo_player.elf")], capture_output=True, text=True, check=True)
    sizes = {m.group(1): int(m.group(2)) for m in re.finditer(r"^\.(data|bss)\s+(\d+)", r.stdout, re.M)}
    assert sizes["data"] + sizes["bss"] <= UNO_RAM_BUDGET, sizes


def test_uno_servo_pulses_equal_the_stream_counts(build, etitc_stream):
    header, counts = read_counts(etitc_stream)
    code, out = simulate(build, "atmega328p", "uno_servo_player.elf", etitc_stream)
    assert code == 0 and out["L"] == [f"OK {len(counts)}"], out["L"]
    strobes = np.array([int(s.split()[1]) for s in out["S"]])
    assert len(strobes) == len(counts)  # every sample played, once
    # the sample clock keeps time: no sample later than 5 ms behind its slot
    lag_ms = (strobes - strobes[0]) / (CYCLES_PER_US * 1000) - np.arange(len(strobes))
    assert lag_ms.max() < 5.0, lag_ms.max()
    pulses = np.array([[int(x) for x in p.split()] for p in out["P"]])
    frames = 0
    for k in range(3):
        rise, width = pulses[pulses[:, 0] == k, 1], pulses[pulses[:, 0] == k, 2] / CYCLES_PER_US
        # the sample being played at the rise: the last one strobed before it (or the next, when
        # it was taken within the 10 us between the widths' latch and its strobe)
        j = np.searchsorted(strobes, rise, side="right") - 1
        expect = counts[np.clip(j, 0, len(counts) - 1), k]  # before the first: the rest pose = sample 0
        nxt = counts[np.clip(j + 1, 0, len(counts) - 1), k]
        close = (j + 1 < len(strobes)) & (strobes[np.clip(j + 1, 0, len(strobes) - 1)] - rise < 10 * CYCLES_PER_US)
        err = np.minimum(np.abs(width - expect), np.where(close, np.abs(width - nxt), np.inf))
        assert err.max() <= 1.0, (k, err.max(), int(np.argmax(err)))
        gaps = np.diff(rise) / (CYCLES_PER_US * 1000)
        # one frame every 20 ms; now and then one starts up to a lap of Timer2 (128 us) late, well
        # within what a servo accepts (14-25 ms), and the next one is on time again
        assert np.abs(gaps - 20.0).max() < 0.5 and np.median(gaps) == pytest.approx(20.0, abs=1e-3), gaps.max()
        frames += len(rise)
    assert frames >= 3 * len(counts) // 20


def test_uno_refuses_a_stream_for_another_printer(build, tmp_path):
    p = printer("linear_kossel")
    s, _ = realistic("linear_kossel", layers=1)
    path = tmp_path / "kossel.dsl"
    write_samples(blocks(s.__class__(s.t[:600], s.q[:600], s.e[:600], s.tool[:600]), 2500), p, path, fmt="stream",
                  rate=p.planning.output_rate)
    code, out = simulate(build, "atmega328p", "uno_servo_player.elf", path, seconds=5)
    assert out["L"] and out["L"][0].startswith("ERR stream made for another printer"), out["L"]
    assert not out["S"]


def test_uno_stops_at_a_corrupt_block(build, etitc_stream, tmp_path):
    from streamtools import record_offsets

    data = bytearray(etitc_stream.read_bytes())
    off, length, _ = [r for r in record_offsets(bytes(data)) if r[2] == ord("B")][2]
    data[off + length // 2] ^= 0x10
    bad = tmp_path / "bad.dsl"
    bad.write_bytes(bytes(data))
    code, out = simulate(build, "atmega328p", "uno_servo_player.elf", bad, seconds=30)
    assert out["L"] and out["L"][0].startswith("ERR block 2 at byte offset"), out["L"]


def assert_steps_exact(out, counts):
    """At the start of sample j the steps of every sample before it have been issued; at the end all
    (counted from where the first sample found the motors: after homing, the rest pose)."""
    T = np.array([[int(x) for x in t.split()] for t in out["T"]])  # sample, cycle, 4 positions
    assert len(T) == len(counts)
    rel = counts[:, :4] - counts[0, :4]
    expect = np.vstack([np.zeros((1, 4), np.int64), rel[:-1]])
    off = np.nonzero((T[:, 2:] - T[0, 2:] != expect).any(axis=1))[0]
    assert not len(off), (len(off), off[:5])
    final = np.array([int(x) for x in out["F"][0].split()])
    assert np.array_equal(final - T[0, 2:], rel[-1])
    return T


@pytest.fixture(scope="module")
def atlas_stream(tmp_path_factory):
    """The pad compiled for the Atlas: bed and hot end set-and-wait events at sample 0."""
    return _pad_stream(tmp_path_factory.mktemp("atlas"), "fivebar_atlas")


def test_mega_heaters_hold_the_first_sample_until_hot(build, atlas_stream):
    import io

    from deltaslice.pipeline import decode_stream

    text = io.StringIO()
    decode_stream(atlas_stream, text)
    events = dict(re.findall(r"^# event i=0 kind=(\w+) value=([\d.]+)$", text.getvalue(), re.M))
    hot, bed = float(events["hotend_wait"]), float(events["bed_wait"])  # 200 and 60 C for PLA
    assert hot > 100 and bed > 40 and events["hotend_set"] and events["bed_set"]
    _, counts = read_counts(atlas_stream)
    code, out = simulate(build, "atmega2560", "mega_stepper_player_sim.elf", atlas_stream)
    assert code == 0 and out["L"] == [f"OK {len(counts)}"], out["L"]
    T = assert_steps_exact(out, counts)
    H = np.array([[int(x) for x in h.split()] for h in out["H"]])  # heater, cycle, level, temp x10
    K = np.array([[int(x) for x in k.split()] for k in out["K"]])  # cycle, hot end x10, bed x10
    t0 = T[0, 1]
    for h in (0, 1):
        sw = H[H[:, 0] == h]
        assert sw[0, 2] == 1 and sw[0, 1] < t0 and sw[0, 3] == 250  # switched on cold, before any sample
        assert sw[-1, 2] == 0  # off at the end
    # the first sample waits until both are within 2 C of their set points (the model's
    # temperature at the first strobe, between two 10 ms log lines), and not much longer: the wait
    # ends within 200 ms of the hot end (the later of the two) getting there, then homing (the
    # lead screw 4000 steps to its switch and back at 10 mm/s: 2 s) comes before the first sample
    at = lambda c, col: np.interp(c, K[:, 0], K[:, col]) / 10  # noqa: E731
    assert at(t0, 1) >= hot - 2.5 and at(t0, 2) >= bed - 2.5, (at(t0, 1), at(t0, 2))
    reached = K[np.argmax(K[:, 1] >= (hot - 2) * 10), 0]
    assert 2.0 * CYCLES_PER_US * 1e6 < t0 - reached < 2.4 * CYCLES_PER_US * 1e6, (t0 - reached) / (CYCLES_PER_US * 1e6)
    assert t0 > 1.0 * CYCLES_PER_US * 1e6  # seconds of waiting (the model: ~3.9 s), not milliseconds
    # while the part plays, bang-bang holds the hot end near its set point (the model heats at
    # 50 C/s, the player reads the thermistors every 100 ms: measured 197.1-206.3 C); the part ends
    # where the job's end sets the hot end to 0, before the tool lifts clear and parks
    off = [int(i) for i, v in re.findall(r"^# event i=(\d+) kind=hotend_set value=([\d.]+)$", text.getvalue(), re.M)
           if float(v) == 0]
    assert off and 0 < off[-1] < len(T)
    play = (K[:, 0] > t0) & (K[:, 0] < T[off[-1], 1])
    assert np.abs(K[play, 1] / 10 - hot).max() < 10, (K[play, 1].min(), K[play, 1].max())
    assert ((H[:, 0] == 0) & (H[:, 1] > t0)).sum() >= 4  # it switched while playing
    # meanwhile the board says "# heating" about once a second (deltaslice send's timeout is 10 s)
    info = [i.split(" ", 1) for i in out["I"]]
    assert info and {text for _, text in info} == {"# heating"}
    # until the wait ends (homing follows it, before the first sample)
    beats = np.array([int(c) for c, _ in info] + [reached]) / (CYCLES_PER_US * 1e6)
    beats -= H[0, 1] / (CYCLES_PER_US * 1e6)  # from the heaters' set
    assert beats[0] < 1.2 and np.diff(beats).max() < 1.2, beats


@pytest.mark.parametrize("elf", ["mega_stepper_player.elf", "mega_stepper_player_kossel.elf"])
def test_the_harness_refuses_a_build_that_reads_unmodelled_thermistor_inputs(build, tmp_path, elf):
    """The RAMPS builds read A13/A14; simavr 1.6 keeps ADC0..7 and reads past its array for the
    others, so such a run's thermistor readings changed from run to run (a Kossel run once stopped
    on "thermistor shorted (ADC 6)"). The harness stops at the first such conversion instead."""
    stream = tmp_path / "empty.dsl"
    stream.write_bytes(b"")
    r = subprocess.run([str(build / "sim_harness"), "atmega2560", str(build / elf), str(stream), "--seconds", "1"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 3 and "converts ADC13, which simavr 1.6 does not model" in r.stderr, (r.returncode, r.stderr)


@pytest.mark.parametrize("name, elf", [("fivebar_atlas", "mega_stepper_player_sim.elf"),
                                       ("linear_kossel", "mega_stepper_player_kossel_sim.elf")])
def test_mega_step_counts_equal_the_stream_at_every_sample(build, tmp_path, name, elf):
    p = printer(name)
    s, _ = realistic(name, layers=1)
    path = tmp_path / f"{name}.dsl"
    # a fan event mid-stream: events are taken in order and do not disturb the steps
    write_samples(blocks(s, 2500), p, path, fmt="stream", rate=p.planning.output_rate, events=[(5000, 5, 255.0)])
    _, counts = read_counts(path)
    code, out = simulate(build, "atmega2560", elf, path)
    assert code == 0 and out["L"] == [f"OK {len(counts)}"], out["L"]
    T = assert_steps_exact(out, counts)
    # the sample clock keeps time: no sample later than 5 ms behind its slot (measured: 0.0 ms on
    # the Atlas, 1.0 ms on the Kossel; with a 4-sample ring 161 and 394 ms, growing with the print)
    period_ms = 1e3 / p.planning.output_rate
    lag_ms = (T[:, 1] - T[0, 1]) / (CYCLES_PER_US * 1000) - period_ms * np.arange(len(T))
    assert lag_ms.max() < 5.0, lag_ms.max()
    moves = np.diff(counts[:, :3], axis=0)
    assert (moves > 0).any() and (moves < 0).any()  # both directions were exercised
