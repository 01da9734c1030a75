"""Hypothesis over the library API and the readers: whatever the input, the only exceptions
are the DeltasliceError family (issue 15)."""

from __future__ import annotations

import copy
import re
import tomllib

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from deltaslice import DeltasliceError
from deltaslice.emit import read_output
from deltaslice.emit.stream import MAGIC, parse_header
from deltaslice.gcode import read_gcode
from deltaslice.machine import printer_from_dict
from deltaslice.toolpath import Toolpath, ToolpathBuilder

from conftest import PRINTER_DIR

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

anything = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**20), 10**20), st.floats(allow_nan=True, allow_infinity=True),
    st.complex_numbers(), st.text(max_size=8), st.lists(st.floats(), max_size=4),
    st.lists(st.lists(st.floats(-1e3, 1e3), min_size=0, max_size=4), max_size=3),
)


def _only_family(fn, *args, **kwargs):
    try:
        fn(*args, **kwargs)
    except DeltasliceError:
        pass


# a Python exception's name in a message (ValueError, StopIteration, BadZipFile): the problem is said instead
PYTHON_NAMES = re.compile(r"\b[A-Z]\w*(Error|Exception)\b|StopIteration|BadZipFile")


def _only_family_in_words(fn, *args, **kwargs):
    """The family only, and its message names no Python exception."""
    try:
        fn(*args, **kwargs)
    except DeltasliceError as exc:
        assert not PYTHON_NAMES.search(str(exc)), str(exc)


@SETTINGS
@given(xyz=anything, feed=anything, e=anything, tool=anything, role=anything)
def test_builder_add_raises_only_the_family(xyz, feed, e, tool, role):
    def go():
        b = ToolpathBuilder()
        b.new_layer(0.4)
        b.add(xyz, feed, e, tool, role)
        b.build()

    _only_family(go)


@SETTINGS
@given(st.data())
def test_toolpath_fields_raise_only_the_family(data):
    n = data.draw(st.integers(0, 4))
    fields = dict(start=np.zeros(3), xyz=np.ones((n, 3)), feed=np.full(n, 10.0), e=np.zeros(n), tool=np.zeros(n),
                  role=np.full(n, 2), layer=np.zeros(n, int), layer_z=np.array([0.4]))
    name = data.draw(st.sampled_from(sorted(fields)))
    fields[name] = data.draw(anything)
    _only_family(Toolpath, **fields)


def _shipped(name):
    return tomllib.loads((PRINTER_DIR / f"{name}.toml").read_text())


SHIPPED = {p.stem: _shipped(p.stem) for p in PRINTER_DIR.glob("*.toml")}


@settings(max_examples=120, deadline=None)
@given(st.sampled_from(sorted(SHIPPED)), st.data())
def test_printer_reader_raises_only_the_family(name, data):
    d = copy.deepcopy(SHIPPED[name])
    section = data.draw(st.sampled_from([s for s in d if isinstance(d[s], dict) and s != "sources"]))
    key = data.draw(st.sampled_from(sorted(d[section]) + ["uper_arm", "extra"]))
    d[section][key] = data.draw(anything)
    _only_family(printer_from_dict, d, f"{name}.toml")


@SETTINGS
@given(st.binary(max_size=300))
def test_output_reader_raises_only_the_family(data):
    _only_family(read_output, data, "fuzz")
    _only_family(read_output, MAGIC + data, "fuzz")
    _only_family(parse_header, MAGIC + data, "fuzz")


@SETTINGS
@given(st.lists(st.sampled_from(["G1", "G0", "X", "Y", "Z", "E", "F", "1", "-", ".", "e9", "nan", " ", ";", "\n", "G92",
                                 "M82", "M83", "G91", "G90", "0.0001", "1e400", "inf", "T1", "G28",
                                 "G2", "G3", "I", "J", "R", "1e9", "200000"]), max_size=60))
def test_gcode_reader_raises_only_the_family(tmp_path_factory, tokens):
    path = tmp_path_factory.mktemp("g") / "f.gcode"
    path.write_text("".join(tokens))
    _only_family(read_gcode, path)


@settings(max_examples=60, deadline=None)
@given(scale=anything, rotate=anything, keep=anything)
def test_mesh_placement_arguments_raise_only_the_family(scale, rotate, keep):
    from deltaslice.mesh import load_mesh

    from conftest import ROOT

    _only_family(load_mesh, ROOT / "examples" / "parts" / "calibration_cube.stl", scale=scale, rotate_z=rotate,
                 keep_position=keep)


@settings(max_examples=80, deadline=None)
@given(rate=anything, fmt=anything, n=st.integers(0, 5), fill=st.floats(allow_nan=True, allow_infinity=True))
def test_verify_arguments_raise_only_the_family(rate, fmt, n, fill):
    from deltaslice.samples import Samples
    from deltaslice.verify import verify_samples

    from conftest import printer

    s = Samples(np.arange(n) / 1000.0, np.full((n, 3), fill), np.full(n, fill), np.full(n, fill))
    _only_family(verify_samples, s, printer("delta_etitc"), rate=rate, fmt=fmt)
    _only_family(verify_samples, s, printer("delta_etitc"), rate=1000.0, fmt="csv")


# ------------------------------------------------------------------------------------------------------
# The readers of untrusted files (issue 50): printer files with numbers no float holds, SVG and images,
# mesh files, streams whose CRCs are valid after the damage, setpoint CSVs. Whatever the bytes: the
# family only, and a stream decodes to at most 512 samples a block.

import io  # noqa: E402
import struct  # noqa: E402
import warnings  # noqa: E402
import zlib  # noqa: E402

from deltaslice.emit import stream as dsl  # noqa: E402

from conftest import ROOT  # noqa: E402
from streamtools import record_offsets  # noqa: E402

FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                       HealthCheck.too_slow])
huge = st.sampled_from([10**309, -(10**310), 7 * 10**400, 2**1100])  # drawn from a list: hypothesis is slow at such sizes


@FAST
@given(st.sampled_from(sorted(SHIPPED)), st.data())
def test_printer_numbers_no_float_holds_raise_only_the_family(name, data):
    d = copy.deepcopy(SHIPPED[name])
    section = data.draw(st.sampled_from([s for s in d if isinstance(d[s], dict) and s != "sources"]))
    key = data.draw(st.sampled_from(sorted(d[section]) + ["sensor_table"]))
    value = data.draw(st.one_of(huge, st.lists(huge, min_size=1, max_size=4),
                                st.tuples(huge, st.integers(0, 1)).map(lambda h: [[[0, 0], [h[0], 1]][::1 - 2 * h[1]]] * 4)))
    d[section][key] = value
    _only_family_in_words(printer_from_dict, d, f"{name}.toml", reach_checks=False)


_NUMBERS = st.one_of(st.sampled_from(["0", "10", "-5", "1e308", "-1e308", "1e-308", "nan", "inf", "1" + "0" * 320,
                                      "9" * 320, ".5", "1e", "--1", ""]), st.integers(-200, 200).map(str))
_NAMESPACES = st.sampled_from(['xmlns="http://www.w3.org/2000/svg"', "", 'xmlns="http://example.com/other"'])


@st.composite
def svg_documents(draw):
    n = _NUMBERS
    root = (f'<svg {draw(_NAMESPACES)} width="{draw(n)}" height="{draw(n)}"'
            + (f' viewBox="{draw(n)} {draw(n)} {draw(n)} {draw(n)}"' if draw(st.booleans()) else "") + ">")
    parts = []
    for _ in range(draw(st.integers(0, 3))):
        kind = draw(st.sampled_from(["path", "circle", "rect", "line", "g"]))
        stroke = ' stroke="black" fill="none"'
        if kind == "path":
            d = " ".join(draw(st.lists(st.one_of(st.sampled_from(list("MLQCAZHVmlqcazhv")), n), max_size=14)))
            parts.append(f'<path d="{d}"{stroke}/>')
        elif kind == "circle":
            parts.append(f'<circle cx="{draw(n)}" cy="{draw(n)}" r="{draw(n)}"{stroke}/>')
        elif kind == "rect":
            parts.append(f'<rect x="{draw(n)}" y="{draw(n)}" width="{draw(n)}" height="{draw(n)}"{stroke}/>')
        elif kind == "line":
            parts.append(f'<line x1="{draw(n)}" y1="{draw(n)}" x2="{draw(n)}" y2="{draw(n)}"{stroke}/>')
        else:
            parts.append(f'<g transform="scale({draw(n)}) translate({draw(n)})"><path d="M 0 0 L 10 10"{stroke}/></g>')
    text = root + "".join(parts) + "</svg>"
    if draw(st.booleans()):  # cut anywhere: not well-formed XML
        text = text[: draw(st.integers(0, len(text)))]
    return text


@FAST
@given(svg_documents())
def test_svg_reader_raises_only_the_family(tmp_path_factory, text):
    from deltaslice.engrave import engrave

    from conftest import printer

    path = tmp_path_factory.mktemp("svg") / "a.svg"
    path.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # numpy's overflow warnings were noise on stderr
        _only_family_in_words(engrave, path, printer("delta_espe_laser"))


def _mutated(data: bytes, draw) -> bytes:
    """A few byte flips, an insertion or a cut of ``data``."""
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        what = draw(st.sampled_from(["flip", "cut", "insert"]))
        i = draw(st.integers(0, max(0, len(out) - 1)))
        if what == "flip" and out:
            out[i] = draw(st.integers(0, 255))
        elif what == "cut":
            del out[i:]
        else:
            out[i:i] = draw(st.binary(min_size=1, max_size=8))
    return bytes(out)


def _image_bytes(fmt: str) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    grey = (np.add.outer(np.arange(24), np.arange(32)) * 4 % 256).astype(np.uint8)
    Image.fromarray(grey).save(buf, format=fmt)
    return buf.getvalue()


IMAGES = {ext: _image_bytes(fmt) for ext, fmt in (("png", "PNG"), ("bmp", "BMP"), ("jpg", "JPEG"), ("tif", "TIFF"))}


@FAST
@given(st.sampled_from(sorted(IMAGES)), st.sampled_from(["vector", "raster"]), st.data())
def test_image_reader_raises_only_the_family(tmp_path_factory, ext, mode, data):
    from deltaslice.engrave import engrave

    from conftest import printer

    path = tmp_path_factory.mktemp("img") / f"a.{ext}"
    path.write_bytes(_mutated(IMAGES[ext], data.draw))
    _only_family_in_words(engrave, path, printer("delta_espe_laser"), {"mode": mode, "width": 20.0})


def _mesh_files() -> dict:
    import zipfile

    import trimesh

    box = trimesh.creation.box((10, 10, 10))
    out = {ext: box.export(file_type=ext) for ext in ("stl", "obj", "off", "ply")}
    out["ascii.stl"] = box.export(file_type="stl_ascii")
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:  # a 3MF's parts, small enough to damage anywhere
        z.writestr("_rels/.rels", '<?xml version="1.0"?><Relationships xmlns="http://schemas.openxmlformats.org/'
                   'package/2006/relationships"><Relationship Target="/3D/3dmodel.model" Id="r0" Type="http://schemas.'
                   'microsoft.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>')
        z.writestr("3D/3dmodel.model", box.export(file_type="3mf") and zipfile.ZipFile(
            io.BytesIO(box.export(file_type="3mf"))).read("3D/3dmodel.model"))
    out["3mf"] = buf.getvalue()
    return {k: v.encode() if isinstance(v, str) else v for k, v in out.items()}


MESHES = _mesh_files()


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(sorted(MESHES)), st.data())
def test_mesh_readers_raise_only_the_family(tmp_path_factory, ext, data):
    from deltaslice.errors import MeshWarning
    from deltaslice.mesh import load_mesh

    path = tmp_path_factory.mktemp("mesh") / f"a.{ext.split('.')[-1]}"
    path.write_bytes(_mutated(MESHES[ext], data.draw))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MeshWarning)
        _only_family_in_words(load_mesh, path)


def _small_stream() -> bytes:
    from deltaslice.samples import Samples

    from conftest import printer

    p = printer("delta_etitc")
    t = np.arange(1500) / 1000.0
    q = np.radians(30.0 + 10.0 * np.sin(np.outer(t, [1.0, 2.0, 3.0])))
    buf = io.BytesIO()
    dsl.write_stream([Samples(t, q, 0.5 * t, np.ones_like(t))], p, buf, rate=1000.0)
    return buf.getvalue()


STREAM = _small_stream()


def _valid_crcs(data: bytes) -> bytes:
    """``data`` with every block CRC, the end record's sample count and both of its CRCs made right
    again: damage only the inner checks can find."""
    out = bytearray(data)
    total = 0
    try:
        records = record_offsets(bytes(out))
    except (struct.error, IndexError):
        return bytes(out)
    for off, length, kind in records:
        if kind == dsl.REC_BLOCK and 9 <= length and off + length <= len(out):
            total += struct.unpack_from("<H", out, off + 3)[0]
            struct.pack_into("<I", out, off + length - 4, zlib.crc32(bytes(out[off: off + length - 4])))
        elif kind == dsl.REC_END and off + dsl.END_LEN <= len(out):
            struct.pack_into("<II", out, off + 3, total & 0xFFFFFFFF, zlib.crc32(bytes(out[:off])))
            struct.pack_into("<I", out, off + 11, zlib.crc32(bytes(out[off: off + 11])))
    return bytes(out)


@FAST
@given(st.data())
def test_stream_reader_with_valid_crcs_raises_only_the_family_and_stays_bounded(data):
    """Damage inside the blocks (sample counts, mode bytes, first values, payload) with every CRC made
    valid again: a block may declare 65,535 samples of width 0 in 17 bytes."""
    from conftest import printer

    hlen = struct.unpack_from("<H", STREAM, 10)[0]
    body = bytearray(STREAM)
    blocks = [(off, length) for off, length, kind in record_offsets(STREAM) if kind == dsl.REC_BLOCK]
    for _ in range(data.draw(st.integers(1, 3))):
        off, length = data.draw(st.sampled_from(blocks))
        field = data.draw(st.sampled_from(["n", "byte"]))
        if field == "n":
            struct.pack_into("<H", body, off + 3, data.draw(st.sampled_from([0, 1, 513, 65535, data.draw(st.integers(0, 65535))])))
        else:
            body[data.draw(st.integers(off + 5, off + length - 5))] = data.draw(st.integers(0, 255))
    damaged = _valid_crcs(bytes(body))
    assert damaged[:hlen] == STREAM[:hlen]
    try:
        _meta, samples = dsl.read_stream(io.BytesIO(damaged), "fuzz")
        assert len(samples) <= dsl.MAX_BLOCK_SAMPLES * len(blocks)
    except DeltasliceError:
        pass
    _only_family_in_words(dsl.decode_to_text, io.BytesIO(damaged), io.StringIO(), units=True, printer=printer("delta_etitc"))


def _small_csv() -> bytes:
    from deltaslice.emit import csv as csvfmt

    t = np.arange(20) / 1000.0
    return (csvfmt.comment_lines("delta_etitc", 1, 1000.0, ["rad"] * 3, {})
            + csvfmt.format_rows(t, np.full((20, 3), 0.5), 0.1 * t, np.ones(20))).encode()


CSV = _small_csv()


@FAST
@given(st.data())
def test_csv_reader_raises_only_the_family(data):
    text = _mutated(CSV, data.draw)
    if data.draw(st.booleans()):  # a number no float holds, or none at all, in a row
        lines = text.split(b"\n")
        i = data.draw(st.integers(0, len(lines) - 1))
        lines[i] = lines[i].replace(b"0.5", data.draw(st.sampled_from([b"1" + b"0" * 400, b"nan", b"inf", b"", b"x"])))
        text = b"\n".join(lines)
    _only_family_in_words(read_output, text, "fuzz.csv")


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(moves=st.lists(st.tuples(st.sampled_from(["G1", "G0"]), st.sampled_from(["", " X5", " X1e6", " Y-10"]),
                                st.sampled_from(["", " E1", " E-2", " E200000", " E1e6", " E1e9", " E-1e9"])),
                      min_size=1, max_size=6))
def test_gcode_filament_of_any_size_raises_only_the_family_before_planning(tmp_path_factory, moves):
    path = tmp_path_factory.mktemp("g") / "f.gcode"
    path.write_text("G21\nG90\nM82\nG92 E0\n;LAYER:0\nG1 Z0.4 F600\n" + "".join(f"{c}{xy}{e} F1200\n" for c, xy, e in moves))
    try:
        tp = read_gcode(path)
    except DeltasliceError:
        return
    assert np.abs(tp.e).max(initial=0.0) <= 10_000.0 + 1e-9  # what reaches the planner is bounded
