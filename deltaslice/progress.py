"""Progress reporting for long work: a ``progress(done, total)`` callback on stderr.

On a terminal it is a tqdm bar (rate and ETA). In a pipe or a log file there is no
carriage return: one plain line at the stage's first report, one per tenth of the work (and at
the end), and one whenever ``PIPE_INTERVAL_S`` has passed since the last (a slow stage still
speaks at a steady pace), each with the elapsed time since the first report and tqdm's ETA.
"""

from __future__ import annotations

import sys
import time

PIPE_STEPS = 10
PIPE_INTERVAL_S = 2.0  # at most this long between two lines of a stage that reports (a pipe's)
_now = time.monotonic


def stderr_progress(enabled: bool, label: str, unit: str = "it", stream=None):
    """A callback ``progress(done, total)`` drawing on ``stream`` (default stderr), or None when disabled."""
    if not enabled:
        return None
    stream = stream or sys.stderr
    isatty = getattr(stream, "isatty", lambda: False)()
    return _TtyBar(label, unit, stream) if isatty else _PipeLines(label, unit, stream)


class _TtyBar:
    def __init__(self, label, unit, stream):
        self.label, self.unit, self.stream, self.bar = label, unit, stream, None

    def __call__(self, done, total):
        from tqdm import tqdm

        if self.bar is None:
            fmt = "{l_bar}{bar}| {n:.0f}/{total:.0f} {unit} [{elapsed}<{remaining}]" if self.unit == "s" else None
            self.bar = tqdm(total=total, desc=self.label, unit=self.unit, file=self.stream, leave=True,
                            dynamic_ncols=True, **({"bar_format": fmt} if fmt else {}))
        self.bar.total = total
        self.bar.update(done - self.bar.n)
        if done >= total:
            self.bar.close()


class _PipeLines:
    def __init__(self, label, unit, stream):
        self.label, self.unit, self.stream = label, unit, stream
        self.t0 = self.last = None  # the first report's time (the stage starts there), the last line's
        self.next_step = 1
        self.finished = False

    def __call__(self, done, total):
        from tqdm import tqdm

        if self.finished:
            return
        now = _now()
        first = self.t0 is None  # the stage's first report is said at once: the stage has begun
        if first:
            self.t0 = self.last = now
        frac = done / total if total > 0 else 1.0
        if not first and frac < self.next_step / PIPE_STEPS and done < total and now - self.last < PIPE_INTERVAL_S:
            return
        self.next_step = max(self.next_step, int(frac * PIPE_STEPS) + 1)
        self.last = now
        elapsed = now - self.t0
        eta = "" if done >= total or frac <= 0 else f", ETA {tqdm.format_interval(elapsed * (1 - frac) / frac)}"
        shown = f"{done:.0f}/{total:.0f} {self.unit}" if self.unit == "s" else f"{done}/{total}"
        self.stream.write(f"{self.label}: {shown} ({100 * frac:.0f}%), {tqdm.format_interval(elapsed)} elapsed{eta}\n")
        self.stream.flush()
        self.finished = done >= total
