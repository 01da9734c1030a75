"""Ctrl-C handling that survives libraries which swallow ``KeyboardInterrupt``.

Light on purpose (standard library only): the CLI installs the handler before any heavy
import. The handler records the request and raises ``KeyboardInterrupt``; if an import or a
library swallows the exception (trimesh's optional imports catch ``BaseException``), the
recorded request still stops the work at the next :func:`check` (the pipeline checks
between stages and before replacing an output), so a previous output is never overwritten
after Ctrl-C. Inside an import nothing is raised: a C extension being initialised (manifold3d)
aborts the process on an exception it does not expect; the handler leaves at once instead (status
130), or, while an output is being written (:func:`writing`), only records the request. A second
Ctrl-C exits at once with status 130. Where Python itself cannot
propagate the exception (a ctypes callback: llvmlite's, while numba writes its cache), it
reports it as "Exception ignored"; that report is dropped, the recorded request stands.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

EXIT_INTERRUPTED = 130
MESSAGE = "interrupted: no output written (any previous output is unchanged)"

_state = {"requested": False, "installed": False, "writing": 0, "written": [], "pid": None,
          "unraisable": sys.__unraisablehook__}


def _handler(signum, frame):
    if os.getpid() != _state["pid"]:
        # A forked worker (a terminal's Ctrl-C signals the whole process group): leave silently, the
        # parent says it once and shuts its pools down. A KeyboardInterrupt raised here reached
        # multiprocessing's bootstrap of an idle worker as "Process ForkProcess-1: Traceback".
        os._exit(EXIT_INTERRUPTED)
    if _state["requested"]:
        exit_now()
    _state["requested"] = True
    if _in_import(frame):
        if not _state["writing"]:
            exit_now()  # nothing is half written: leave now, without raising into the import
        return  # an output is being written: recorded, the next check() stops before it replaces anything
    raise KeyboardInterrupt


def _in_import(frame) -> bool:
    """Whether ``frame`` runs inside an import. A KeyboardInterrupt raised there can surface inside
    a C extension's initialisation, which does not expect one: manifold3d's aborts the process
    ("Fatal Python error: Aborted", or a segmentation fault) instead of raising."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _unraisable(report) -> None:
    """sys.unraisablehook: a KeyboardInterrupt this module raised and Python could not propagate
    is silent (the request is recorded); everything else goes to the hook that was there."""
    if _state["requested"] and report.exc_type is not None and issubclass(report.exc_type, KeyboardInterrupt):
        return
    _state["unraisable"](report)


def message() -> str:
    """The one interrupt line: nothing written, or which outputs were put in place, whole, before
    the Ctrl-C (one that lands after an output's rename cannot take it back)."""
    if not _state["written"]:
        return MESSAGE
    return f"interrupted: {', '.join(_state['written'])} written in full before it; nothing else written"


def exit_now() -> None:
    """Print the one interrupt line and leave with status 130 at once (no traceback, no cleanup:
    nothing is half written)."""
    sys.stderr.write(message() + "\n")
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
    _state["pid"] = os.getpid()  # forked workers inherit the handler, not this process's id
    if not at_once and sys.unraisablehook is not _unraisable:
        _state["unraisable"] = sys.unraisablehook
        sys.unraisablehook = _unraisable
    _state["installed"] = True


@contextlib.contextmanager
def writing():
    """Around the writing of an output: a Ctrl-C inside an import is then recorded (the writer's
    next check stops it and its temporary file is removed) instead of leaving at once."""
    _state["writing"] += 1
    try:
        yield
    finally:
        _state["writing"] -= 1


@contextlib.contextmanager
def beside_workers():
    """Around work done here while forked workers run (a compile loads numba while its slicing
    workers slice): a Ctrl-C inside an import is recorded, and raised as KeyboardInterrupt when
    the block ends, so the pool is shut down; leaving at once would leave the workers behind,
    waiting on the pool's pipes."""
    with writing():
        yield
    check()


@contextlib.contextmanager
def held():
    """SIGINT held back (acted on when the block ends): around an output's rename and its record,
    so that the interrupt line never says "no output written" about a file already replaced.

    The handler is swapped for one that only notes the signal. Blocking SIGINT in this thread
    (``pthread_sigmask``) did not hold it: the kernel hands a signal sent to the process to any
    thread that does not block it (numpy's BLAS threads, for one), and Python then runs the
    handler in the main thread at once. Python-level handlers run in the main thread whichever
    thread took the signal, so the swap holds it wherever it lands."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is None:
        yield  # not ours to swap: a handler set outside Python could not be put back
        return
    caught = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(frame))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if caught:
            if callable(previous):
                previous(signal.SIGINT, caught[-1])
            elif previous == signal.SIG_DFL:
                os.kill(os.getpid(), signal.SIGINT)  # the default action, now that it is back


def wrote(path) -> None:
    """An output was put in place whole (renamed over its target, or written to a device)."""
    _state["written"].append(str(path))


def requested() -> bool:
    """True once Ctrl-C was pressed, even if the KeyboardInterrupt was swallowed."""
    return _state["requested"]


def check() -> None:
    """Raise KeyboardInterrupt if Ctrl-C was pressed since :func:`reset`."""
    if _state["requested"]:
        raise KeyboardInterrupt


def reset() -> None:
    """Forget a recorded Ctrl-C and the outputs written (each CLI run starts clean)."""
    _state["requested"] = False
    _state["written"] = []
