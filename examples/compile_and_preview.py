"""The pipeline from Python: compile a mesh, verify the output, draw both pictures.

    python examples/compile_and_preview.py [OUT_DIR]

What `deltaslice PART --printer delta_etitc`, `deltaslice verify` and `deltaslice preview` do,
as library calls (docs/library.md); the results are objects (CompileResult, VerifyReport).
"""

from __future__ import annotations

import sys
from pathlib import Path

from deltaslice import DeltasliceError
from deltaslice.pipeline import compile_part, preview, verify_output
from deltaslice.report import compile_summary

HERE = Path(__file__).resolve().parent
CUBE = HERE / "parts" / "calibration_cube.stl"


def main(out_dir: Path) -> int:
    out = out_dir / "cube.dsl"
    result = compile_part(CUBE, "delta_etitc", output=out, scale=0.5, workers=1)
    print(compile_summary(result))
    report = verify_output(out, "delta_etitc", toolpath=CUBE, scale=0.5)
    print("verify:", "PASS" if report.ok else "FAIL", f"({report.n_samples} samples)")
    print(preview(CUBE, "delta_etitc", out_dir / "cube_layer.png", scale=0.5))
    print(preview(out, "delta_etitc", out_dir / "cube_joints.png"))
    return 0 if report.ok else 1


if __name__ == "__main__":
    try:
        sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(".")))
    except DeltasliceError as exc:
        sys.exit(f"error: {exc}")
