"""Binary stream and setpoints CSV: round trips, corruption, atomic writes, size."""

from __future__ import annotations

import io
import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from streamtools import block_sample_counts, record_offsets
from trajectories import ROOT, blocks, printer, realistic

from deltaslice.formats import format_for
from deltaslice.pipeline import read_output, write_samples
from deltaslice.emit import stream
from deltaslice.pipeline import decode_stream, read_counts
from deltaslice.errors import DeltasliceError, StreamError
from deltaslice.samples import Samples, to_counts


@pytest.fixture(scope="module")
def etitc():
    s, _tp = realistic("delta_etitc", layers=2)
    return printer("delta_etitc"), s


@pytest.fixture(scope="module")
def etitc_files(etitc, tmp_path_factory):
    p, s = etitc
    d = tmp_path_factory.mktemp("out")
    meta = {"planner": "synthetic", "speed_limit": "feed"}
    dsl, csv = d / "part.dsl", d / "part.csv"
    n_dsl = write_samples(blocks(s, 3000), p, dsl, fmt="stream", rate=1000.0, metadata=meta)
    n_csv = write_samples(blocks(s, 3000), p, csv, fmt="csv", rate=1000.0, metadata=meta)
    assert n_dsl == dsl.stat().st_size and n_csv == csv.stat().st_size
    return dsl, csv


def _decoded_prefix(path) -> tuple[np.ndarray, Exception | None]:
    f = open(path, "rb")
    reader = stream.StreamReader(f, str(path))
    got, err = [], None
    with f:
        try:
            for _i, _first, c in reader.blocks():
                got.append(c)
        except StreamError as exc:
            err = exc
    return (np.concatenate(got) if got else np.zeros((0, 4), np.int64)), err


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("name", ["delta_etitc", "linear_kossel", "fivebar_atlas", "delta_espe_laser"])
def test_counts_are_numpys_rounding_half_to_even(name):
    """The compiled per-block counts (joints and tool channel given apart) are numpy's
    rint(zero + cpu * value), half-way values included, and Limits.to_counts gives the same."""
    p = printer(name)
    lim, J = p.limits, p.n_joints
    rng = np.random.default_rng(2)
    values = rng.uniform(-2, 2, (300, J + 1)) / lim.counts_per_unit[None]
    values[:40] = (np.arange(40)[:, None] - 20 + 0.5 - lim.zero_count[None]) / lim.counts_per_unit[None]  # k + 1/2 counts
    want = np.rint(lim.counts_per_unit[None] * values + lim.zero_count[None]).astype(np.int64)
    assert np.array_equal(lim.joint_and_channel_counts(values[:, :J], values[:, J]), want)
    assert np.array_equal(lim.to_counts(values), want)
    assert np.array_equal(lim.to_counts(values[0]), want[:1])  # one row
    for bad in (values[:, :J], np.hstack([values, values])):  # a channel short, or too many: refused
        with pytest.raises(ValueError, match="channels"):
            lim.to_counts(bad)


@pytest.mark.parametrize("name", ["delta_etitc", "linear_kossel", "fivebar_atlas", "delta_espe_laser"])
def test_stream_round_trip_exact_in_counts(name, tmp_path):
    p = printer(name)
    s, _ = realistic(name, layers=1)
    out = tmp_path / "x.dsl"
    write_samples(blocks(s, 1777), p, out, fmt="stream", rate=p.planning.output_rate, metadata={"planner": "t"})
    header, counts = read_counts(out)
    assert np.array_equal(counts, to_counts(p, s))
    assert header.fingerprint == p.fingerprint() and header.printer_name == p.name
    assert header.rate == p.planning.output_rate and header.metadata == {"planner": "t"}
    kinds = [c.kind_name for c in header.channels]
    assert kinds[-1] == ("laser" if p.is_laser else "extruder")
    assert kinds[:-1] == [j.kind for j in p.joints]


def test_csv_round_trip(etitc, etitc_files):
    p, s = etitc
    meta, back = read_output(etitc_files[1])
    assert meta["printer"] == p.name and meta["planner"] == "synthetic" and meta["rate_hz"] == "1000"
    assert meta["fingerprint"] == f"0x{p.fingerprint():08x}"
    assert len(back) == len(s)
    assert np.abs(back.q - s.q).max() < 1e-9
    assert np.abs(back.e - s.e).max() < 1e-9
    assert np.abs(back.t - s.t).max() < 1e-9
    assert np.array_equal(back.tool, s.tool)


def test_read_output_stream_in_units(etitc, etitc_files):
    p, s = etitc
    meta, back = read_output(etitc_files[0])
    assert meta["format"] == "stream" and meta["planner"] == "synthetic"
    step = 1.0 / p.limits.counts_per_unit[:p.n_joints]
    assert np.all(np.abs(back.q - s.q) <= 0.5 * step + 1e-12)
    assert np.abs(back.e - s.e).max() <= 0.5 / p.tool.counts_per_mm + 1e-12


def test_decode_counts_text(etitc, etitc_files):
    p, s = etitc
    buf = io.StringIO()
    n = decode_stream(etitc_files[0], buf)
    assert n == len(s)
    lines = buf.getvalue().splitlines()
    counts = to_counts(p, s)
    assert lines[0] == "0 " + " ".join(map(str, counts[0]))
    assert lines[12345] == "12345 " + " ".join(map(str, counts[12345]))
    assert len(lines) == len(s)


def test_decode_units_equals_csv_within_quantisation(etitc, etitc_files):
    p, _s = etitc
    out = subprocess.run(
        [sys.executable, "-m", "deltaslice", "decode", str(etitc_files[0]), "--units"],
        capture_output=True, text=True, cwd=ROOT, check=True,
    ).stdout.splitlines()
    ref = etitc_files[1].read_text().splitlines()
    assert len(out) == len(ref)
    n_head = next(i for i, line in enumerate(ref) if line.startswith("t,"))
    assert out[: n_head + 1] == ref[: n_head + 1]  # comments and header row identical
    a = np.array([[float(v) for v in line.split(",")] for line in out[n_head + 1 :]])
    b = np.array([[float(v) for v in line.split(",")] for line in ref[n_head + 1 :]])
    assert np.abs(a[:, 0] - b[:, 0]).max() < 1e-9
    q_tol = 0.5 / p.limits.counts_per_unit[:p.n_joints] + 1e-9
    assert np.all(np.abs(a[:, 1:4] - b[:, 1:4]) <= q_tol)
    assert np.abs(a[:, 4] - b[:, 4]).max() <= 0.5 / p.tool.counts_per_mm + 1e-9
    # the extruder's on/off column is derived from the filament counts (see the spec): on exactly
    # where the filament count rose since the previous sample
    rose = np.concatenate([[False], np.diff(np.rint(a[:, 4] * p.tool.counts_per_mm)) > 0])
    assert set(np.unique(a[:, 5])) == {0.0, 1.0}
    assert np.array_equal(a[:, 5] == 1.0, rose)


def test_decode_refuses_other_printer(etitc_files):
    with pytest.raises(StreamError, match="compiled for printer 'delta_etitc'"):
        decode_stream(etitc_files[0], io.StringIO(), units=True, printer=ROOT / "printers/linear_kossel.toml")


# --------------------------------------------------------------------------- damage


def test_corrupt_block_is_named_and_none_of_its_samples_escape(etitc, etitc_files, tmp_path):
    p, s = etitc
    data = bytearray(etitc_files[0].read_bytes())
    recs = [r for r in record_offsets(bytes(data)) if r[2] == stream.REC_BLOCK]
    per_block = block_sample_counts(bytes(data))
    k = 7
    off, length, _ = recs[k]
    data[off + length // 2] ^= 0x10
    bad = tmp_path / "bad.dsl"
    bad.write_bytes(bytes(data))
    got, err = _decoded_prefix(bad)
    assert err is not None and f"block {k} at byte offset {off}" in str(err) and "CRC" in str(err)
    assert np.array_equal(got, to_counts(p, s)[: sum(per_block[:k])])
    buf = io.StringIO()
    with pytest.raises(StreamError, match=f"block {k} "):
        decode_stream(bad, buf)
    assert len(buf.getvalue().splitlines()) == sum(per_block[:k])


@pytest.mark.parametrize("where", ["header", "mid_block", "before_end", "in_end", "one_short"])
def test_truncated_stream(etitc, etitc_files, tmp_path, where):
    p, s = etitc
    data = etitc_files[0].read_bytes()
    recs = record_offsets(data)
    cut = {
        "header": 20,
        "mid_block": recs[3][0] + 10,
        "before_end": recs[-1][0],
        "in_end": recs[-1][0] + 6,
        "one_short": len(data) - 1,
    }[where]
    bad = tmp_path / "cut.dsl"
    bad.write_bytes(data[:cut])
    if where == "header":
        with pytest.raises(StreamError, match="truncated"):
            with open(bad, "rb") as f:
                stream.StreamReader(f, str(bad))
        return
    got, err = _decoded_prefix(bad)
    assert err is not None and "truncated" in str(err)
    assert np.array_equal(got, to_counts(p, s)[: len(got)])


def test_wrong_magic_and_corrupt_header(etitc_files, tmp_path):
    data = bytearray(etitc_files[0].read_bytes())
    bad = tmp_path / "magic.dsl"
    bad.write_bytes(b"PK\x03\x04" + bytes(data[4:]))
    with pytest.raises(StreamError, match="not a deltaslice stream"):
        read_counts(bad)
    data[30] ^= 1
    bad.write_bytes(bytes(data))
    with pytest.raises(StreamError, match="header CRC"):
        read_counts(bad)


def test_end_record_checks(etitc_files, tmp_path):
    data = etitc_files[0].read_bytes()
    bad = tmp_path / "tail.dsl"
    bad.write_bytes(data + b"\0")
    with pytest.raises(StreamError, match="after the end record"):
        read_counts(bad)
    recs = record_offsets(data)
    # drop one whole block: every block is fine, but the end record disagrees
    off, length, _ = recs[2]
    bad.write_bytes(data[:off] + data[off + length :])
    with pytest.raises(StreamError, match="end record counts"):
        read_counts(bad)


def test_atomic_write_leaves_nothing_on_failure(etitc, tmp_path):
    p, s = etitc

    def failing():
        yield from blocks(s, 5000)
        raise RuntimeError("planner died")

    for fmt, name in (("stream", "x.dsl"), ("csv", "x.csv")):
        with pytest.raises(RuntimeError):
            write_samples(failing(), p, tmp_path / name, fmt=fmt, rate=1000.0)
        assert os.listdir(tmp_path) == []
    # an existing output survives a failed run untouched
    keep = tmp_path / "keep.dsl"
    keep.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        write_samples(failing(), p, keep, fmt="stream", rate=1000.0)
    assert keep.read_bytes() == b"old" and os.listdir(tmp_path) == ["keep.dsl"]


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 300), st.integers(0, 10**7), st.sampled_from([1000.0, 250.0, 3.0e4]),
       st.lists(st.tuples(st.integers(0, 299), st.sampled_from([1e-9, -3e-6, 0.5, np.nan, np.inf])), max_size=3))
def test_time_base_offset_is_numpys(n, n0, rate, errors):
    """The writer's one-pass time-base check gives numpy's max |t - (n0 + k) / rate|, NaN where
    numpy's is (a NaN anywhere), exactly."""
    t = (n0 + np.arange(n)) / rate
    for i, err in errors:
        t[i % n] += err
    expect = np.abs(t - (n0 + np.arange(n)) / rate).max()
    got = stream._time_base_offset(t, n0, rate)
    assert (np.isnan(got) and np.isnan(expect)) or got == expect


def test_writer_refuses_bad_samples(etitc, tmp_path):
    p, s = etitc
    squeezed = Samples(s.t * 0.999, s.q, s.e, s.tool)
    with pytest.raises(StreamError, match="uniformly spaced"):
        write_samples([squeezed], p, tmp_path / "a.dsl", fmt="stream", rate=1000.0)
    # the first sample off the grid, counted across blocks, with the time it should have
    late = s.t.copy()
    late[[250, 300]] += 2e-6
    blocks = [Samples(s.t[:200], s.q[:200], s.e[:200], s.tool[:200]), Samples(late[200:], s.q[200:], s.e[200:], s.tool[200:])]
    with pytest.raises(StreamError, match=r"sample 250: t = 0\.250002000 s, expected 0\.250000000 s"):
        write_samples(blocks, p, tmp_path / "a.dsl", fmt="stream", rate=1000.0)
    q = s.q.copy()
    q[100, 1] = np.nan
    q[90, 0] = np.inf
    e = s.e.copy()
    e[50] = np.nan  # t, q, e, tool are checked in that order: q's first row is named
    for fmt in ("stream", "csv"):
        with pytest.raises(StreamError, match="sample 90: non-finite q"):
            write_samples([Samples(s.t, q, e, s.tool)], p, tmp_path / f"a.{fmt}", fmt=fmt, rate=1000.0)
        with pytest.raises(StreamError, match="sample 50: non-finite e"):
            write_samples([Samples(s.t, s.q, e, s.tool)], p, tmp_path / f"a.{fmt}", fmt=fmt, rate=1000.0)
        t = s.t.copy()
        t[70] = np.nan
        with pytest.raises(StreamError, match="sample 70: non-finite t"):
            write_samples([Samples(t, q, e, s.tool)], p, tmp_path / f"a.{fmt}", fmt=fmt, rate=1000.0)
    # a joint beyond what a count can hold (the player's int32 arithmetic)
    far = s.q.copy()
    far[[120, 130], 2] = 1e9
    with pytest.raises(StreamError, match=r"sample 120: actuator count \[.*\] beyond \+-2\^29"):
        write_samples([Samples(s.t, far, s.e, s.tool)], p, tmp_path / "a.dsl", fmt="stream", rate=1000.0)
    # so large that its count is -2^63, which np.abs leaves negative
    far[110, 0] = 1e30
    with pytest.raises(StreamError, match=r"sample 110: actuator count \[-9223372036854775808, .*\] beyond \+-2\^29"):
        write_samples([Samples(s.t, far, s.e, s.tool)], p, tmp_path / "a.dsl", fmt="stream", rate=1000.0)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("sign", [1, -1])
def test_writer_takes_counts_up_to_the_limit_and_refuses_one_more(etitc, tmp_path, sign):
    """The writer's check is the counts pass's largest magnitude (below COUNT_LIMIT - 1/2): a
    count of +-(COUNT_LIMIT - 1) is written and read back, +-COUNT_LIMIT is refused, whichever
    channel (a joint or the tool channel) holds it."""
    p, s = etitc
    cpu, zero = p.limits.counts_per_unit, p.limits.zero_count
    J = p.n_joints
    for c in (1, J):
        for offset, ok in ((-1.2, True), (-0.8, True), (-0.3, False), (0.4, False)):
            target = sign * (stream.COUNT_LIMIT + offset)  # offset -0.8 rounds to COUNT_LIMIT - 1
            q, e = s.q.copy(), s.e.copy()
            value = (target - zero[c]) / cpu[c]
            if c < J:
                q[40, c] = value
            else:
                e[40:] = value  # the filament position, held
            block = Samples(s.t, q, e, s.tool)
            out = tmp_path / f"a{c}{offset}.dsl"
            if ok:
                write_samples([block], p, out, fmt="stream", rate=1000.0)
                assert np.array_equal(read_counts(out)[1], to_counts(p, block))
                assert abs(to_counts(p, block)[40, c]) == stream.COUNT_LIMIT - 1
            else:
                with pytest.raises(StreamError, match=r"sample 40: actuator count \[.*\] beyond \+-2\^29"):
                    write_samples([block], p, out, fmt="stream", rate=1000.0)


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=4, max_size=40))
@settings(max_examples=200, deadline=None)
def test_counts_peak_against_numpy(values):
    """joint_and_channel_counts' peak: the largest |zero + cpu * value|, NaN when any is not finite;
    its counts numpy's rint where every value is finite."""
    p = printer("delta_etitc")
    lim = p.limits
    n = len(values) // 4
    v = np.array(values[: 4 * n], dtype=float).reshape(n, 4)
    with np.errstate(all="ignore"):
        scaled = lim.counts_per_unit[None] * v + lim.zero_count[None]
        counts, peak = lim.joint_and_channel_counts(v[:, :3], v[:, 3], with_peak=True)
    if np.isfinite(scaled).all():
        assert peak == np.abs(scaled).max()
        small = np.abs(scaled) < 2.0**62
        assert np.array_equal(counts[small], np.rint(scaled[small]).astype(np.int64))
    else:
        assert np.isnan(peak)


@pytest.mark.parametrize("count", [stream.COUNT_LIMIT, -stream.COUNT_LIMIT, -(2**63), 2**63 - 1])
def test_block_codec_refuses_counts_beyond_the_limit(count):
    """Counts at +-2^29 and beyond are refused before any is encoded, -2^63 too (its np.abs is
    negative: it passed the check and made a record that decodes to zeros, or never ended)."""
    x = np.array([[0, 5], [count, 5], [0, 5]], dtype=np.int64)
    with pytest.raises(StreamError, match="beyond"):
        stream.encode_blocks(x)
    assert stream.encode_blocks(np.clip(x, -(stream.COUNT_LIMIT - 1), stream.COUNT_LIMIT - 1))


def test_format_for():
    assert format_for("a/part.CSV") == "csv"
    assert format_for("part.dsl") == "stream" and format_for("part.stream") == "stream"
    assert format_for("part.gcode") == "gcode"
    with pytest.raises(DeltasliceError, match="--format"):
        format_for("part.bin")


# --------------------------------------------------------------------------- size


def test_bytes_per_sample_within_budget(etitc, etitc_files):
    p, s = etitc
    size = etitc_files[0].stat().st_size
    csv_size = etitc_files[1].stat().st_size
    per = size / len(s)
    assert p.n_joints + 1 == 4
    assert per <= 4.0, f"stream uses {per:.3f} bytes/sample for 4 channels at 1 kHz (budget 4)"
    assert per < 1.5, f"stream uses {per:.3f} bytes/sample; measured 0.95 when this test was written"
    assert csv_size / size > 50, f"CSV {csv_size / len(s):.1f} B/sample vs stream {per:.3f}"
    assert max(block_sample_counts(etitc_files[0].read_bytes())) <= stream.BLOCK_SAMPLES
    assert max(r[1] for r in record_offsets(etitc_files[0].read_bytes())) <= stream.MAX_RECORD


# --------------------------------------------------------------------------- codec properties


@st.composite
def count_arrays(draw):
    n = draw(st.integers(1, 700))
    c = draw(st.integers(1, stream.MAX_CHANNELS))
    kind = draw(st.sampled_from(["random", "smooth", "constant", "spiky"]))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    lim = stream.COUNT_LIMIT - 1
    if kind == "random":
        scale = draw(st.sampled_from([1, 3, 1000, lim]))
        x = rng.integers(-scale, scale + 1, size=(n, c))
    elif kind == "smooth":
        acc = rng.normal(0, draw(st.sampled_from([0.01, 1.0, 50.0])), size=(n, c))
        x = np.rint(np.cumsum(np.cumsum(acc, 0), 0)) + rng.integers(-1000, 1000, size=c)
    elif kind == "constant":
        x = np.broadcast_to(rng.integers(-lim, lim, size=c), (n, c))
    else:
        x = np.zeros((n, c), np.int64)
        idx = rng.integers(0, n, size=3)
        x[idx] = rng.choice([-lim, lim], size=(3, c))
    return np.clip(np.asarray(x, np.int64), -lim, lim)


@settings(max_examples=150, deadline=None)
@given(count_arrays())
def test_block_codec_round_trip(x):
    recs = stream.encode_blocks(x)
    assert all(len(r) <= stream.MAX_RECORD for r in recs)
    back = np.concatenate([stream.decode_block(r, x.shape[1]) for r in recs])
    assert np.array_equal(back, x)


def _records_sized_from_scratch(x, block_samples, max_record):
    """The records of counts x as the encoder cuts them, every range measured on its own (its
    ors from its rows, no half measured with its block): the reference the encoder's one pass
    over a block and its halves must equal byte for byte."""
    nch = x.shape[1]
    order, width, v0 = (np.empty(nch, np.int64) for _ in range(3))
    ored = np.empty((2, nch), np.int64)
    out = []
    for first in range(0, len(x), block_samples):
        todo = [(first, min(first + block_samples, len(x)))]
        while todo:
            a, b = todo.pop()
            stream._ors(x, a, b, ored)
            size = stream._sized(x, a, b, True, True, order, width, v0, ored)
            if size > max_record:
                assert b - a > 1
                m = (a + b) // 2
                todo += [(m, b), (a, m)]
                continue
            buf = np.zeros(size, np.uint8)
            stream._write_record(x, a, b, order, width, v0, size, buf, 0)
            out.append(buf[: size - 4].tobytes())  # the CRC is the caller's
    return out


@settings(max_examples=150, deadline=None)
@given(count_arrays(), st.sampled_from([1, 2, 3, 4, 5, 7, 8, 64, 512]), st.sampled_from([40, 64, 100, 200, 512]))
def test_block_records_equal_ranges_sized_from_scratch(x, block_samples, max_record):
    """The encoder measures a nominal block's two halves in the pass that measures the block (most
    blocks are halved once): its records are byte for byte those of every range measured on its
    own, whether a block fits, is halved, or halved again, for blocks of 1 to 3 rows (not split)
    and more."""
    x = np.ascontiguousarray(x)
    try:
        recs = stream.encode_blocks(x, block_samples=block_samples, max_record=max_record)
    except stream.StreamError:  # one sample does not fit: the reference cannot cut it either
        with pytest.raises(AssertionError):
            _records_sized_from_scratch(x, block_samples, max_record)
        return
    assert [r[:-4] for r in recs] == _records_sized_from_scratch(x, block_samples, max_record)


@pytest.mark.parametrize("rows", range(2, 19))
def test_block_codec_keeps_the_last_partial_byte(rows):
    """The residual bits end in a partial byte whose set bits are the block's last residual:
    rows of 2 + w bits (w odd: every end position in a byte, one bit past a byte included) over
    1..17 residuals decode to what was encoded."""
    for width in (1, 3, 7, 29):
        x = np.zeros((rows, 2), dtype=np.int64)
        x[-1] = [1, -(2 ** (width - 1))]  # two bits, then w whose top one, the last bit written, is set
        back = stream.decode_block(stream.encode_block(x), 2)
        assert np.array_equal(back, x), width


def test_block_codec_widest_residuals_at_every_bit_offset():
    """Second differences of counts swinging between +-(COUNT_LIMIT - 1) take the widest
    residual (32 bits), after a channel of 0 or of 2 to 30 bits ((1 << w) // 2 zig-zags to w + 1
    bits): across the rows the packer holds every number of bits from 0 to 31 when one is added,
    and the 64-bit accumulator must not overflow at any."""
    lim = stream.COUNT_LIMIT - 1
    n = 70
    swing = np.where(np.arange(n) % 2 == 0, lim, -lim)
    for w in range(30):
        small = np.where(np.arange(n) % 4 < 2, 0, (1 << w) // 2)
        x = np.column_stack([small, swing]).astype(np.int64)
        (rec,) = stream.encode_blocks(x, block_samples=n, max_record=0xFFFF, orders=(2,))
        assert np.array_equal(stream.decode_block(rec, 2), x), w


@given(st.lists(st.integers(-(2**62), 2**62), min_size=1, max_size=50))
def test_zigzag_round_trip(values):
    v = np.array(values, dtype=np.int64)
    u = stream.zigzag(v)
    assert np.array_equal(stream.unzigzag(u), v)
    assert all(int(a) == stream._zz1(int(b)) for a, b in zip(u, v))


def test_write_trajectory_uses_the_planner_interface(etitc, tmp_path):
    from deltaslice.pipeline import write_output

    p, s = etitc

    class FakeTrajectory:
        printer = p
        duration = float(s.t[-1])

        def iter_samples(self, rate):
            assert rate == p.planning.output_rate
            return blocks(s, 4000)

        def metadata(self):
            return {"planner": "toppra", "speed_limit": "feed"}

    for name in ("part.dsl", "part.csv"):
        size = write_output(FakeTrajectory(), tmp_path / name)
        assert size == (tmp_path / name).stat().st_size
        meta, back = read_output(tmp_path / name)
        assert meta["planner"] == "toppra" and meta["duration_s"] == f"{s.t[-1]:.6f}" and len(back) == len(s)
    size = write_output(FakeTrajectory(), tmp_path / "forced.out", fmt="csv")
    assert (tmp_path / "forced.out").read_text().startswith("# deltaslice setpoints v1")
