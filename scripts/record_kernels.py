"""Write deltaslice/kernels.json: the kernels the README's first compile calls from Python, with the
argument types of each call and the seconds each takes to compile with an empty cache.

    python scripts/record_kernels.py [--part examples/parts/calibration_cube.stl] [--printer delta_etitc]

A first run compiles these in parallel before it goes on (deltaslice.jit.warm_up). Run it again
when a kernel listed there changes its arguments' types or a new kernel is called from Python
(tests/test_jit.py says so). Child processes: one compiles the part (one worker, every kernel in
that process) into an empty cache, a second compiles it again from that cache and reads each
kernel's signatures from numba's dispatchers (a kernel loaded from the cache has not compiled the
kernels it calls, so only those called from Python are listed: a callee listed on its own would
be compiled twice, alone and inside its callers, whatever the state of the tree's cache); the last
compiles each kernel alone into an empty cache directory and times it, in CPU seconds (the split
between processes is balanced by these times).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SIGNATURES = """
import json, sys
from deltaslice import jit, pipeline
jit.load(warm=False)
pipeline.compile_part(sys.argv[1], sys.argv[2], output=sys.argv[3], workers=1)
found = []
for (module, name) in sorted(jit._KERNELS):
    kernel = getattr(sys.modules[module], name.split('.')[0], None)
    sigs = []
    for s in getattr(kernel, 'signatures', []):
        try:  # a signature numba's types cannot write back (a literal value) compiles at its call
            if jit._signatures([repr(s)]) == [s]:
                sigs.append(repr(s))
        except (NameError, SyntaxError, TypeError):
            pass
    if sigs:
        found.append({"module": module, "name": name, "signatures": sigs})
print(json.dumps(found))
"""

TIMES = """
import json, sys, time
from deltaslice import jit
kernels = json.loads(sys.stdin.read())
for k in kernels:
    __import__(k["module"])
jit.load(warm=False)
import numba
numba.njit(lambda x: x + 1)(1)  # numba's own set-up, paid once by any process, is no kernel's
for k in kernels:
    t = time.process_time()  # CPU time: on a busy machine the wall time says more of the others
    jit._compile(k["module"], k["name"], k["signatures"])
    k["seconds"] = round(time.process_time() - t, 2)
print(json.dumps(kernels))
"""


def _child(code: str, argv: list, env: dict, stdin: str | None = None):
    """Run ``code`` in a new Python process; the JSON of its last line."""
    r = subprocess.run([sys.executable, "-c", code, *argv], input=stdin, env=env, capture_output=True, text=True,
                       cwd=ROOT)
    if r.returncode != 0:
        raise SystemExit(f"record_kernels: a child process failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", default=str(ROOT / "examples" / "parts" / "calibration_cube.stl"))
    ap.add_argument("--printer", default="delta_etitc")
    args = ap.parse_args()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as cache:
        argv = [args.part, args.printer, str(Path(tmp) / "x.dsl")]
        _child(SIGNATURES, argv, dict(env, NUMBA_CACHE_DIR=cache))
        out = _child(SIGNATURES, argv, dict(env, NUMBA_CACHE_DIR=cache))
        kernels = _child(TIMES, [], dict(env, NUMBA_CACHE_DIR=tmp), stdin=json.dumps(out))
    manifest = {"about": "kernels a first run compiles in parallel (deltaslice.jit.warm_up); "
                         "written by scripts/record_kernels.py",
                "part": Path(args.part).name, "printer": args.printer, "kernels": kernels}
    path = ROOT / "deltaslice" / "kernels.json"
    path.write_text(json.dumps(manifest, indent=1) + "\n")
    total = sum(k["seconds"] for k in kernels)
    print(f"{path}: {len(kernels)} kernels, {sum(len(k['signatures']) for k in kernels)} signatures, "
          f"{total:.1f} s to compile one after the other")


if __name__ == "__main__":
    main()
