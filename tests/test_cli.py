"""The command line a newcomer meets (issue 15): shipped printers by name (also from a built
wheel), the default PART.dsl beside the part, --json, --set, preview pictures, progress that
behaves in a pipe, click's "No such command", documented exit codes."""

from __future__ import annotations

import io
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import zipfile

import pytest
from click.testing import CliRunner

from deltaslice.cli import main
from deltaslice.printers import shipped_names, shipped_path
from deltaslice.progress import stderr_progress

from conftest import PRINTER_NAMES, ROOT

CUBE = ROOT / "examples" / "parts" / "calibration_cube.stl"
SQUARE = (
    "G21\nG90\nM82\nG92 E0\n;LAYER:0\nG1 Z0.4 F600\nG1 X-5 Y-5 F3000\n"
    "G1 X5 Y-5 E0.5 F1200\nG1 X5 Y5 E1.0\nG1 X-5 Y5 E1.5\nG1 X-5 Y-5 E2.0\n"
)


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts threads in /proc")
def test_the_command_runs_blas_on_one_thread_unless_told_otherwise():
    """The command line's process (and the workers it forks) keeps OpenBLAS to one thread: its
    per-core threads only spun on the workers' cores. A user's OPENBLAS_NUM_THREADS stands."""
    code = ("import os, sys\n"
            "import deltaslice.cli\n"
            "import numpy, scipy.linalg\n"
            "print(os.environ['OPENBLAS_NUM_THREADS'], len(os.listdir('/proc/self/task')))\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.stdout.split() == ["1", "1"], out.stderr[-2000:]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**env, "OPENBLAS_NUM_THREADS": "2"}, timeout=120)
    assert out.stdout.split()[0] == "2", out.stderr[-2000:]


def _huge_pages_always() -> bool:
    """Whether transparent huge pages back anonymous memory unasked (any size set to always)."""
    import glob

    for name in ["/sys/kernel/mm/transparent_hugepage/enabled",
                 *glob.glob("/sys/kernel/mm/transparent_hugepage/hugepages-*/enabled")]:
        try:
            with open(name) as f:
                if "[always]" in f.read():
                    return True
        except OSError:
            pass
    return False


FAULTS = """
import resource
import numpy as np


def faults():
    a = np.ones(2 << 20)  # 16 MB, written
    del a
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    b = np.ones(2 << 20)
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc" or _huge_pages_always(),
                    reason="glibc's malloc settings, counted in page faults")
def test_the_console_script_and_its_workers_keep_freed_memory_for_the_next_arrays(tmp_path):
    """In the console script's process and in a pool's worker (forked, whatever the default start
    method: Python 3.14's is forkserver on Linux), a 16 MB array freed and allocated again is
    written into the same pages (no page fault), where glibc's defaults give the freed pages back
    and the next array faults its pages in again (as in a program that only imports deltaslice)."""
    (tmp_path / "faultcount.py").write_text(FAULTS)
    code = ("import multiprocessing, sys\n"
            "import deltaslice.cli as cli\n"
            "from deltaslice.pool import start_pool\n"
            "from faultcount import faults\n"
            "def main():\n"
            "    multiprocessing.set_start_method('spawn', force=True)\n"
            "    with start_pool(1) as pool:\n"
            "        print(faults(), pool.submit(faults).result())\n"
            "cli.main = main\n"
            "cli.run() if sys.argv[1] == 'run' else main()\n")
    # numpy's own advice of huge pages for large arrays off (a 2 MB page a fault would hide the
    # count), and no malloc settings of the user's
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    env.update(NUMPY_MADVISE_HUGEPAGE="0", PYTHONPATH=os.pathsep.join([str(tmp_path), env.get("PYTHONPATH", "")]))
    counts = {}
    for how in ("run", "import"):
        out = subprocess.run([sys.executable, "-c", code, how], capture_output=True, text=True, timeout=120,
                             env=env, cwd=ROOT)
        assert out.returncode == 0, out.stderr[-2000:]
        counts[how] = [int(v) for v in out.stdout.split()]
    pages = (16 << 20) // resource.getpagesize()
    assert max(counts["run"]) < 16 and min(counts["import"]) >= pages // 2, counts


def test_printers_lists_the_shipped_printers_and_they_are_package_data():
    assert shipped_names() == PRINTER_NAMES and len(PRINTER_NAMES) == 6
    assert all(shipped_path(n).is_file() for n in PRINTER_NAMES)
    r = _run("printers")
    assert r.exit_code == 0 and all(n in r.output for n in PRINTER_NAMES)
    rows = json.loads(_run("printers", "--json").output)
    assert {row["name"] for row in rows} == set(PRINTER_NAMES) and all(row["family"] for row in rows)


def test_a_printer_by_name_and_a_misspelt_name(tmp_path):
    r = _run("slice", CUBE, "--printer", "delta_etitc", "-o", tmp_path / "c.gcode", "--quiet")
    assert r.exit_code == 0, r.output
    r = _run("slice", CUBE, "--printer", "delta_etitcc", "-o", tmp_path / "c.gcode", "--quiet")
    assert r.exit_code == 1 and "did you mean 'delta_etitc'" in r.stderr


def test_the_wheel_carries_the_printers_and_names_work_installed(tmp_path):
    """Build the wheel, install it (no dependencies) into a folder, and run from there."""
    pytest.importorskip("wheel")
    pytest.importorskip("setuptools")
    src = tmp_path / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".venv", ".git", "build", "*.egg-info", "__pycache__",
                                                            ".hypothesis", ".pytest_cache", "tests", "examples"),
                    symlinks=True)
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(wheels)], check=True, capture_output=True)
    whl = next(wheels.glob("deltaslice-*.whl"))
    names = zipfile.ZipFile(whl).namelist()
    assert {f"deltaslice/printers/{n}.toml" for n in PRINTER_NAMES} <= set(names)
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(whl)],
                   check=True, capture_output=True)
    env = {**os.environ, "PYTHONPATH": str(site)}
    work = tmp_path / "elsewhere"
    work.mkdir()
    shutil.copy(CUBE, work / "cube.stl")
    (work / "sq.gcode").write_text(SQUARE)
    where = subprocess.run([sys.executable, "-c", "import deltaslice; print(deltaslice.__file__)"], env=env, cwd=work,
                           capture_output=True, text=True)
    assert where.stdout.startswith(str(site)), where.stdout
    r = subprocess.run([sys.executable, "-m", "deltaslice", "printers"], env=env, cwd=work, capture_output=True, text=True)
    assert r.returncode == 0 and "delta_etitc" in r.stdout, r.stderr
    r = subprocess.run([sys.executable, "-m", "deltaslice", "sq.gcode", "--printer", "delta_etitc", "--quiet", "--json",
                        "--workers", "1"], env=env, cwd=work, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["fmt"] == "stream" and (work / "sq.dsl").stat().st_size > 0


def test_default_output_is_part_dsl_beside_the_part(tmp_path, monkeypatch):
    parts = tmp_path / "parts"
    parts.mkdir()
    (parts / "sq.gcode").write_text(SQUARE)
    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    r = _run(parts / "sq.gcode", "--printer", "delta_etitc", "--quiet", "--workers", "1")
    assert r.exit_code == 0, r.output
    assert (parts / "sq.dsl").read_bytes()[:4] == b"\x89DSL"
    assert list(elsewhere.iterdir()) == []


def test_json_on_compile_verify_and_workspace(tmp_path):
    part = tmp_path / "sq.gcode"
    part.write_text(SQUARE)
    r = _run(part, "--printer", "delta_etitc", "-o", tmp_path / "sq.dsl", "--quiet", "--json", "--workers", "1")
    data = json.loads(r.output)
    assert r.exit_code == 0 and data["printer"] == "delta_etitc" and data["size_bytes"] > 0 and data["duration_s"] > 0
    r = _run("verify", tmp_path / "sq.dsl", "--printer", "delta_etitc", "--json")
    data = json.loads(r.output)
    assert r.exit_code == 0 and data["ok"] is True and data["n_samples"] > 0
    assert {row["check"] for row in data["rows"]} >= {"velocity", "acceleration", "non-finite values"}
    r = _run("workspace", "--printer", "delta_etitc", "--plot", tmp_path / "ws.png", "--json")
    data = json.loads(r.output)
    assert r.exit_code == 0 and 6.0 < data["reachable_litres"] < 8.0 and data["plot"].endswith("ws.png")


def test_set_overrides_are_validated_like_the_file(tmp_path):
    out = tmp_path / "c.gcode"
    import re

    r = _run("slice", CUBE, "--printer", "delta_etitc", "-o", out, "--quiet")
    default_layers = int(re.search(r"(\d+) layers", r.output).group(1))
    r = _run("slice", CUBE, "--printer", "delta_etitc", "--set", "slicing.layer_height=0.3", "-o", out, "--quiet")
    assert r.exit_code == 0, r.output
    assert int(re.search(r"(\d+) layers", r.output).group(1)) > default_layers * 1.25
    # a --set's problem is the command line's: named as the --set, not as the printer file's key
    r = _run("slice", CUBE, "--printer", "delta_etitc", "--set", "slicing.layer_height=-1", "-o", out, "--quiet")
    assert r.exit_code == 1 and r.stderr.startswith("error: --set slicing.layer_height = -1.0: expected a number > 0")
    assert "[slicing] layer_height" not in r.stderr
    r = _run("slice", CUBE, "--printer", "delta_etitc", "--set", "slicing.layer_hieght=0.3", "-o", out, "--quiet")
    assert r.exit_code == 1 and r.stderr.startswith("error: --set slicing.layer_hieght: ")
    assert "did you mean 'layer_height'" in r.stderr and "unknown key" not in r.stderr
    r = _run("slice", CUBE, "--printer", "delta_etitc", "--set", "slicin.layer_height=0.3", "-o", out, "--quiet")
    assert r.exit_code == 1 and r.stderr.startswith("error: --set slicin.layer_height: ") and "did you mean 'slicing'" in r.stderr
    r = _run("slice", CUBE, "--printer", "delta_etitc", "--set", "slicing.layer_height=-1", "--set", "bed.radius=0",
             "-o", out, "--quiet")
    assert r.exit_code == 1 and r.stderr.startswith("error: 2 problems with --set")
    assert "--set bed.radius = 0" in r.stderr and "--set slicing.layer_height = -1.0" in r.stderr
    r = _run("slice", CUBE, "--printer", "delta_etitc", "--set", "layer_height", "-o", out, "--quiet")
    assert r.exit_code == 2


def test_preview_draws_a_layer_and_a_trajectory(tmp_path):
    png = tmp_path / "layer.png"
    r = _run("preview", CUBE, "--printer", "delta_etitc", "-o", png)
    assert r.exit_code == 0, r.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    part = tmp_path / "sq.gcode"
    part.write_text(SQUARE)
    assert _run(part, "--printer", "delta_etitc", "-o", tmp_path / "sq.dsl", "--quiet", "--workers", "1").exit_code == 0
    png2 = tmp_path / "joints.png"
    r = _run("preview", tmp_path / "sq.dsl", "--printer", "delta_etitc", "-o", png2)
    assert r.exit_code == 0 and png2.stat().st_size > 20_000, r.output
    r = _run("preview", CUBE, "--printer", "delta_etitc", "-o", tmp_path / "x.jpg")
    assert r.exit_code == 1 and ".png" in r.stderr


def test_progress_in_a_pipe_is_plain_lines_with_an_eta():
    out = io.StringIO()
    bar = stderr_progress(True, "planning runs", stream=out)
    for i in range(1, 501):
        bar(i, 500)
    text = out.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert 2 <= len(lines) <= 11 and lines[-1].startswith("planning runs: 500/500 (100%)")
    assert any("ETA" in line for line in lines[:-1])
    assert stderr_progress(False, "x") is None


def test_a_mistyped_command_is_no_such_command():
    r = _run("slic", "part.stl")
    assert r.exit_code == 2 and "No such command 'slic'" in r.output and "--printer" not in r.output
    r = _run("cube.stl", "--printer", "no_such_printer")  # a path goes to compile
    assert r.exit_code == 1 and "no such printer" in r.stderr


def test_exit_codes_are_documented():
    r = _run("--help")
    assert r.exit_code == 0
    for code in ("0 done", "1 error", "2 usage", "3 verify", "130 interrupted"):
        assert code in r.output, r.output


def test_workspace_plot_path_is_checked_before_the_work(tmp_path):
    r = _run("workspace", "--printer", "delta_etitc", "--plot", tmp_path / "missing" / "ws.png")
    assert r.exit_code == 1 and "does not exist" in r.stderr and r.stderr.count("\n") == 1
    r = _run("workspace", "--printer", "delta_etitc", "--plot", tmp_path / "ws.pdf")
    assert r.exit_code == 1 and ".png" in r.stderr


@pytest.mark.parametrize("command", sorted(main.commands))
def test_every_command_help_shows_an_example(command):
    r = CliRunner().invoke(main, [command, "--help"])
    assert r.exit_code == 0, r.output
    assert "Example" in r.output, r.output
    example = r.output.split("Example", 1)[1]
    # compile is the default command: its examples start with the part
    assert f"deltaslice {command} " in example or (command == "compile" and "deltaslice part.gcode" in example), r.output
