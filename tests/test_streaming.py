"""A large G-code compiled a stretch at a time (issue 14: memory bounded by a stretch, not the print).

``gcode.open_gcode`` reads a file once into a temporary file and hands its moves over in chunks;
``planning.plan_stream`` plans the chunks as they come, a run going on past a chunk planned with
the next chunk's moves, and a run longer than ``STREAM_RUN`` window by window as its parts come.
The chunks, windows and thresholds are made small here so the files stay small.
"""

from __future__ import annotations

import filecmp
import tracemalloc

import numpy as np
import pytest

from deltaslice import load_printer
from deltaslice import gcode as gcode_mod
from deltaslice import pipeline
from deltaslice import planning
from deltaslice.errors import DeltasliceError, UnreachableError
from deltaslice.gcode import open_gcode, read_gcode
from deltaslice.planning import plan, plan_stream, topp
from deltaslice.planning.context import PlanContext
from deltaslice.planning.runpath import RunSpec
from deltaslice.planning.stages import run_stage_maxima
from deltaslice.planning.topp import iter_run_parts, plan_run
from deltaslice.toolpath import Toolpath

COLUMNS = ("start", "xyz", "feed", "e", "tool", "role", "layer", "layer_z")


@pytest.fixture(scope="module")
def kossel():
    return load_printer("linear_kossel")


def prusa_like(layers=6, sides=40, filament=None, arcs=True, z_comments=True) -> str:
    """A PrusaSlicer-style file: ;LAYER_CHANGE and ;Z: comments, absolute E, a wall of ``sides``
    moves a layer, a retraction, a travel and a short infill line per layer, a heater wait and
    a fan in the middle, an arc per layer; ``filament``: the settings block's filament diameter."""
    out = ["G21", "G90", "M82", "M104 S200", "G92 E0", "G1 Z0.3 F7800", "G1 X20 Y0 F7800"]
    e = 0.0
    for layer in range(layers):
        z = 0.3 + 0.2 * layer
        out += [";LAYER_CHANGE"] + ([f";Z:{z:.2f}"] if z_comments else []) + [f"G1 Z{z:.2f} F7800", ";TYPE:Perimeter"]
        for k in range(1, sides + 1):
            th = 2 * np.pi * k / sides
            x, y = 20 * np.cos(th), 20 * np.sin(th)
            e += 0.04 * 2 * np.pi * 20 / sides
            out.append(f"G1 X{x:.3f} Y{y:.3f} E{e:.5f} F1800")
        if layer == layers // 2:
            out += ["M109 S210", "M106 S128"]
        e -= 0.8
        out += [f"G1 E{e:.5f} F2100", "G1 X5 Y5 F7800", f"G1 E{e + 0.8:.5f} F2100", ";TYPE:Solid infill"]
        e += 0.8
        for k in range(6):
            e += 0.03
            out.append(f"G1 X{5 + 2 * (k + 1):.3f} Y{5 + (k % 2):.3f} E{e:.5f} F1500")
        if arcs:
            e += 0.2
            out.append(f"G2 X21.000 Y6.000 I2 J0 E{e:.5f} F1200")  # a half circle about (19, 6)
    out += ["M107", "M104 S0"]
    if filament is not None:
        out.append(f"; filament_diameter = {filament}")
    return "\n".join(out) + "\n"


def joined(chunks) -> Toolpath:
    chunks = list(chunks)
    tp = chunks[0]
    for c in chunks[1:]:
        tp = tp.then(c)
    return tp


def same_toolpath(a: Toolpath, b: Toolpath) -> None:
    for name in COLUMNS:
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.array_equal(a.events, b.events)


@pytest.mark.parametrize("filament", [None, 3.0])
@pytest.mark.parametrize("chunk", [1, 7, 45, 100000])
def test_a_gcode_in_chunks_is_the_file_read_whole(tmp_path, kossel, chunk, filament):
    """Bit for bit, whatever the chunk: moves, filament (rescaled for 3 mm filament, retractions
    kept at their length across the chunks' ends), roles, layers and heights, events."""
    path = tmp_path / "p.gcode"
    path.write_text(prusa_like(filament=filament))
    notes_whole, notes_stream = [], []
    whole = read_gcode(path, printer=kossel, echo=notes_whole.append)
    with open_gcode(path, printer=kossel, chunk=chunk, echo=notes_stream.append) as stream:
        assert stream.streamed and stream.moves == len(whole) and stream.layers == whole.n_layers
        chunks = list(stream.chunks())
        same_toolpath(stream.whole(), whole)
    assert sum(len(c) for c in chunks) == len(whole)
    arc = int(np.diff(np.flatnonzero(np.diff(whole.role) != 0)).max())  # the longest stretch of one role
    assert all(len(c) < chunk + arc for c in chunks)  # a block ends after the move (an arc's chords) that fills it
    same_toolpath(joined(chunks), whole)
    assert notes_stream == notes_whole  # said once, while reading
    if filament:
        assert any("rescaled" in n for n in notes_stream)
        assert (whole.e[whole.role == 7] != 0).any()


@pytest.mark.parametrize("chunk", [3, 50])
def test_layers_without_their_height_comment_get_it_from_a_pass_over_the_moves(tmp_path, kossel, chunk):
    """Cura writes ;LAYER:n and no ;Z: : a layer's height is its highest working move, found in a
    pass over the temporary file before the chunks, the same as the file read whole."""
    path = tmp_path / "noz.gcode"
    path.write_text(prusa_like(z_comments=False).replace(";LAYER_CHANGE", ";LAYER:0"))
    whole = read_gcode(path, printer=kossel)
    assert whole.n_layers == 6 and len(set(whole.layer_z.tolist())) == 6
    with open_gcode(path, printer=kossel, chunk=chunk) as stream:
        assert stream.streamed
        chunks = list(stream.chunks())
    assert len(chunks) > 3
    same_toolpath(joined(chunks), whole)


@pytest.mark.parametrize("chunk", [1, 3, 50])
def test_a_file_without_layer_comments_gets_its_layers_from_two_passes(tmp_path, kossel, chunk):
    """Slic3r and GRBL write no layer comments: a new layer at each working move higher than every
    one before (a pass forwards), the travels and retractions before it belonging to it (a pass
    backwards, across the chunks' ends): the layers and heights the file read whole gets. A file
    that never works is one layer. --center needs the footprint of every move: one chunk."""
    path = tmp_path / "nolayers.gcode"
    path.write_text(prusa_like().replace(";LAYER_CHANGE\n", ""))
    whole = read_gcode(path, printer=kossel)
    assert whole.n_layers == 6
    with open_gcode(path, printer=kossel, chunk=chunk) as stream:
        assert stream.streamed and stream.layers == 6
        chunks = list(stream.chunks())
    same_toolpath(joined(chunks), whole)
    idle = tmp_path / "idle.gcode"
    idle.write_text("G90\nG0 X1 Y1 Z1\nG0 X2 Y2 Z3\nG0 X3 Y1 Z2\n")
    with open_gcode(idle, printer=kossel, chunk=chunk) as stream:
        same_toolpath(joined(stream.chunks()), read_gcode(idle, printer=kossel))
    with open_gcode(path, printer=kossel, chunk=10, center=True) as stream:
        assert not stream.streamed
        (only,) = stream.chunks()
    same_toolpath(only, read_gcode(path, printer=kossel, center=True))


@pytest.fixture
def full_batches(monkeypatch):
    """A stream's jobs go to the workers CHUNK_MAX at a time, as those of a print of more than
    8 * CHUNK_MAX jobs do; a smaller print planned whole is made to do the same (its travels are
    solved a batch at a time, and other batches would change their last bits), in chunks of 8 so
    that these small prints make several (a stream chunked otherwise than a print fails)."""
    monkeypatch.setattr(planning.scheduler, "CHUNKS_PER_PRINT", 1e-9)
    monkeypatch.setattr(planning.scheduler, "CHUNK_MAX", 8)  # several chunks even in these small prints


def test_a_stream_is_planned_as_the_whole_toolpath(tmp_path, kossel, full_batches):
    """Runs and travels going on past a chunk are planned with the next chunk's moves: the same
    jobs, the same pieces, the same events as the whole toolpath planned at once."""
    path = tmp_path / "p.gcode"
    path.write_text(prusa_like(layers=5))
    whole = plan(read_gcode(path, printer=kossel), kossel, workers=1)
    for chunk in (13, 64):
        with open_gcode(path, printer=kossel, chunk=chunk) as stream:
            done = []
            traj = plan_stream(stream.chunks(), kossel, moves=stream.moves, workers=1,
                               progress=lambda d, n: done.append((d, n)))
        assert traj.duration == whole.duration
        assert traj.events == whole.events
        assert traj.piece_counts() == whole.piece_counts()
        assert [p.duration for p in traj.pieces] == [p.duration for p in whole.pieces]
        assert done[-1] == (stream.moves, stream.moves)


def test_compiling_a_large_gcode_streams_it_to_the_same_bytes(tmp_path, kossel, monkeypatch, full_batches):
    path = tmp_path / "p.gcode"
    path.write_text(prusa_like(layers=4))
    pipeline.compile_part(path, kossel, output=tmp_path / "whole.dsl", workers=1)
    monkeypatch.setattr(pipeline, "STREAM_BYTES", 0)
    monkeypatch.setattr(gcode_mod, "CHUNK_MOVES", 50)
    seen = []
    real = planning.plan_stream
    monkeypatch.setattr(planning, "plan_stream", lambda *a, **k: seen.append(1) or real(*a, **k))
    res = pipeline.compile_part(path, kossel, output=tmp_path / "stream.dsl", workers=2)
    assert seen, "the stream was not planned as a stream"
    assert res.moves == len(read_gcode(path, printer=kossel)) and res.layers == 4
    assert filecmp.cmp(tmp_path / "whole.dsl", tmp_path / "stream.dsl", shallow=False)


def spiral_text(turns: float, per_turn: int = 200) -> str:
    """A spiral vase: one run climbing 0.2 mm a turn."""
    n = int(turns * per_turn)
    k = np.arange(1, n + 1)
    th = 2 * np.pi * k / per_turn
    r = 20 + 0.5 * np.sin(25 * th)
    x, y, z = r * np.cos(th), r * np.sin(th), 0.3 + 0.2 * k / per_turn
    out = ["G21", "G90", "M82", "G92 E0", "G1 Z0.3 F7800", "G1 X20 Y0", "G1 F1800"]
    e, last = 0.0, (20.0, 0.0)
    for i in range(n):
        if i % per_turn == 0:
            out += [";LAYER_CHANGE", f";Z:{z[i]:.4f}"]
        e += 0.03 * np.hypot(x[i] - last[0], y[i] - last[1])
        out.append(f"G1 X{x[i]:.3f} Y{y[i]:.3f} Z{z[i]:.4f} E{e:.5f}")
        last = (x[i], y[i])
    return "\n".join(out) + "\n"


def test_a_run_longer_than_a_stream_run_is_planned_in_parts(tmp_path, kossel, small_windows, monkeypatch):
    """A run going on past STREAM_RUN moves is planned window by window as its parts come: it
    starts and ends at rest, joins at speed, keeps every limit, pushes the whole run's filament
    (the ratio per mm along the path driven, blends included) and takes its time within 0.1 %."""
    monkeypatch.setattr(planning.jobs, "STREAM_RUN", 250)
    path = tmp_path / "s.gcode"
    path.write_text(spiral_text(6))
    tp = read_gcode(path, printer=kossel)
    whole = plan(tp, kossel, workers=1)
    with open_gcode(path, printer=kossel, chunk=97) as stream:
        traj = plan_stream(stream.chunks(), kossel, moves=stream.moves, workers=1)
    runs = [p for p in traj.pieces if p.kind == "run"]
    assert len(runs) >= 5
    assert abs(traj.duration / whole.duration - 1) < 1e-3, (traj.duration, whole.duration)
    assert len(planning.split_runs(tp)) == 1
    pushed = sum(p.filament_total for p in traj.pieces)
    assert pushed == pytest.approx(sum(p.filament_total for p in whole.pieces), rel=1e-5)
    assert runs[0].xd[0] == 0 and runs[-1].xd[-1] == 0
    for a, b in zip(runs[:-1], runs[1:]):
        np.testing.assert_allclose(a.q_end, b.q_start, atol=1e-9)
        assert a.xd[-1] * a.S == pytest.approx(b.xd[0] * b.S, rel=1e-12) and a.xd[-1] * a.S > 1.0
    vmax, amax = kossel.limits.velocity[:3], kossel.limits.acceleration[:3]
    for p in runs:
        assert run_stage_maxima(p, kossel.kinematics(), vmax, amax).worst <= 1 + 1e-6


def test_a_run_in_parts_keeps_the_filament_of_moves_shorter_than_a_micron(kossel, small_windows):
    """Parts that end in, or are made only of, moves shorter than a micron: their filament goes to
    a segment of the next part, none is lost (a straight line, so no blend shortens the path)."""
    pts = np.c_[np.linspace(-40, 40, 801), np.zeros(801), np.full(801, 0.3)]
    pts = np.insert(pts, [100, 100, 100, 250, 400, 400], pts[[100, 100, 100, 250, 400, 400]], axis=0)
    e = np.full(len(pts) - 1, 0.01)
    spec = RunSpec(pts, np.full(len(e), 40.0), e, 1.0, 0)
    bounds = [0, 50, 99, 100, 101, 102, 103, 251, 404, 405, len(e)]
    parts = [spec.part(a, b) for a, b in zip(bounds[:-1], bounds[1:])]
    pieces = [p for p, _taken in iter_run_parts(PlanContext.of(kossel, "feed"), iter(parts))]
    assert len(pieces) >= 3
    assert sum(p.filament_total for p in pieces) == pytest.approx(e.sum(), rel=1e-9)
    whole = plan_run(PlanContext.of(kossel, "feed"), spec)
    assert sum(p.duration for p in pieces) == pytest.approx(sum(p.duration for p in whole), rel=1e-3)


def _spiral_chunks(n: int, chunk: int, per_turn: int = 200):
    """A spiral vase of n moves made chunk by chunk (never whole), as open_gcode hands one over."""
    layer_z = 0.3 + 0.2 * np.arange(n // per_turn + 1)
    start = np.array([20.0, 0.0, 0.3])
    for a in range(0, n, chunk):
        k = np.arange(a + 1, min(a + chunk, n) + 1)
        th = 2 * np.pi * k / per_turn
        r = 20 + 0.5 * np.sin(25 * th)
        xyz = np.c_[r * np.cos(th), r * np.sin(th), 0.3 + 0.2 * k / per_turn]
        steps = np.linalg.norm(np.diff(np.vstack([start, xyz]), axis=0), axis=1)
        m = len(k)
        yield Toolpath(start, xyz, np.full(m, 30.0), 0.03 * steps, np.ones(m), np.full(m, 2, np.uint8),
                       ((k - 1) // per_turn).astype(np.int32), layer_z)
        start = xyz[-1]


def test_planning_a_stream_holds_a_few_chunks_whatever_its_length(kossel, small_windows, monkeypatch):
    """What plan_stream holds at its peak (tracemalloc) does not grow with the print: a spiral of
    3,000 moves and one of 12,000, handed over 500 at a time, its one run planned in parts. Held
    whole (a run gathered until it ends) it grows by about 80 bytes a move; here by none."""
    monkeypatch.setattr(planning.jobs, "STREAM_RUN", 600)
    peaks = []
    for n in (3000, 3000, 12000):  # the first warms the caches up
        tracemalloc.start()
        traj = plan_stream(_spiral_chunks(n, 500), kossel, moves=n, workers=1)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert traj.piece_counts()["run"] >= n // 250
        del traj
    assert (peaks[2] - peaks[1]) / 9000 < 15, peaks


def test_reading_a_stream_holds_a_chunk_whatever_the_files_length(tmp_path, kossel, monkeypatch):
    """open_gcode and its chunks hold a chunk, not the file: read whole, the moves take about 100
    bytes each at the peak; a stream's peak grows by none. (The line count is taken a block of
    SCAN_BLOCK bytes at a time, 1 MB, smaller here than these files.)"""
    monkeypatch.setattr(gcode_mod, "SCAN_BLOCK", 4096)
    peaks = []
    for turns in (10, 10, 40):
        path = tmp_path / f"s{turns}.gcode"
        path.write_text(spiral_text(turns))
        tracemalloc.start()
        with open_gcode(path, printer=kossel, chunk=500) as stream:
            n = sum(len(c) for c in stream.chunks())
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert n == stream.moves == 200 * turns + 2
    assert (peaks[2] - peaks[1]) / 6000 < 15, peaks


def test_plan_stream_refuses_chunks_that_do_not_follow_on_and_names_an_unreachable_layer(kossel):
    chunks = list(_spiral_chunks(400, 100))
    gap = Toolpath(chunks[1].start + 1.0, chunks[1].xyz, chunks[1].feed, chunks[1].e, chunks[1].tool, chunks[1].role,
                   chunks[1].layer, chunks[1].layer_z)
    with pytest.raises(DeltasliceError, match="starts at"):
        plan_stream([chunks[0], gap], kossel, workers=1)
    with pytest.raises(DeltasliceError, match="no moves"):
        plan_stream(iter(()), kossel, workers=1)
    with pytest.raises(DeltasliceError, match="expected Toolpaths"):
        plan_stream([chunks[0], "G1 X0"], kossel, workers=1)
    far = chunks[2].xyz.copy()
    far[5:, 0] += 500.0
    bad = Toolpath(chunks[2].start, far, chunks[2].feed, chunks[2].e, chunks[2].tool, chunks[2].role, chunks[2].layer,
                   chunks[2].layer_z)
    with pytest.raises(UnreachableError, match="layer 1"):
        plan_stream(chunks[:2] + [bad], kossel, workers=1)


def _laser_text(typed_from: int, moves: int = 60) -> str:
    """Laser G-code (M3, power S per move) whose moves from ``typed_from`` on follow a ;TYPE:
    comment (a slicer's file after its intro line): roles Perimeter, not Laser, before them Laser."""
    out = ["G21", "G90", ";LAYER_CHANGE", ";Z:0.0", "G0 X0 Y0 Z0", "M3 S500", "G1 F1500"]
    for i in range(1, moves + 1):
        if i == typed_from:
            out.append(";TYPE:Perimeter")
        out.append(f"G1 X{(i % 2) * 10} Y{i * 0.2:.2f} S{100 + 10 * i}")
    return "\n".join(out + ["M5", "G0 X0 Y0"]) + "\n"


@pytest.mark.parametrize("stream_run", [20, 10**9])
def test_a_lasers_runs_are_its_tool_channels_not_its_moves_roles(tmp_path, monkeypatch, full_batches, stream_run):
    """On a laser a run goes on through power changes (its power per move), whether its moves have
    a laser role or a slicer's ;TYPE: role: a chunk holding only ;TYPE: moves is split, and planned,
    as the whole file is (it was cut at every power change, and a run in parts that crossed the
    comment failed to join its parts)."""
    laser = load_printer("delta_espe_laser")
    monkeypatch.setattr(planning.jobs, "STREAM_RUN", stream_run)
    path = tmp_path / "l.gcode"
    path.write_text(_laser_text(typed_from=30))
    tp = read_gcode(path, printer=laser)
    assert {int(r) for r in np.unique(tp.role[tp.working])} == {8, 2}  # Laser and Perimeter moves
    assert len(planning.split_runs(tp, laser=True)) == 1
    whole = plan(tp, laser, workers=1)
    with open_gcode(path, printer=laser, chunk=10) as stream:
        traj = plan_stream(stream.chunks(), laser, moves=stream.moves, workers=1)
    assert traj.piece_counts() == whole.piece_counts()
    if stream_run > 60:
        assert traj.duration == whole.duration
    else:
        assert traj.duration == pytest.approx(whole.duration, rel=1e-3)
    runs = [p for p in whole.pieces if p.kind == "run"]
    assert len(runs) == 1 and runs[0].power is not None  # the power per move, not the first move's


def test_a_stream_taken_whole_holds_what_reading_the_file_whole_holds(tmp_path):
    """A file that is not streamed (read with --center) is taken whole from the temporary file a
    column at a time: its peak is read_gcode's (the columns once), not the blocks and their
    concatenation at once."""
    path = tmp_path / "s.gcode"
    path.write_text(spiral_text(100))
    peaks = {}
    for kind in ("read", "whole", "read", "whole"):  # the first two warm up
        tracemalloc.start()
        if kind == "read":
            tp = read_gcode(path, center=True)
        else:
            with open_gcode(path, chunk=1000, center=True) as stream:
                assert not stream.streamed
                tp = stream.whole()
        peaks[kind] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert len(tp) == 20002
    assert peaks["whole"] < 1.1 * peaks["read"], peaks


def test_concatenate_renumbers_layers_and_then_keeps_them(tmp_path, kossel):
    """Both join moves and re-index events; concatenate's parts are separate prints (their layers
    follow each other), then's a print's consecutive stretches (its layers kept)."""
    path = tmp_path / "part.gcode"
    path.write_text(prusa_like(layers=3))
    tp = read_gcode(path, printer=kossel)
    half = int(np.flatnonzero(tp.events["index"] > 0)[0])  # an event in the second half, too
    a, b = tp.subset(slice(0, int(tp.events["index"][half]) - 1)), tp.subset(slice(int(tp.events["index"][half]) - 1, None))
    same_toolpath(a.then(b), tp)
    both = Toolpath.concatenate([tp, tp])
    assert len(both) == 2 * len(tp) and np.array_equal(both.layer_z, np.concatenate([tp.layer_z, tp.layer_z]))
    assert np.array_equal(both.layer, np.concatenate([tp.layer, tp.layer + len(tp.layer_z)]))
    assert both.layer.dtype == tp.layer.dtype
    assert np.array_equal(both.events["index"], np.concatenate([tp.events["index"], tp.events["index"] + len(tp)]))
    with pytest.raises(DeltasliceError, match="starts at"):
        b.then(a)
