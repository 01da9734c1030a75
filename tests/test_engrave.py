"""Laser engraving: images and SVG -> Toolpath -> planned trajectory, on images drawn here."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image, ImageDraw

from conftest import printer as shipped
from deltaslice import engrave as engrave_mod
from deltaslice.cli import main
from deltaslice.engrave import EngraveError, engrave, order_polylines, raster_powers
from deltaslice.planning import plan, split_runs
from deltaslice.toolpath import Role
from deltaslice.verify import verify_samples

ROOT = Path(__file__).resolve().parents[1]
ESPE = "delta_espe_laser"
PRINTER_FILE = str(ROOT / "printers" / f"{ESPE}.toml")
PX = 0.2  # mm per pixel at width 40 mm for the 200 px wide images below


def _shapes(path, ring=False):
    """200 x 100 px: a black rectangle (px 20..80) and a black disc (px 110..170), or a ring."""
    im = Image.new("L", (200, 100), 255)
    d = ImageDraw.Draw(im)
    d.rectangle([20, 20, 79, 79], fill=0)
    if ring:
        d.ellipse([110, 20, 169, 79], outline=0, width=12)
    else:
        d.ellipse([110, 20, 169, 79], fill=0)
    im.save(path)
    return path


def _mm_x(px):
    return -20.0 + px * PX


def _mm_y(py):
    return 10.0 - py * PX


def _runs_xy(tp):
    """xy of every burning run's moves (start point included): list of (k, 2)."""
    out = []
    for i, j in tp.runs():
        out.append(np.concatenate([tp.starts[i : i + 1], tp.xyz[i:j]])[:, :2])
    return out


def _speed(samples, kin, rate):
    p = kin.forward(samples.q)
    return np.linalg.norm(np.gradient(p, 1.0 / rate, axis=0), axis=1), p


# --------------------------------------------------------------------------- vector


def test_vector_contours_number_and_bounds(tmp_path):
    tp = engrave(_shapes(tmp_path / "a.png"), shipped(ESPE), {"width": 40.0})
    runs = _runs_xy(tp)
    assert len(runs) == 2
    assert set(np.unique(tp.role[tp.working])) == {int(Role.LASER_DYNAMIC)}
    boxes = sorted((r.min(axis=0).tolist() + r.max(axis=0).tolist()) for r in runs)
    # rectangle: pixels 20..79 -> edges at px 20 and 80; disc: 110..170 (Canny rings lie within ~1.5 px)
    want = [
        [_mm_x(20), _mm_y(80), _mm_x(80), _mm_y(20)],
        [_mm_x(110), _mm_y(170 - 90), _mm_x(170), _mm_y(20)],
    ]
    assert np.allclose(boxes, want, atol=1.5 * PX + 0.05), (boxes, want)
    for r in runs:  # closed loops
        assert np.allclose(r[0], r[-1], atol=1e-9)


def test_vector_ring_gives_two_loops_and_invert_keeps_edges(tmp_path):
    img = _shapes(tmp_path / "ring.png", ring=True)
    tp = engrave(img, shipped(ESPE), {"width": 40.0})
    assert len(tp.runs()) == 3  # rectangle, ring outside, ring inside
    inv = engrave(img, shipped(ESPE), {"width": 40.0, "invert": True})
    assert len(inv.runs()) == 3


def test_vector_simplification_within_tolerance(tmp_path):
    img = _shapes(tmp_path / "a.png")
    fine = engrave(img, shipped(ESPE), {"width": 40.0, "tolerance": 0.01})
    coarse = engrave(img, shipped(ESPE), {"width": 40.0, "tolerance": 0.5})
    assert len(coarse) < len(fine)
    # every fine vertex of the disc lies within the coarse tolerance (+ a pixel) of the coarse polyline
    c = _runs_xy(coarse)[1] if _runs_xy(coarse)[1][:, 0].mean() > 0 else _runs_xy(coarse)[0]
    f = [r for r in _runs_xy(fine) if r[:, 0].mean() > 0][0]
    a, b = c[:-1], c[1:]
    ab = b - a
    u = np.clip(np.einsum("nkd,kd->nk", f[:, None] - a[None], ab) / np.einsum("kd,kd->k", ab, ab), 0, 1)
    d = np.linalg.norm(f[:, None] - (a[None] + u[..., None] * ab[None]), axis=2).min(axis=1)
    assert d.max() < 0.5 + 0.01 + PX


def test_order_polylines_is_nearest_first():
    rng = np.random.default_rng(3)
    squares = [c + np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]], float) for c in rng.uniform(-40, 40, (30, 2))]
    lines = [np.array([[5.0, 5.0], [6.0, 7.0]])] + squares  # one open line
    out = order_polylines(lines, (0.0, 0.0))
    assert len(out) == len(lines)
    pos = np.zeros(2)
    remaining = list(range(len(lines)))
    for p in out:
        # the chosen entry is no farther than any entry of the polylines still waiting
        entries = [lines[k][:-1] if len(lines[k]) > 2 else lines[k][[0, -1]] for k in remaining]
        best = min(np.linalg.norm(e - pos, axis=1).min() for e in entries)
        assert np.linalg.norm(p[0] - pos) <= best + 1e-12
        same = lambda a, b: a.shape == b.shape and np.allclose(np.unique(a, axis=0), np.unique(b, axis=0))  # noqa: E731
        k = next(k for k in remaining if same(lines[k], p))
        remaining.remove(k)
        pos = p[-1]
    greedy = sum(np.linalg.norm(b[0] - a[-1]) for a, b in zip(out[:-1], out[1:]))
    given = sum(np.linalg.norm(b[0] - a[-1]) for a, b in zip(lines[:-1], lines[1:]))
    assert greedy < given


def test_vector_power_follows_speed_and_verify_passes(tmp_path):
    pr = shipped(ESPE)
    tp = engrave(_shapes(tmp_path / "a.png"), pr, {"width": 40.0, "power": 0.8})
    traj = plan(tp, pr, workers=1)
    rate = pr.planning.output_rate
    s = traj.samples()
    v, p = _speed(s, traj.kin, rate)
    burn = s.tool > 0
    feed = pr.slicing.perimeter_speed
    expected = 0.8 * np.clip(v / feed, 0, 1)
    assert np.corrcoef(s.tool[burn], v[burn])[0, 1] > 0.9
    # the central difference's window within the burn: at a burn's last sample the next piece
    # (a travel, now a straight line that starts at full acceleration) is in it
    inside = burn & np.concatenate([[False], burn[:-1]]) & np.concatenate([burn[1:], [False]])
    err = np.abs(s.tool[inside] - expected[inside])
    # central differences over 2 ms smear the steps of the path acceleration at the corners' short stages
    assert np.percentile(err, 99) < 0.02 and err.max() < 0.1
    assert (v[burn] < 0.5 * feed).any()  # the corners do slow the tool: the test sees a real range
    assert verify_samples(s, pr, rate=rate, fmt="csv", toolpath=tp).ok
    # constant power (M3): the same value everywhere the laser is on
    const = plan(engrave(tmp_path / "a.png", pr, {"width": 40.0, "power": 0.8, "dynamic_power": False}), pr, workers=1)
    sc = const.samples()
    assert np.allclose(sc.tool[sc.tool > 0], 0.8)


# --------------------------------------------------------------------------- raster


def test_raster_covers_the_dark_areas_only(tmp_path):
    pr = shipped(ESPE)
    tp = engrave(_shapes(tmp_path / "a.png"), pr, {"width": 40.0, "mode": "raster", "line_pitch": 0.5})
    burn = tp.tool > 0
    a, b = tp.starts[burn], tp.xyz[burn]
    assert np.allclose(a[:, 1], b[:, 1])  # scan lines are horizontal
    rows = np.unique(b[:, 1])
    assert len(rows) == 24  # shapes 60 px = 12 mm high, at 0.5 mm pitch
    lo, hi = np.minimum(a[:, 0], b[:, 0]), np.maximum(a[:, 0], b[:, 0])
    in_rect = (lo >= _mm_x(20) - 0.5) & (hi <= _mm_x(80) + 0.5)
    in_disc = (lo >= _mm_x(110) - 0.5) & (hi <= _mm_x(170) + 0.5)
    assert np.all(in_rect | in_disc)
    # the rectangle's rows are burnt across its whole width
    mid = np.isclose(b[:, 1], rows[len(rows) // 2]) & in_rect
    assert np.isclose(lo[mid].min(), _mm_x(20), atol=0.5) and np.isclose(hi[mid].max(), _mm_x(80), atol=0.5)
    # burnt length per rectangle row = its width (coverage)
    assert np.isclose((hi - lo)[mid].sum(), 12.0, atol=0.5)
    # the disc's burnt area (power-weighted: grey edge pixels burn part-way) is close to pi r^2 (6 mm radius)
    area = ((hi - lo) * tp.tool[burn])[in_disc].sum() * 0.5
    assert area == pytest.approx(np.pi * 36, rel=0.06)


def test_raster_grey_ramp_power_and_dither():
    ramp = np.tile(np.linspace(1.0, 0.0, 64), (8, 1))  # white on the left, black on the right
    pw = raster_powers(ramp, 16, False, 1.0)
    assert np.all(np.diff(pw, axis=1) >= 0) and pw[:, 0].max() == 0 and pw[:, -1].min() == 1
    assert np.abs(pw - (1 - ramp)).max() <= 0.5 / 15 + 1e-12
    d = raster_powers(ramp, 16, True, 0.7)
    assert set(np.unique(d)) <= {0.0, 0.7}
    # dithered density follows the darkness (8-column blocks average to the mean darkness)
    dens = (d > 0).reshape(8, 8, 8).mean(axis=(0, 2))
    want = (1 - ramp).reshape(8, 8, 8).mean(axis=(0, 2))
    assert np.abs(dens - want).max() < 0.1


def test_raster_planned_laser_off_in_travels_and_overscan(tmp_path):
    pr = shipped(ESPE)
    im = Image.new("L", (200, 100), 255)
    ramp = np.tile(np.linspace(200, 0, 120), (40, 1)).astype(np.uint8)
    im.paste(Image.fromarray(ramp), (40, 30))
    im.save(tmp_path / "ramp.png")
    tp = engrave(tmp_path / "ramp.png", pr, {"width": 40.0, "mode": "raster", "line_pitch": 0.5})
    # overscan moves belong to the burning runs: one planned run per scan line
    assert len(split_runs(tp, pr.tool.takes_laser_power)) == 16
    traj = plan(tp, pr, workers=1)
    rate = pr.planning.output_rate
    s = traj.samples()
    v, p = _speed(s, traj.kin, rate)
    burn = s.tool > 0
    feed = pr.slicing.infill_speed
    # laser on only at the line speed: never while accelerating in the overscan or travelling
    assert v[burn].min() > 0.97 * feed
    # and only inside the image's footprint (px 40..160 x 30..70)
    assert p[burn, 0].min() >= _mm_x(40) - 0.05 and p[burn, 0].max() <= _mm_x(160) + 0.05
    assert p[burn, 1].min() >= _mm_y(70) - 0.3 and p[burn, 1].max() <= _mm_y(30) + 0.3
    # power follows the grey level: darker (right) burns more; equals darkness x speed ratio
    xb, tb = p[burn, 0], s.tool[burn]
    darkness = np.interp(xb, [_mm_x(40), _mm_x(160)], [1 - 200 / 255, 1.0])
    assert np.corrcoef(xb, tb)[0, 1] > 0.95
    assert np.abs(tb - darkness * np.clip(v[burn] / feed, 0, 1)).max() < 0.1
    assert verify_samples(s, pr, rate=rate, fmt="csv", toolpath=tp).ok


# --------------------------------------------------------------------------- SVG, placement, errors, CLI


def test_svg_stroked_paths_are_burnt(tmp_path):
    svg = tmp_path / "d.svg"
    svg.write_text(
        '<svg xmlns="http://www.w3.org/2000/svg" width="100" height="50" viewBox="0 0 100 50">'
        '<rect x="10" y="10" width="30" height="30" fill="none" stroke="black"/>'
        '<circle cx="70" cy="25" r="15" fill="none" stroke="black"/>'
        '<path d="M 0 0 L 100 50" fill="black" stroke="none"/>'
        "</svg>"
    )
    tp = engrave(svg, shipped(ESPE), {"width": 60.0})
    runs = _runs_xy(tp)
    assert len(runs) == 2
    allp = np.concatenate(runs)
    # frame = the strokes' extent (x 10..85, y 10..40): 60 mm wide, 24 mm high, centred
    assert np.allclose(allp.min(axis=0), [-30, -12], atol=1e-6) and np.allclose(allp.max(axis=0), [30, 12], atol=1e-6)
    circle = [r for r in runs if r[:, 0].mean() > 0][0]
    centre = np.array([(70 - 10) * 0.8 - 30, 12 - (25 - 10) * 0.8])
    assert np.allclose(np.linalg.norm(circle - centre, axis=1), 12.0, atol=0.06)


def test_too_large_is_refused_with_the_largest_size_that_fits(tmp_path):
    img = _shapes(tmp_path / "a.png")
    with pytest.raises(EngraveError, match="largest that fits is") as exc:
        engrave(img, shipped(ESPE), {"width": 400.0})
    width = float(str(exc.value).rsplit("--width ", 1)[1].rstrip(")"))
    assert 40 < width < 400
    engrave(img, shipped(ESPE), {"width": width})  # the size offered does fit
    default = engrave(img, shipped(ESPE), {})  # no size: the largest that fits
    assert np.ptp(default.xyz[:, 0]) == pytest.approx(150 / 200 * width, rel=0.02)  # shapes span px 20..170


def test_spot_size_sets_the_default_line_pitch(tmp_path):
    pr = shipped(ESPE)
    tp = engrave(_shapes(tmp_path / "a.png"), pr, {"width": 40.0, "mode": "raster"})
    rows = np.unique(tp.xyz[tp.tool > 0, 1])
    assert np.allclose(np.diff(rows), pr.tool.spot_size)


def _bad_images(tmp_path):
    (tmp_path / "text.png").write_text("this is not an image")
    (tmp_path / "empty.png").write_bytes(b"")
    Image.new("L", (50, 40), 255).save(tmp_path / "white.png")
    Image.new("L", (50, 40), 0).save(tmp_path / "black.jpg")
    return {
        "text.png": "not an image file",
        "empty.png": "empty file",
        "white.png": "uniformly white",
        "black.jpg": "uniformly black",
    }


def test_bad_images_clear_error_and_no_output(tmp_path, monkeypatch):
    runner = CliRunner()
    for name, message in _bad_images(tmp_path).items():
        for mode in ("vector", "raster"):
            out = tmp_path / f"{name}.{mode}.dsl"
            r = runner.invoke(main, [str(tmp_path / name), "--printer", PRINTER_FILE, "--mode", mode, "-o", str(out), "--quiet"])
            assert r.exit_code == 1 and message in r.output and "Traceback" not in r.output, r.output
            assert not out.exists()
    monkeypatch.setattr(engrave_mod, "MAX_PIXELS", 1000)
    with pytest.raises(EngraveError, match="too large"):
        engrave(_shapes(tmp_path / "a.png"), shipped(ESPE), {})
    with pytest.raises(EngraveError, match="has no laser"):
        engrave(tmp_path / "a.png", shipped("delta_etitc"), {})
    # Pillow itself refuses an image over twice its MAX_IMAGE_PIXELS while opening it: our words, not its
    import PIL.Image

    monkeypatch.setattr(PIL.Image, "MAX_IMAGE_PIXELS", 10)
    with pytest.raises(EngraveError, match=r"a\.png: image is too large .*decompression-bomb bound\): scale it down$"):
        engrave(tmp_path / "a.png", shipped(ESPE), {})


def test_cli_compiles_both_modes_and_gcode_uses_grbl_laser_words(tmp_path):
    img = str(_shapes(tmp_path / "a.png"))
    runner = CliRunner()
    for mode in ("vector", "raster"):
        out = tmp_path / f"a_{mode}.csv"
        args = [img, "--printer", PRINTER_FILE, "--width", "30", "--mode", mode, "-o", str(out), "--quiet", "--workers", "1"]
        r = runner.invoke(main, args + (["--line-pitch", "0.6"] if mode == "raster" else []))
        assert r.exit_code == 0, r.output
        v = runner.invoke(main, ["verify", str(out), "--printer", PRINTER_FILE, "--toolpath", img, "--width", "30",
                                 "--mode", mode] + (["--line-pitch", "0.6"] if mode == "raster" else []))
        assert v.exit_code == 0, v.output
    gcode = tmp_path / "a.gcode"
    r = runner.invoke(main, [img, "--printer", PRINTER_FILE, "--width", "30", "--mode", "raster", "-o", str(gcode)])
    assert r.exit_code == 0, r.output
    lines = gcode.read_text().splitlines()
    assert lines.count("M4 S0") == lines.count("M5") > 0
    burns = [ln for ln in lines if ln.startswith("G1") and " S" in ln and not ln.endswith(" S0")]
    powers = [int(ln.rsplit(" S", 1)[1]) for ln in burns]
    # S is the power fraction times [tool] s_max (GRBL $30), the scale the G-code reader divides by
    assert burns and max(powers) == 1000 and min(powers) > 0  # black shapes: full power (grey only at the disc's edge)
    assert not any(ln.startswith("G0") and " S" in ln for ln in lines)


def test_example_engraves_and_verifies(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["engrave_image.py", str(tmp_path)])
    with pytest.raises(SystemExit) as exc:
        runpy.run_path(str(ROOT / "examples" / "engrave_image.py"), run_name="__main__")
    assert exc.value.code == 0, capsys.readouterr().out
    for name in ("badge.png", "badge_vector.dsl", "badge_raster.dsl", "badge_vector.gcode", "badge_raster.gcode"):
        assert (tmp_path / name).stat().st_size > 0


def test_run_speed_at_is_the_derivative_of_arc_length():
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from deltaslice.planning.context import PlanContext
    from deltaslice.planning.runpath import RunSpec
    from deltaslice.planning.topp import plan_run

    pr = shipped(ESPE)
    kin = pr.kinematics()

    @settings(max_examples=8, deadline=None)
    @given(st.lists(st.tuples(st.floats(-30, 30), st.floats(-30, 30)), min_size=3, max_size=6, unique=True))
    def check(xy):
        pts = np.column_stack([np.array(xy), np.zeros(len(xy))])
        if np.linalg.norm(np.diff(pts, axis=0), axis=1).min() < 1.0:
            return
        m = len(pts) - 1
        power = np.linspace(0.2, 1.0, m)
        spec = RunSpec(pts, np.full(m, 20.0), np.zeros(m), 1.0, 0, power=power, dynamic_power=True)
        piece = plan_run(PlanContext.of(pr, "feed"), spec)
        piece = piece[0] if isinstance(piece, list) else piece
        tau = np.linspace(0, piece.duration, 4001)
        h = 1e-6
        numeric = (piece.arc_length_at(tau + h) - piece.arc_length_at(tau - h)) / (2 * h)
        inside = (tau > h) & (tau < piece.duration - h)
        assert np.allclose(piece.speed_at(tau)[inside], numeric[inside], atol=1e-3 * 20)
        _q, _e, tool = piece.sample(kin, tau)
        # power x speed / feed, never above the move's power, zero at rest at both ends
        assert np.all(tool <= power.max() + 1e-12) and tool[0] == 0 and tool[-1] < 1e-6
        assert np.allclose(tool, piece.power[piece.path.locate(piece.arc_length_at(tau))] * piece.speed_at(tau) / 20.0)

    check()
