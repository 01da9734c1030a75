"""Ctrl-C handling that survives libraries which swallow ``KeyboardInterrupt``.

Light on purpose (standard library only): the CLI installs the handler before any heavy
import. The handler records the request and raises ``KeyboardInterrupt``; if an import or a
library swallows the exception (trimesh's optional imports catch ``BaseException``), the
recorded request still stops the work at the next :func:`check` (the pipeline checks
between stages and before replacing an output), so a previous output is never overwritten
after Ctrl-C. A second Ctrl-C exits at once with status 130. Where Python itself cannot
propagate the exception (a ctypes callback: llvmlite's, while numba writes its cache), it
reports it as "Exception ignored"; that report is dropped, the recorded request stands.
"""

from __future__ import annotations

import os
import signal
import sys
import threading

EXIT_INTERRUPTED = 130
MESSAGE = "interrupted: no output written (any previous output is unchanged)"

_state = {"requested": False, "installed": False, "unraisable": sys.__unraisablehook__}


def _handler(signum, frame):
    if _state["requested"]:
        sys.stderr.write(MESSAGE + "\n")
        sys.stderr.flush()
        os._exit(EXIT_INTERRUPTED)
    _state["requested"] = True
    raise KeyboardInterrupt


def _unraisable(report) -> None:
    """sys.unraisablehook: a KeyboardInterrupt this module raised and Python could not propagate
    is silent (the request is recorded); everything else goes to the hook that was there."""
    if _state["requested"] and report.exc_type is not None and issubclass(report.exc_type, KeyboardInterrupt):
        return
    _state["unraisable"](report)


def exit_now() -> None:
    """Print the one interrupt line and leave with status 130 at once (no traceback, no cleanup:
    nothing has been written yet)."""
    sys.stderr.write(MESSAGE + "\n")
    sys.stderr.flush()
    os._exit(EXIT_INTERRUPTED)


def _exit_handler(signum, frame):
    exit_now()


def install(at_once: bool = False) -> None:
    """Route SIGINT through the recording handler (main thread only; a no-op elsewhere).

    at_once: exit at once instead (:func:`exit_now`), for the command line's own imports
    (``from .cli import run``, click's import), where a KeyboardInterrupt would surface as a
    traceback from inside an import and nothing is written yet."""
    if threading.current_thread() is not threading.main_thread():
        return
    signal.signal(signal.SIGINT, _exit_handler if at_once else _handler)
    if not at_once and sys.unraisablehook is not _unraisable:
        _state["unraisable"] = sys.unraisablehook
        sys.unraisablehook = _unraisable
    _state["installed"] = True


def requested() -> bool:
    """True once Ctrl-C was pressed, even if the KeyboardInterrupt was swallowed."""
    return _state["requested"]


def check() -> None:
    """Raise KeyboardInterrupt if Ctrl-C was pressed since :func:`reset`."""
    if _state["requested"]:
        raise KeyboardInterrupt


def reset() -> None:
    """Forget a recorded Ctrl-C (each CLI run starts clean)."""
    _state["requested"] = False
