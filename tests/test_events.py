"""Heater, fan and laser events: through planning (times), the CSV (comment lines) and the
binary stream (event records, version 2), read back and decoded."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import pytest
from conftest import printer
from streamtools import record_offsets
from trajectories import blocks, realistic

from deltaslice.emit import event_samples
from deltaslice.pipeline import read_output, write_samples
from deltaslice.emit import stream
from deltaslice.pipeline import decode_stream
from deltaslice.errors import StreamError
from deltaslice.gcode import parse_gcode
from deltaslice.planning import plan, split_runs
from deltaslice.samples import Samples
from deltaslice.toolpath import EventKind

EVENTS = [(0, EventKind.BED_SET, 60.0), (0, EventKind.HOTEND_WAIT, 215.0), (700, EventKind.FAN, 255.0),
          (700, EventKind.FAN, 127.0), (1234, EventKind.LASER_MODE, 0.0)]


@pytest.fixture(scope="module")
def samples():
    s, _ = realistic("delta_etitc", layers=1)
    return printer("delta_etitc"), s


def test_csv_event_lines_between_rows_and_read_back(samples, tmp_path):
    p, s = samples
    n = len(s)
    events = EVENTS + [(n, EventKind.HOTEND_SET, 0.0)]
    out = tmp_path / "e.csv"
    write_samples(blocks(s, 500), p, out, fmt="csv", rate=1000.0, events=events)
    lines = out.read_text().splitlines()
    body = lines[lines.index("t,q1,q2,q3,e,tool") + 1 :]
    i = body.index("# event t=0.700000000 kind=fan value=255")
    assert body[i + 1] == "# event t=0.700000000 kind=fan value=127"
    assert body[i - 1].startswith("0.699000000,") and body[i + 2].startswith("0.700000000,")
    assert body[-1] == f"# event t={n / 1000:.9f} kind=hotend_set value=0"
    meta, back = read_output(out)
    assert len(back) == n and meta["events"] == tuple((i, int(k), v) for i, k, v in events)
    assert np.allclose(back.q, s.q, atol=1e-9)


def test_stream_event_records(samples, tmp_path):
    p, s = samples
    n = len(s)
    events = EVENTS + [(n, EventKind.BED_SET, 0.0)]
    out = tmp_path / "e.dsl"
    write_samples(blocks(s, 777), p, out, fmt="stream", rate=1000.0, events=events)
    data = out.read_bytes()
    assert struct.unpack_from("<H", data, 8)[0] == 2  # version 2: the stream has events
    meta, back = read_output(out)
    assert meta["events"] == tuple((i, int(k), v) for i, k, v in events) and len(back) == n
    # every event record: 16 bytes, CRC of bytes 0..11, before the block whose first sample is i
    recs = [o for o, _n, kind in record_offsets(data) if kind == stream.REC_EVENT]
    assert len(recs) == len(events)
    for off, (i, kind, value) in zip(recs, events):
        rec = data[off : off + 16]
        assert struct.unpack("<BHIBi", rec[:12]) == (0x56, 16, i, int(kind),
                                                    int(round(value * 10 if kind <= 4 else value)))
        assert struct.unpack("<I", rec[12:])[0] == zlib.crc32(rec[:12])
    with open(out, "rb") as f:
        reader = stream.StreamReader(f, str(out))
        firsts = [first for _b, first, _c in reader.blocks()]
    assert {700, 1234} <= set(firsts)  # blocks end at event indices
    # without events the stream stays version 1
    plain = tmp_path / "p.dsl"
    write_samples(blocks(s, 777), p, plain, fmt="stream", rate=1000.0)
    assert struct.unpack_from("<H", plain.read_bytes(), 8)[0] == 1 and "events" not in read_output(plain)[0]


def test_decode_prints_events(samples, tmp_path):
    p, s = samples
    out = tmp_path / "e.dsl"
    write_samples(blocks(s, 1000), p, out, fmt="stream", rate=1000.0, events=EVENTS)
    buf = io.StringIO()
    decode_stream(out, buf)
    lines = buf.getvalue().splitlines()
    i = lines.index("# event i=700 kind=fan value=255")
    assert lines[i - 1].startswith("699 ") and lines[i + 2].startswith("700 ")
    assert lines[:2] == ["# event i=0 kind=bed_set value=60", "# event i=0 kind=hotend_wait value=215"]
    buf = io.StringIO()
    decode_stream(out, buf, units=True)
    assert "# event t=1.234000000 kind=laser_mode value=0" in buf.getvalue().splitlines()


def test_damaged_event_records_are_refused(samples, tmp_path):
    p, s = samples
    out = tmp_path / "e.dsl"
    write_samples(blocks(s, 1000), p, out, fmt="stream", rate=1000.0,
                  events=EVENTS)
    data = bytearray(out.read_bytes())
    off = [o for o, _n, kind in record_offsets(bytes(data)) if kind == stream.REC_EVENT][2]
    bad = bytearray(data)
    bad[off + 8] ^= 1
    (tmp_path / "b.dsl").write_bytes(bytes(bad))
    with pytest.raises(StreamError, match="event record corrupt"):
        read_output(tmp_path / "b.dsl")
    # an event whose sample index is not where it stands
    bad = bytearray(data)
    bad[off + 3 : off + 7] = struct.pack("<I", 5)
    bad[off + 12 : off + 16] = struct.pack("<I", zlib.crc32(bytes(bad[off : off + 12])))
    (tmp_path / "c.dsl").write_bytes(bytes(bad))
    with pytest.raises(StreamError, match="before sample 700"):
        read_output(tmp_path / "c.dsl")
    # an event record in a version-1 stream
    bad = bytearray(data)
    bad[8:10] = struct.pack("<H", 1)
    hlen = struct.unpack_from("<H", bad, 10)[0]
    bad[hlen - 4 : hlen] = struct.pack("<I", zlib.crc32(bytes(bad[: hlen - 4])))
    (tmp_path / "d.dsl").write_bytes(bytes(bad))
    with pytest.raises(StreamError, match="version 1 stream"):
        read_output(tmp_path / "d.dsl")


def test_event_samples_index_is_the_first_sample_at_or_after_the_time():
    assert event_samples([(0.0, 1, 200.0), (0.0123, 5, 255.0), (0.5, 2, 200.0), (9.0, 3, 0.0)], 1.0, 1000.0) == [
        (0, 1, 200.0), (13, 5, 255.0), (500, 2, 200.0), (1001, 3, 0.0)]


def test_plan_times_events_and_ends_runs_at_waits():
    etitc = printer("delta_etitc")
    text = """M104 S200
G1 X0 Y0 Z0.5 F1200
G1 X10 Y0 E0.5
M106 S255
G1 X10 Y10 E1.0
M109 S210
G1 X0 Y10 E1.5
G0 X0 Y0
M104 S0
"""
    tp = parse_gcode(text, printer=etitc)
    assert split_runs(tp) == [(1, 3), (3, 4)]  # the wait cuts the run; the fan does not
    for planner in ("toppra", "trapezoid"):
        traj = plan(tp, etitc, planner=planner, workers=1)
        times = [t for t, _k, _v in traj.events]
        # every job ends with its heaters and fan set to 0 (after the file's own M104 S0), where
        # its last move ends, before the tool lifts clear and parks
        assert [k for _t, k, _v in traj.events] == [1, 5, 2, 1, 1, 3, 5]
        assert [v for _t, _k, v in traj.events][-4:] == [0.0, 0.0, 0.0, 0.0]
        assert times[0] == 0.0 and 0 < times[-1] < traj.duration and len(set(times[-4:])) == 1
        kin = etitc.kinematics()
        assert np.allclose(kin.forward(traj.sample_at(np.array([times[-1]])).q[:, :3])[0], [0, 0, 0.5], atol=1e-6)
        assert times == sorted(times)
        if planner == "toppra":
            # the wait is where a piece starts: the machine is at rest there
            assert np.isclose(traj.starts, times[2]).any() and 0 < times[2] < traj.duration
            s = traj.sample_at(np.array([times[2] - 1e-3, times[2], times[2] + 1e-3]))
            assert np.allclose(s.q[0], s.q[1], atol=1e-6)


def test_sliced_part_carries_heater_events_to_csv_and_stream(tmp_path):
    import trimesh

    from deltaslice.pipeline import compile_part

    box = trimesh.creation.box((10, 10, 1))
    box.apply_translation((0, 0, 0.5))
    part = tmp_path / "box.stl"
    box.export(part)
    kossel = printer("linear_kossel")
    for out in (tmp_path / "box.csv", tmp_path / "box.dsl"):
        compile_part(part, kossel, output=str(out), workers=1)
        meta, s = read_output(out)
        heaters = tuple(e for e in meta["events"] if e[1] != EventKind.FAN)
        assert heaters[:4] == ((0, 3, 60.0), (0, 1, 200.0), (0, 4, 60.0), (0, 2, 200.0))
        # the part fan ([cooling]): on, full, after the first three layers of the five
        assert [e[2] for e in meta["events"] if e[1] == EventKind.FAN][:1] == [255.0]
        # hot end, bed and fan off where the last move ends (before the park)
        ends = meta["events"][-3:]
        assert [(k, v) for _i, k, v in ends] == [(1, 0.0), (3, 0.0), (5, 0.0)]
        assert len({i for i, _k, _v in ends}) == 1 and 0 < ends[0][0] < len(s.t) - 1
    etitc = printer("delta_etitc")  # an unheated bed: hot-end events only at the start
    compile_part(part, etitc, output=str(tmp_path / "e.csv"), workers=1)
    assert read_output(tmp_path / "e.csv")[0]["events"][:2] == ((0, 1, 200.0), (0, 2, 200.0))
    assert [(k, v) for _i, k, v in read_output(tmp_path / "e.csv")[0]["events"][2:]] == [(1, 0.0), (3, 0.0), (5, 0.0)]


@pytest.mark.parametrize("sizes", [(100,), (511, 2), (513,), (700, 1), (1234, 5000)])
def test_stream_bytes_do_not_depend_on_the_blocks_the_samples_come_in(samples, tmp_path, sizes):
    """The writer holds back the rows short of a record and completes them from the next block:
    whatever the blocks (smaller or larger than a record, cut at an event or beside one), the
    same records, events and bytes as the samples in one block."""
    p, s = samples
    events = EVENTS + [(len(s), EventKind.BED_SET, 0.0)]
    whole = tmp_path / "whole.dsl"
    write_samples(blocks(s, len(s)), p, whole, fmt="stream", rate=1000.0, events=events)
    cut = np.cumsum(np.resize(sizes, len(s)))
    cut = cut[cut < len(s)]
    parts = [Samples(s.t[a:b], s.q[a:b], s.e[a:b], s.tool[a:b]) for a, b in zip([0, *cut], [*cut, len(s)])]
    out = tmp_path / "parts.dsl"
    write_samples(parts, p, out, fmt="stream", rate=1000.0, events=events)
    assert out.read_bytes() == whole.read_bytes()
