"""Safe outputs: an output path checked before any work (not an input, a writable directory),
written atomically (a temporary file renamed over it; devices and pipes written directly), and a
job's print time and size bounded before it is written. Part of the one layer that opens paths."""

from __future__ import annotations

import contextlib
import math
import os
import re
import stat
import tempfile
from pathlib import Path

from .. import interrupt
from ..errors import DeltasliceError, OutputError
from ..formats import is_stdout


def _same_file(a, b) -> bool:
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError, TypeError):
        return False


def _own_fd(path) -> int | None:
    """The number of this process's file descriptor that ``path`` names (``/dev/stdout``,
    ``/dev/fd/3``, ``/proc/self/fd/1``, or a link to one), else None. Followed link by link,
    not with realpath: realpath turns ``/proc/self/fd/1`` into ``pipe:[N]`` or the file behind."""
    p = os.path.abspath(os.fspath(path))
    for _ in range(40):
        directory, name = os.path.split(p)
        m = re.fullmatch(r"/proc/(self|\d+)/fd", os.path.realpath(directory))
        if m and name.isdigit() and m.group(1) in ("self", str(os.getpid())):
            return int(name)
        if not os.path.islink(p):
            return None
        p = os.path.normpath(os.path.join(directory, os.readlink(p)))
    return None


def _resolve_output(output, inputs=()) -> tuple[Path, bool]:
    """(the path to write, whether it is written directly). Directly: a character or block
    device, a FIFO, a socket, or one of this process's descriptors (``/dev/stdout`` even when
    the shell redirected it to a regular file: replacing that file by rename would detach it
    from the shell's descriptor). The type is read with os.stat (following links) before any
    realpath, which would turn ``/dev/stdout`` into ``/proc/.../fd/pipe:[N]``."""
    if output is None or not isinstance(output, (str, os.PathLike)) or not str(output):
        raise OutputError(f"output: expected a file path, got {output!r}")
    if is_stdout(output):
        return Path("/dev/stdout"), True  # this process's descriptor 1 (_own_fd), whatever it is
    path = Path(output)
    for src in inputs:
        if src is not None and isinstance(src, (str, os.PathLike)) and _same_file(path, src):
            raise OutputError(f"{output}: is the input file {src}: refusing to overwrite it (choose another -o)")
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        st = None  # missing (or a dangling link): created below, through the link
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise OutputError(f"{output}: is a directory: expected a file path")
    if st is not None and (not stat.S_ISREG(st.st_mode) or _own_fd(path) is not None):
        return path, True  # a device, a pipe, a socket, or our own descriptor: written directly
    target = Path(os.path.realpath(path))
    directory = target.parent
    if not directory.is_dir():
        raise OutputError(f"{output}: directory {directory} does not exist")
    if not os.access(directory, os.W_OK | os.X_OK):
        raise OutputError(f"{output}: directory {directory} is not writable")
    if target.exists() and not os.access(target, os.W_OK):
        raise OutputError(f"{output}: file is read-only")
    return target, False


def check_output(output, inputs=()) -> Path:
    """Refuse an output before any work: the same file as an input, a missing or read-only
    directory, a directory. Returns the path written (a symlink's target; a device, a pipe or
    ``/dev/stdout`` as given; ``-`` is standard output). Raises OutputError."""
    return _resolve_output(output, inputs)[0]


def _printer_file(printer):
    """The printer file a command reads (a Printer's path, or the path or name given), which no
    output may replace."""
    return getattr(printer, "path", printer)


class _BoundedFile:
    """A file object that refuses to grow past ``limit`` bytes (None: no bound)."""

    def __init__(self, f, limit, name):
        self.f, self.limit, self.name, self.written = f, limit, name, 0

    def write(self, data):
        self.written += len(data)
        if self.limit is not None and self.written > self.limit:
            raise OutputError(
                f"{self.name}: output would exceed {self.limit / 1024**2:.0f} MiB; nothing written "
                "(raise the bound with --max-size MiB, 0 for none)"
            )
        return self.f.write(data)

    def __getattr__(self, name):
        return getattr(self.f, name)


@contextlib.contextmanager
def atomic_output(path, mode: str = "wb", *, max_bytes=None, **open_kwargs):
    """Open ``path`` for writing so that a failure or Ctrl-C leaves any previous file untouched.

    A regular file (or a new one) is written to a temporary file beside it and renamed over
    it at the end, keeping an existing file's permission bits (a new file gets the umask's).
    A symlink is followed: its target is replaced, the link stays. A character device or a
    pipe (``/dev/null``, ``/dev/stdout``) is written directly, never replaced. ``max_bytes``
    bounds the bytes written (OutputError beyond). OSError (full disk, permissions) becomes
    OutputError naming the path."""
    with interrupt.writing():
        yield from _atomic_output(path, mode, max_bytes=max_bytes, **open_kwargs)


def _atomic_output(path, mode: str, *, max_bytes=None, **open_kwargs):
    target, direct = _resolve_output(path)
    if direct:
        fd = _own_fd(target)
        try:
            # our own descriptor is duplicated, not reopened: a socket cannot be reopened by
            # path, and a file the shell opened for appending keeps its offset
            with (os.fdopen(os.dup(fd), mode, **open_kwargs) if fd is not None
                  else open(target, mode, **open_kwargs)) as f:
                yield _BoundedFile(f, max_bytes, str(path))
        except OSError as exc:
            raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
        interrupt.wrote(path)
        return
    if target.exists():
        file_mode = target.stat().st_mode & 0o7777
    else:
        umask = os.umask(0)
        os.umask(umask)
        file_mode = 0o666 & ~umask
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
        os.fchmod(fd, file_mode)
        with os.fdopen(fd, mode, **open_kwargs) as f:
            yield _BoundedFile(f, max_bytes, str(path))
            f.flush()
            os.fsync(f.fileno())
        interrupt.check()  # a Ctrl-C swallowed by a library still keeps the previous file
        with interrupt.held():
            os.replace(tmp, target)
            tmp = None
            interrupt.wrote(path)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def check_job(duration_s: float, n_samples_per_s: float, bytes_per_sample: float, *, max_duration_s, max_bytes,
              output="output") -> None:
    """Refuse a job whose print time or estimated output size is beyond the bounds (None: no bound)."""
    check_bounds(max_duration_s, max_bytes)
    if max_duration_s is not None and not duration_s <= max_duration_s:
        raise OutputError(
            f"{output}: print time {_hours(duration_s)} exceeds the bound {max_duration_s / 3600:g} h "
            "(a feed rate near zero in the part?); raise it with --max-time HOURS, 0 for none"
        )
    size = duration_s * n_samples_per_s * bytes_per_sample
    if max_bytes is not None and not size <= max_bytes:
        raise OutputError(
            f"{output}: the output would be about {_mib(size)} MiB, over the bound {_mib(max_bytes)} MiB; "
            "raise it with --max-size MiB (0 for none), or write the compact .dsl stream"
        )


def check_bounds(max_duration_s, max_bytes) -> None:
    """The job bounds a library caller gives: None, or a finite number > 0 (nan compares false
    with everything, so it would refuse every job)."""
    for key, value, unit in (("max_duration_s", max_duration_s, "seconds"), ("max_bytes", max_bytes, "bytes")):
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            raise OutputError(f"{key} = {value!r}: expected a finite number of {unit} > 0, or None for no bound")


def _hours(seconds: float) -> str:
    """A print time for a message: hours, with the digits a small bound needs ("0.00111 h", not "0.0 h")."""
    return f"{seconds / 3600:.3g} h" if seconds < 360 else f"{seconds / 3600:.1f} h"


def _mib(size: float) -> str:
    """A size in MiB with the digits a small bound needs ("0.001", not "0")."""
    return f"{size / 1024**2:.3g}" if size < 100 * 1024**2 else f"{size / 1024**2:.0f}"


def _check_path(value, what):
    if not isinstance(value, (str, os.PathLike)) or not str(value):
        raise DeltasliceError(f"{what}: expected a file path, got {value!r}")
