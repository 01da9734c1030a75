"""Engrave a generated image with the ESPE delta laser, in vector and in raster mode.

    python examples/engrave_image.py [OUT_DIR]

Draws ``badge.png`` (a frame, a disc, a ring and a grey ramp; no text, so no font is
needed), compiles it for ``printers/delta_espe_laser.toml`` 50 mm wide in both modes to
binary streams and GRBL G-code, replays the streams with ``verify`` and prints the
summaries. The same from the shell:

    deltaslice badge.png --printer printers/delta_espe_laser.toml --width 50 --mode vector -o badge_vector.dsl
    deltaslice verify badge_vector.dsl --printer printers/delta_espe_laser.toml --toolpath badge.png --width 50
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from deltaslice.pipeline import compile_part, verify_output
from deltaslice.report import compile_summary

ROOT = Path(__file__).resolve().parents[1]
PRINTER = ROOT / "printers" / "delta_espe_laser.toml"


def draw_badge(path: Path) -> None:
    """A 250 x 150 px image: black frame, disc, ring and a white-to-black ramp."""
    im = Image.new("L", (250, 150), 255)
    d = ImageDraw.Draw(im)
    d.rectangle([5, 5, 244, 144], outline=0, width=6)
    d.ellipse([25, 25, 95, 95], fill=0)
    d.ellipse([115, 25, 185, 95], outline=0, width=10)
    ramp = np.tile(np.linspace(255, 0, 200), (25, 1)).astype(np.uint8)
    im.paste(Image.fromarray(ramp), (25, 110))
    im.save(path)


def main(out_dir: Path) -> int:
    out_dir.mkdir(parents=True, exist_ok=True)
    image = out_dir / "badge.png"
    draw_badge(image)
    ok = True
    for mode in ("vector", "raster"):
        options = {"mode": mode, "width": 50.0}
        stream = out_dir / f"badge_{mode}.dsl"
        print(f"== {mode}")
        print(compile_summary(compile_part(image, PRINTER, output=stream, workers=1, engrave=options)))
        compile_part(image, PRINTER, output=out_dir / f"badge_{mode}.gcode", engrave=options)
        report = verify_output(stream, PRINTER, toolpath=image, engrave=options)
        print(report.text())
        ok &= report.ok
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(".")))
