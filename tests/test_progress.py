"""Progress in a pipe or a log: plain lines at a steady pace through a slow stage, not a burst at
its end (deltaslice.progress)."""

from __future__ import annotations

import io
import re

import pytest

from deltaslice import progress


class _Clock:
    """A fake monotonic clock: the stage's slowness without the wait."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


@pytest.mark.parametrize("step_s, steps", [(0.3, 400), (1.5, 60), (0.01, 5000)])
def test_a_slow_stage_speaks_at_least_every_interval(monkeypatch, step_s, steps):
    """A stage reporting every ``step_s`` seconds: a line at least every PIPE_INTERVAL_S (plus one
    step: a line can only be written when the stage reports), each tenth of the work too, the
    elapsed time counted from the stage's first report, and the end said once."""
    clock = _Clock()
    monkeypatch.setattr(progress, "_now", clock)
    out = io.StringIO()
    bar = progress.stderr_progress(True, "planning", stream=out)
    written = []  # (time, line) as the lines are written
    for i in range(1, steps + 1):
        clock.t += step_s
        before = out.getvalue().count("\n")
        bar(i, steps)
        if out.getvalue().count("\n") > before:
            written.append((clock.t, out.getvalue().splitlines()[-1]))
    bar(steps, steps)  # a repeated end adds nothing
    lines = out.getvalue().splitlines()
    assert len(lines) == len(written) and lines[-1].startswith(f"planning: {steps}/{steps} (100%)")
    assert written[0][0] == 100.0 + step_s  # the stage says it has begun at its first report
    times = [t for t, _ in written]
    assert max(b - a for a, b in zip(times, times[1:])) <= progress.PIPE_INTERVAL_S + step_s
    tenths = {int(re.search(r"\((\d+)%\)", line).group(1)) // 10 for _, line in written}
    assert tenths >= set(range(1, 11)) - ({10} if steps < 10 else set())
    assert " 00:00 elapsed" in lines[0]  # counted from the stage's first report, not from the bar's making


def test_a_fast_stage_writes_a_line_per_tenth_at_most(monkeypatch):
    """Quick work stays short in a log: the first report, one line per tenth (the last is the end)."""
    clock = _Clock()
    monkeypatch.setattr(progress, "_now", clock)
    out = io.StringIO()
    bar = progress.stderr_progress(True, "slicing layers", stream=out)
    for i in range(1, 1001):
        clock.t += 0.001
        bar(i, 1000)
    lines = out.getvalue().splitlines()
    assert len(lines) == 11 and "\r" not in out.getvalue()
