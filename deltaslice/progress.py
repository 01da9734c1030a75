"""Progress reporting for long work: a ``progress(done, total)`` callback on stderr."""

from __future__ import annotations

import sys


def stderr_progress(enabled: bool, label: str):
    """A callback writing one updating line ``label: done/total (pct%)`` on stderr, or None."""
    if not enabled:
        return None
    state = {"last": -1}

    def progress(done: int, total: int) -> None:
        pct = int(100 * done / max(total, 1))
        if pct != state["last"] or done >= total:
            state["last"] = pct
            end = "\n" if done >= total else ""
            sys.stderr.write(f"\r{label}: {done}/{total} ({pct}%){end}")
            sys.stderr.flush()

    return progress
