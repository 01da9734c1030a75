"""The AVR players left alone (issue 49), in simavr with faults injected by the harness
(examples/firmware/sim_harness.c: a thermistor fixed at a reading, a sender that goes silent or
stalls, a corrupted byte), judged by the pins: the heater outputs (D10, D8), the driver enable pins
and the step pulses, not only the board's text.

* Heater protection (the printer file's [safety], Marlin's defaults): an open or shorted
  thermistor, a heater that does not heat, a thermal runaway once at temperature, a heating wait
  that outlasts wait_timeout: an error line naming the heater and the fault, both heaters off,
  the steppers disabled, and nothing on again.
* No host, no heat: a sender gone silent mid-job switches the heaters off within host_timeout.
* A corrupt block: its full message (not cut at 40 characters), heaters and steppers off.
* Every AVR image feeds the hardware watchdog.
* Feed hold: a sender stall and the host's pause ramp the playback clock to a stop and back, the
  path exact, the joints within their limits; abort, the E-stop and an unframed sender stop all.
* Homing (Mega): from an offset power-up against simulated end stops, then every step exact; a
  switch that never trips or reads tripped for good (a broken wire) is a fault.

Needs what tests/test_firmware_targets.py needs (gcc-avr, avr-libc, simavr, libsimavr-dev).
"""

from __future__ import annotations

import re
import subprocess

import numpy as np
import pytest
from test_firmware_targets import CYCLES_PER_US, FIRMWARE, _pad_stream, assert_steps_exact, build, simulate  # noqa: F401
from trajectories import blocks, printer, realistic

from deltaslice import load_printer
from deltaslice.pipeline import read_counts, write_firmware_config, write_samples

SECOND = CYCLES_PER_US * 1_000_000
MEGA = ("atmega2560", "mega_stepper_player_sim.elf")
OPEN, SHORT, COLD = 1023, 0, 990  # ADC readings: no sensor, a short, about 25 C


@pytest.fixture(scope="module")
def atlas_stream(tmp_path_factory):
    """The pad compiled for the Atlas: bed and hot end set-and-wait at sample 0 (200 and 60 C)."""
    return _pad_stream(tmp_path_factory.mktemp("atlas_safety"), "fivebar_atlas")


@pytest.fixture(scope="module")
def quick_build(build, tmp_path_factory):
    """The simulated Mega build with a short hold period (3 s) and heating wait (10 s), from a
    header written by firmware-config with --set (the fingerprint does not depend on [safety])."""
    out = tmp_path_factory.mktemp("quick")
    config = out / "atlas_quick.h"
    config.write_text(write_firmware_config(load_printer(
        "fivebar_atlas", {"safety.hotend_hold_period": 3, "safety.wait_timeout": 10})))
    r = subprocess.run(["make", "-C", str(FIRMWARE), f"BUILD={out}", f"CONFIG_MEGA={config}", "sim"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    return out


def heater_timeline(out):
    """(heater, cycle, level) of every switch of the heater pins."""
    return [tuple(int(x) for x in h.split()[:3]) for h in out["H"]]


def off_for_good(out, since=0):
    """The cycle from which both heater pins stay off to the end of the run (and never came on
    after ``since``'s last switch-off); None if a heater is on at the end."""
    last = {0: (0, 0), 1: (0, 0)}
    for h, cycle, level in heater_timeline(out):
        last[h] = (cycle, level)
    if any(level for _c, level in last.values()):
        return None
    return max(c for c, _l in last.values())


def disabled_at(out):
    """The cycle the four drivers were all disabled (enable mask 15), or None."""
    for n in out["N"]:
        cycle, mask = (int(x) for x in n.split())
        if mask == 15:
            return cycle
    return None


def run_end(out):
    """The last cycle the harness logged (its 10 ms temperature lines run to the end)."""
    return int(out["K"][-1].split()[0])


def assert_stopped_safe(out, error, within_s, since=0):
    """The verdict is the error, both heaters are off from ``since + within_s`` on, the drivers are
    disabled, and the run went on well after that with nothing switching on."""
    assert out["L"] and out["L"][0].startswith(error), out["L"]
    off = off_for_good(out)
    assert off is not None, "a heater is still on at the end of the run"
    assert off - since <= within_s * SECOND, (off - since) / SECOND
    assert disabled_at(out) is not None, out["N"]
    assert run_end(out) - max(off, disabled_at(out)) > 2 * SECOND  # watched for seconds after the stop


def test_every_avr_image_feeds_the_watchdog(build):
    for elf in ("uno_servo_player.elf", "mega_stepper_player.elf", "mega_stepper_player_kossel.elf",
                "mega_stepper_player_sim.elf", "mega_stepper_player_kossel_sim.elf"):
        text = subprocess.run(["avr-objdump", "-d", str(build / elf)], capture_output=True, text=True, check=True).stdout
        assert re.search(r"\twdr\b", text), f"{elf}: no wdr instruction: the watchdog is never fed"
        # wdt_enable writes WDTCSR (0x60 in data space on both MCUs) with the change-enable sequence
        assert re.search(r"sts\t0x0060, r", text), f"{elf}: WDTCSR never written: the watchdog is never enabled"


def test_open_thermistor_stops_before_anything_heats(build, atlas_stream):
    code, out = simulate(build, *MEGA, atlas_stream, 20, "--fix-thermistor", f"0,{OPEN},0", "--after", "10")
    assert out["L"] == ["ERR hot end: thermistor open (ADC 1023)"], out["L"]
    assert_stopped_safe(out, "ERR hot end: thermistor open", within_s=10)
    assert not out["T"]  # no sample played
    # neither heater was on for more than the first 100 ms poll
    on = [c for _h, c, level in heater_timeline(out) if level]
    assert all(c < 0.5 * SECOND for c in on), on


def test_shorted_bed_thermistor_is_named(build, atlas_stream):
    code, out = simulate(build, *MEGA, atlas_stream, 20, "--fix-thermistor", f"1,{SHORT},0", "--after", "5")
    assert out["L"] == ["ERR bed: thermistor shorted (ADC 0)"], out["L"]
    assert_stopped_safe(out, "ERR bed: thermistor shorted", within_s=1)
    assert not any(level for _h, _c, level in heater_timeline(out))  # a shorted sensor: found before any set point
    assert not out["T"]


def test_a_heater_that_does_not_heat_fails_within_its_heating_period(build, atlas_stream):
    # the thermistor fell out of the block: it reads the room while the heater is on
    code, out = simulate(build, *MEGA, atlas_stream, 60, "--fix-thermistor", f"0,{COLD},0", "--after", "3")
    line = out["L"][0]
    assert re.fullmatch(r"ERR hot end: heating failed \(thermal runaway\): rose -?\d+\.\d C in 40 s, under 2\.0 C", line), line
    stop = disabled_at(out)
    # WATCH_TEMP_PERIOD 40 s from the hot end's wait event, which comes once the bed is at 60 C
    # (the model's bed: 2.3 s), as an M109 restarts Marlin's watch: measured 42.4 s
    assert 40 * SECOND <= stop <= 43 * SECOND, stop / SECOND
    assert_stopped_safe(out, "ERR hot end: heating failed", within_s=43)
    assert not out["T"]  # the wait never let a sample through


def test_thermal_runaway_once_at_temperature(quick_build, atlas_stream):
    # at temperature and printing (the wait ends at ~3.9 s, homing takes 2 s), the hot end reads
    # cold from 8 s on: more than 4 C under its set point for hotend_hold_period (3 s in this build)
    code, out = simulate(quick_build, *MEGA, atlas_stream, 30, "--fix-thermistor", f"0,{COLD},8", "--after", "3")
    line = out["L"][0]
    assert line == "ERR hot end: thermal runaway: 17.1 C, more than 4.0 C under its set point 200.0 C for 3 s", line
    assert_stopped_safe(out, "ERR hot end: thermal runaway", within_s=11.2)
    T = np.array([[int(x) for x in t.split()[:2]] for t in out["T"]])
    assert T[0, 1] < 7 * SECOND and len(T) > 100  # it was printing
    stop = disabled_at(out)
    assert T[-1, 1] <= stop  # no sample after the stop
    assert 10.8 * SECOND <= stop <= 11.2 * SECOND, stop / SECOND  # the 30th poll from 8 s on


def test_heating_wait_has_a_limit_the_keepalive_does_not_extend(quick_build, atlas_stream):
    # the hot end stalls at about 150 C (a reading that neither rises nor reaches 200 C); the heating
    # watch (40 s) would catch it later, the wait's own limit (10 s in this build) first
    code, out = simulate(quick_build, *MEGA, atlas_stream, 30, "--fix-thermistor", "0,355,0", "--after", "3")
    assert out["L"] == ["ERR hot end: not at its set point after the longest heating wait, 10 s"], out["L"]
    assert len(out["I"]) >= 8  # "# heating" every second meanwhile
    assert_stopped_safe(out, "ERR hot end: not at its set point", within_s=10.3)


def test_host_gone_mid_job_switches_the_heaters_off(build, atlas_stream):
    # the sender stops at 70 % of the stream; from 5 s on (printing) the nozzle reads cold, so the
    # bang-bang keeps the heater on: the board must notice the silence, not the temperature
    n = len(atlas_stream.read_bytes())
    code, out = simulate(build, *MEGA, atlas_stream, 60, "--cut", str(int(0.7 * n)),
                         "--fix-thermistor", f"0,{COLD},5", "--after", "5")
    assert out["L"] == ["ERR host silent for 5 s: heaters off, motors off"], out["L"]
    T = np.array([[int(x) for x in t.split()[:2]] for t in out["T"]])
    cut = int(out["X"][0].split()[0])
    assert T[0, 1] < cut  # mid-job: the part was playing when the host went
    last = T[-1, 1]
    assert_stopped_safe(out, "ERR host silent", within_s=15, since=last)
    assert off_for_good(out) - last <= 15 * SECOND
    # the heater regulated (on) until the board gave up on the host
    assert any(h == 0 and level and c > 5 * SECOND for h, c, level in heater_timeline(out))


def test_corrupt_block_stops_heaters_and_motors_with_the_whole_message(build, atlas_stream, tmp_path):
    from streamtools import record_offsets

    data = bytearray(atlas_stream.read_bytes())
    off, length, _ = [r for r in record_offsets(bytes(data)) if r[2] == ord("B")][3]
    data[off + length // 2] ^= 0x10
    bad = tmp_path / "bad.dsl"
    bad.write_bytes(bytes(data))
    code, out = simulate(build, *MEGA, bad, 60, "--after", "3")
    line = out["L"][0]
    assert re.fullmatch(r"ERR block 3 at byte offset \d+: CRC mismatch: block is corrupt", line), line
    assert len(line) > 44  # more than the 40 characters the message was cut at
    assert_stopped_safe(out, "ERR block 3", within_s=60)
    stop = disabled_at(out)
    T = np.array([[int(x) for x in t.split()[:2]] for t in out["T"]])
    assert T[-1, 1] <= stop and len(T) > 0
    _, counts = read_counts(atlas_stream)
    assert len(T) < len(counts)


def test_uno_corrupt_block_message_whole_and_extruder_disabled(build, tmp_path):
    from streamtools import record_offsets

    stream = _pad_stream(tmp_path, "delta_etitc")
    data = bytearray(stream.read_bytes())
    off, length, _ = [r for r in record_offsets(bytes(data)) if r[2] == ord("B")][2]
    data[off + length // 2] ^= 0x10
    bad = tmp_path / "bad.dsl"
    bad.write_bytes(bytes(data))
    code, out = simulate(build, "atmega328p", "uno_servo_player.elf", bad, 30, "--after", "0.5")
    assert re.fullmatch(r"ERR block 2 at byte offset \d+: CRC mismatch: block is corrupt", out["L"][0]), out["L"]
    masks = [int(n.split()[1]) for n in out["N"]]
    assert masks[-1] == 8  # the extruder's driver disabled (D8 high)
    # the servos hold their last widths: frames go on after the verdict
    last_strobe = int(out["S"][-1].split()[1])
    rises = [int(p.split()[1]) for p in out["P"] if p.startswith("0 ")]
    assert sum(r > last_strobe + 0.1 * SECOND for r in rises) >= 10


def warp(out, counts, period_ms=1.0, h=20):
    """What the joints did in real time: the clock's rate r at each sample (the stream's period over
    the strobe interval), its change, and each joint's velocity and acceleration as played,
    v = v_stream r and a = a_stream r^2 + v_stream dr/dt (counts per ms, per ms^2), with the
    stream's own v and a from central differences over h samples (the counts are quantised)."""
    T = np.array([[int(x) for x in t.split()[:2]] for t in out["T"] or out["S"]])  # Mega, Uno strobes
    n = len(T)
    c = counts[:n, :3].astype(float)
    t = T[:, 1] / (CYCLES_PER_US * 1000)
    vs, acc = np.zeros_like(c), np.zeros_like(c)
    vs[h:-h] = (c[2 * h:] - c[:-2 * h]) / (2 * h * period_ms)
    acc[h:-h] = (c[2 * h:] - 2 * c[h:-h] + c[:-2 * h]) / (h * period_ms) ** 2
    r = np.ones(n)
    r[:-1] = period_ms / np.diff(t)
    dr = np.zeros(n)
    dr[1:-1] = (r[2:] - r[:-2]) / (t[2:] - t[:-2])
    return t, r, vs, vs * r[:, None], acc * r[:, None] ** 2 + vs * dr[:, None]


@pytest.mark.parametrize("name, mcu, elf, fault", [
    ("fivebar_atlas", "atmega2560", "mega_stepper_player_sim.elf", "stall"),
    ("linear_kossel", "atmega2560", "mega_stepper_player_kossel_sim.elf", "stall"),
    ("delta_etitc", "atmega328p", "uno_servo_player.elf", "stall"),
    ("fivebar_atlas", "atmega2560", "mega_stepper_player_sim.elf", "pause"),
    ("linear_kossel", "atmega2560", "mega_stepper_player_kossel_sim.elf", "pause"),
    ("delta_etitc", "atmega328p", "uno_servo_player.elf", "pause"),
])
def test_stall_and_pause_are_ridden_out_with_a_ramp(build, tmp_path, name, mcu, elf, fault):
    """stall: the sender stops for 2.5 s mid-part: the player sees its buffer running low and ramps
    its clock to a stop and back (the old Mega stopped dead and restarted at speed: 20-30 % of the
    peak speed at both ends; the old Uno caught up in a burst of samples 0.13 ms apart). pause: the
    host's feed hold at 6 s for 3 s, the same ramp. Either way the path is the stream's (every
    step exact on the Mega, every sample played once on the Uno), and no moving sample comes
    < 0.5 ms after the one before."""
    p = printer(name)
    s, _ = realistic(name, layers=1)
    path = tmp_path / f"{name}.dsl"
    write_samples(blocks(s, 2500), p, path, fmt="stream", rate=p.planning.output_rate)
    _, counts = read_counts(path)
    n = len(path.read_bytes())
    # (the Kossel's test trajectory starts 290 mm below its rest pose: homing then takes it there
    # at 30 mm/s, and its part plays from 9.8 s on)
    option = ["--stall", f"{n // 2},2.5"] if fault == "stall" else ["--pause", "14,3" if "kossel" in name else "6,3"]
    code, out = simulate(build, mcu, elf, path, 60, *option)
    assert code == 0 and out["L"] == [f"OK {len(counts)}"], out["L"]
    events = [x.split()[2] for x in out["X"]]
    assert events[0] == fault and events[-1] == "resume", events
    if mcu == "atmega2560":
        assert_steps_exact(out, counts)
    else:
        assert len(out["S"]) == len(counts)
    t, r, vs, v, a = warp(out, counts)
    gaps = np.diff(t)
    g = int(np.argmax(gaps))
    assert gaps[g] > 1500  # the stop is in the playback (a stall: 2.5 s less the buffer played meanwhile)
    peak = np.abs(vs).max(axis=0)
    moving = peak > 0
    entry = np.abs(vs[g]) * r[g - 1] / np.where(moving, peak, 1)
    leave = np.abs(vs[g + 1]) * r[g + 1] / np.where(moving, peak, 1)
    assert (entry < 0.05).all() and (leave < 0.05).all(), (entry, leave)  # measured: <= 2.9 %
    assert np.abs(vs[g] / np.where(moving, peak, 1)).max() > 0.1  # it stalled while moving
    moved = np.any(np.diff(counts[:len(t), :3], axis=0) != 0, axis=1)
    assert gaps[moved].min() >= 0.5, gaps[moved].min()  # measured: 0.995 ms (Mega), 0.78 (Uno)
    if mcu != "atmega2560":
        return  # the Uno strobes from its main loop (+-0.2 ms): too rough for an acceleration
    # the ramps keep the joints within their limits (counts per ms and per ms^2)
    cpu = np.abs(np.array(p.limits.counts_per_unit[:3]))
    vmax, amax = np.array(p.limits.velocity[:3]) * cpu / 1e3, np.array(p.limits.acceleration[:3]) * cpu / 1e6
    ramp = (r < 0.98) & (r > 0)
    assert ramp.sum() > 50
    assert (np.abs(v[ramp]) <= vmax).all() and (np.abs(a[ramp]) <= amax).all()


@pytest.mark.parametrize("option, error", [
    (("--abort", "6"), "ERR aborted by the host: heaters off, motors off"),
    (("--estop", "6"), "ERR emergency stop (D41 open): heaters off, motors off"),
])
def test_abort_and_estop_stop_motion_and_heaters_at_once(build, atlas_stream, option, error):
    # at 6 s the part is printing (the wait ended at ~3.9 s) and the hot end regulating
    code, out = simulate(build, *MEGA, atlas_stream, 30, *option, "--after", "3")
    assert out["L"] == [error], out["L"]
    at = int(out["X"][0].split()[0])
    stop = disabled_at(out)
    assert 0 <= stop - at < (5 if option[0] == "--estop" else 1) * CYCLES_PER_US * 1000, (stop - at) / CYCLES_PER_US
    T = np.array([[int(x) for x in t.split()[:2]] for t in out["T"]])
    assert T[0, 1] < at and T[-1, 1] <= stop  # it was playing; no sample after
    assert_stopped_safe(out, error, within_s=0.01, since=at)
    F = np.array([int(x) for x in out["F"][0].split()])
    steps_at_stop = np.array([int(x) for x in out["T"][-1].split()[2:]])
    assert (np.abs(F - steps_at_stop) <= 31).all()  # at most the rest of one sample's steps after it


def test_a_sender_of_the_unframed_protocol_is_refused(build, atlas_stream):
    code, out = simulate(build, *MEGA, atlas_stream, 10, "--unframed", "--after", "1")
    assert out["L"] and out["L"][0].startswith("ERR serial: byte 137 between chunks"), out["L"]
    assert not out["T"] and not any(level for _h, _c, level in heater_timeline(out))


@pytest.mark.parametrize("name, elf, offset", [("fivebar_atlas", "mega_stepper_player_sim.elf", (300, -250, 800)),
                                               ("linear_kossel", "mega_stepper_player_kossel_sim.elf", (-2000, -1500, -2500))])
def test_homing_finds_the_rest_pose_then_every_step_is_exact(build, tmp_path, name, elf, offset):
    """The machine powers up away from its rest pose (the arms turned, the carriages lower): the
    player homes every joint against its simulated end stop ([homing] of the printer file), steps
    to the rest pose and plays the stream from there, every step count exact."""
    from test_firmware_targets import endstops_at_rest

    p = printer(name)
    s, _ = realistic(name, layers=1)
    path = tmp_path / f"{name}.dsl"
    write_samples(blocks(s, 2500), p, path, fmt="stream", rate=p.planning.output_rate)
    _, counts = read_counts(path)
    code, out = simulate(build, "atmega2560", elf, path, 60, "--endstops", endstops_at_rest(name, offset))
    assert code == 0 and out["L"] == [f"OK {len(counts)}"], out["L"]
    T = assert_steps_exact(out, counts)
    # the first sample finds the motors exactly there: the rest pose is where they powered up less
    # the offset, and this stream (a test trajectory) starts a little off it
    values = np.zeros((1, len(p.limits.counts_per_unit)))
    values[0, :3] = p.rest_pose
    rest = p.limits.to_counts(values)[0, :3]
    assert list(T[0, 2:5]) == list(counts[0, :3] - rest - np.array(offset)), T[0]


def test_an_end_stop_that_never_trips_is_a_fault(build, atlas_stream):
    code, out = simulate(build, *MEGA, atlas_stream, 30, "--endstops", "h99999,l-433,l-4000", "--after", "1")
    assert out["L"] == ["ERR joint 1: end stop not found within the joint's range"], out["L"]
    assert not out["T"] and disabled_at(out) is not None
    F = [int(x) for x in out["F"][0].split()]
    assert F[0] == 11734  # DSL_CFG_HOME_MAX_STEPS: the joint's range and a tenth, then it stopped


def test_an_end_stop_with_a_broken_wire_is_a_fault(build, atlas_stream):
    # no switch on the pin: the pull-up reads tripped (open), and backing off does not release it
    code, out = simulate(build, *MEGA, atlas_stream, 30, "--endstops", "n,l-433,l-4000", "--after", "1")
    assert out["L"] == ["ERR joint 1: end stop tripped and not released by backing off (a broken wire?)"], out["L"]
    assert not out["T"] and disabled_at(out) is not None
    F = [int(x) for x in out["F"][0].split()]
    assert F[0] == -(11734 // 16)  # backed off a sixteenth of the range, away from the switch
