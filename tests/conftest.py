"""Shared helpers: the shipped printer files, loaded once; tests/ on sys.path for helper modules."""

from __future__ import annotations

import functools
import os
import sys
from pathlib import Path

import pytest
from hypothesis import settings

sys.path.insert(0, str(Path(__file__).resolve().parent))

from deltaslice.machine import load_printer  # noqa: E402

# The suite's verdict must not depend on luck: property tests draw the same examples on every run
# (derandomized, no example database). `python scripts/explore_properties.py` runs the open-ended
# search with fresh seeds; whatever it finds becomes an @example of its test.
settings.register_profile("gating", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", derandomize=False, print_blob=True)
settings.load_profile(os.environ.get("DELTASLICE_HYPOTHESIS", "gating"))

ROOT = Path(__file__).resolve().parents[1]
PRINTER_DIR = ROOT / "printers"
PRINTER_NAMES = sorted(p.stem for p in PRINTER_DIR.glob("*.toml"))


@functools.cache
def printer(name: str):
    """The shipped printer ``printers/<name>.toml`` (cached; Printer is frozen)."""
    return load_printer(PRINTER_DIR / f"{name}.toml")


@pytest.fixture(params=PRINTER_NAMES)
def any_printer(request):
    return printer(request.param)


@pytest.fixture
def small_windows(monkeypatch):
    """A long run's windows made a few hundred segments (the planner's are thousands) so tests of
    long runs stay fast."""
    from deltaslice.planning import windows

    monkeypatch.setattr(windows, "LONG_RUN", 300)
    monkeypatch.setattr(windows, "WINDOW", 200)
    monkeypatch.setattr(windows, "LOOKAHEAD", 100)
    monkeypatch.setattr(windows, "LOOKAHEAD_MM", 5.0)
