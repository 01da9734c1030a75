"""deltaslice.jit's first run: with numba's cache empty, the listed kernels compile in parallel
before the run goes on, reported to a progress callback; with the cache warm nothing is compiled
and nothing is said. kernels.json covers what the README's first compile calls."""

from __future__ import annotations

import json
import multiprocessing
import os
import subprocess
import sys
from pathlib import Path

from deltaslice import jit

ROOT = Path(__file__).resolve().parents[1]
CUBE = ROOT / "examples" / "parts" / "calibration_cube.stl"

DEMO = '''
from deltaslice.jit import njit

@njit
def _twice(x):
    return 2.0 * x

@njit
def doubled(a, out):
    for i in range(a.shape[0]):
        out[i] = _twice(a[i])

@njit
def halved_sum(a):
    return sum_of(a) / 2.0

@njit
def sum_of(a):
    s = 0.0
    for v in a:
        s += v
    return s

@njit
def plus_one(n):
    return n + 1
'''

VEC = "Array(float64, 1, 'C', False, aligned=True)"
ENTRIES = [
    {"module": "demo_kernels", "name": "plus_one", "seconds": 0.1, "signatures": ["(int64,)"]},
    {"module": "demo_kernels", "name": "doubled", "seconds": 0.5, "signatures": [f"({VEC}, {VEC})"]},
    {"module": "demo_kernels", "name": "halved_sum", "seconds": 0.5, "signatures": [f"({VEC},)"]},
    {"module": "demo_kernels", "name": "sum_of", "seconds": 0.3, "signatures": [f"({VEC},)"]},
]

RUN = '''
import json, os, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
import demo_kernels as demo
from deltaslice import jit
jit.load(warm=False)
calls = []
n = jit.warm_up(json.loads(sys.argv[2]), progress=lambda d, t: calls.append([d, t]), processes=2)
a = np.arange(4.0)
out = np.empty(4)
demo.doubled(a, out)
assert list(out) == [0.0, 2.0, 4.0, 6.0] and demo.halved_sum(a) == 3.0 and demo.plus_one(1) == 2
loaded = {k: sum(getattr(demo, k).stats.cache_hits.values()) for k in ("doubled", "halved_sum", "plus_one")}
print(json.dumps({"n": n, "calls": calls, "loaded": loaded}))
'''


def _warm_up(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-c", RUN, str(tmp_path), json.dumps(ENTRIES)], env=env, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.splitlines()[-1])


def test_a_first_run_compiles_the_listed_kernels_once_and_says_so(tmp_path):
    """Empty cache: every listed kernel is compiled (here and in a worker), the progress callback
    counts them to the end, and the kernels' own dispatchers then load them from the cache (a
    cache hit each: the run does not compile them again). A second process finds the cache warm:
    nothing compiled, nothing reported."""
    (tmp_path / "demo_kernels.py").write_text(DEMO)
    first = _warm_up(tmp_path)
    assert first["n"] == len(ENTRIES)
    assert first["calls"] and first["calls"][-1] == [len(ENTRIES), len(ENTRIES)]
    assert all(hits >= 1 for hits in first["loaded"].values()), first
    second = _warm_up(tmp_path)
    assert second["n"] == 0 and second["calls"] == [], second
    assert all(hits >= 1 for hits in second["loaded"].values()), second


def test_kernels_that_share_a_callee_are_compiled_in_one_process():
    """numba compiles a called kernel with its caller: two processes each compiling it would pay
    twice. Every kernel goes to one group (a process compiles a whole group), each once; the
    longest group comes first."""
    import deltaslice.planning.blend as blend

    jobs = [{"module": m, "name": n, "seconds": 1.0, "signatures": []} for m, n in jit._KERNELS if m == blend.__name__]
    assert len(jobs) > 3
    groups = jit._groups(jobs)
    assert len(groups) > 1
    assert sorted(j["name"] for g in groups for j in g) == sorted(j["name"] for j in jobs)
    assert [len(g) for g in groups] == sorted((len(g) for g in groups), reverse=True)  # 1 s each
    where = {j["name"]: i for i, group in enumerate(groups) for j in group}
    reach = {j["name"]: jit._reached(jit._KERNELS[(j["module"], j["name"])][0]) | {(j["module"], j["name"])}
             for j in jobs}
    for a in reach:
        for b in reach:
            if reach[a] & reach[b]:
                assert where[a] == where[b], (a, b)


def test_the_warm_up_compiles_without_the_cyclic_collector_and_gives_it_back(monkeypatch):
    """numba's compile makes objects by the million: the collector's passes over them took a fifth
    of a first run's CPU. Off while the groups compile (a failing kernel too), on again after."""
    import gc

    seen = []

    def compile_(module, name, signatures):
        seen.append(gc.isenabled())
        if name == "bad":
            raise ValueError("a kernel that does not compile")

    monkeypatch.setattr(jit, "_compile", compile_)
    groups = [[{"module": "m", "name": n, "signatures": []} for n in ("a", "bad", "c")]]
    counter = multiprocessing.Value("i", 0)
    assert gc.isenabled()
    done = [0]
    jit._compile_groups(groups, counter, done=done)
    assert seen == [False, False, False] and done == [3]
    assert gc.isenabled()


def test_the_manifest_lists_what_the_readme_compile_calls(tmp_path):
    """Every kernel the README's first compile calls from Python, with every argument type it is
    called with, is in kernels.json (else a first run compiles it alone, after the parallel
    part): a kernel whose arguments changed needs ``python scripts/record_kernels.py``. Read in a
    second process from the first's cache, as the script does: a kernel loaded from the cache has
    compiled none of the kernels it calls (which a cold tree cache would list too)."""
    code = (
        "import json, sys\n"
        "from deltaslice import jit, pipeline\n"
        f"pipeline.compile_part({str(CUBE)!r}, 'delta_etitc', output=sys.argv[1], workers=1)\n"
        "found = set()\n"
        "for (module, name) in jit._KERNELS:\n"
        "    kernel = getattr(sys.modules[module], name, None)\n"
        "    found |= {(module, name, repr(s)) for s in getattr(kernel, 'signatures', [])}\n"
        "print(json.dumps(sorted(found)))\n"
    )
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    for _ in range(2):
        with_out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "cube.dsl")], capture_output=True,
                                  text=True, timeout=900, cwd=ROOT, env=env)
        assert with_out.returncode == 0, with_out.stderr[-3000:]
    called = {tuple(x) for x in json.loads(with_out.stdout.splitlines()[-1])}
    listed = {(k["module"], k["name"], s) for k in jit._manifest() for s in k["signatures"]}
    assert called, "no kernel called"
    assert called <= listed, sorted(called - listed)


def test_a_warm_compile_says_nothing_of_compiling(tmp_path):
    """The first-run line is for the first run: once the cache is warm (the first compile here
    warms it if it was not), a compile's stderr has no such line."""
    out = tmp_path / "cube.dsl"
    command = [sys.executable, "-m", "deltaslice", str(CUBE), "--printer", "delta_etitc", "-o", str(out)]
    for extra in (["--quiet"], []):
        r = subprocess.run(command + extra, capture_output=True, text=True, timeout=900, cwd=ROOT)
        assert r.returncode == 0, r.stderr[-3000:]
    assert "planning" in r.stderr and jit.FIRST_RUN_LABEL not in r.stderr
