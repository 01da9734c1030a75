"""`deltaslice workspace --printer FILE --plot PNG`: prints the figures and writes the plot."""

from __future__ import annotations

import re

from click.testing import CliRunner

from deltaslice.cli import main

from conftest import PRINTER_DIR


def _figure(text, label, unit="mm"):
    m = re.search(rf"{label}[^\n]*?([0-9.]+) {unit}", text)
    assert m, f"no {label!r} figure in:\n{text}"
    return float(m.group(1))


def test_workspace_etitc_prints_figures_and_writes_png(tmp_path):
    png = tmp_path / "etitc.png"
    result = CliRunner().invoke(main, ["workspace", "--printer", str(PRINTER_DIR / "delta_etitc.toml"), "--plot", str(png)])
    assert result.exit_code == 0, result.output
    out = result.stdout
    for label in ("reachable volume:", "largest cylinder:", "largest cylinder standing on the bed:", "largest cube:",
                  "largest cube standing on the bed:", "singularity margin", "resolution", "plot:"):
        assert label in out
    assert 6.0 < float(re.search(r"reachable volume: ([0-9.]+) litres", out).group(1)) < 8.0
    # Bounded by the 13 deg ball-joint tilt: 162 mm cylinder, 118.6 mm cube (docs/printers.md).
    assert 155.0 <= _figure(out, "largest cylinder standing on the bed: cylinder diameter") <= 162.0
    cube = float(re.search(r"largest cube standing on the bed: box ([0-9.]+) x", out).group(1))
    assert 114.0 <= cube <= 118.6
    cond = re.search(r"median ([0-9.]+), worst ([0-9.]+) \(limit 50\)", out)
    assert 1.0 < float(cond.group(1)) <= float(cond.group(2)) < 50.0
    res = re.search(r"best ([0-9.]+) mm, median ([0-9.]+) mm, worst ([0-9.]+) mm", out)
    best, median, worst = map(float, res.groups())
    assert 0.05 < best <= median <= worst < 1.0  # hobby servo: 0.09 deg per microsecond of pulse
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert str(png) in out
