"""Setpoints CSV: one row per sample, joint units, written block by block.

Layout (the binary stream's ``decode --units`` prints exactly this)::

    # deltaslice setpoints v1
    # printer: delta_etitc
    # fingerprint: 0x6b02c06b
    # rate_hz: 1000
    # columns: t s, q1 rad, q2 rad, q3 rad, e mm, tool 0..1
    # planner: toppra                     <- planner metadata, one "# key: value" each
    t,q1,q2,q3,e,tool
    0.000000000,1.0180981100,1.0180981100,1.0180981100,0.0000000000,0.000000000

t in s with 9 decimals, joints (rad or mm) and e (mm of filament, cumulative)
with 10 decimals (round trip within 5e-11), tool (0 off, 1 extruding, or laser
power 0..1) with 9 decimals.
"""

from __future__ import annotations

import io
import re

import numpy as np

from ..errors import StreamError
from ..samples import Samples
from ..toolpath import EVENT_NAMES, EventKind

TITLE = "deltaslice setpoints v1"
RESERVED = ("printer", "fingerprint", "rate_hz", "columns")


def column_names(n_joints: int) -> list[str]:
    return ["t", *[f"q{j + 1}" for j in range(n_joints)], "e", "tool"]


def check_metadata(metadata: dict) -> dict[str, str]:
    """Metadata as str -> str, one line each; keys are words (no ':', '=', spaces)."""
    out = {}
    for k, v in (metadata or {}).items():
        k, v = str(k), str(v)
        if not k or any(c in k for c in ":=# \t\r\n") or k in RESERVED:
            raise StreamError(f"metadata key {k!r}: expected a word without ':', '=', '#' or spaces, not one of {RESERVED}")
        out[k] = " ".join(v.split())
    return out


def comment_lines(printer_name: str, fingerprint: int, rate: float, joint_units: list[str], metadata: dict) -> str:
    """The ``#`` lines and the header row."""
    names = column_names(len(joint_units))
    units = ["s", *joint_units, "mm", "0..1"]
    lines = [
        f"# {TITLE}",
        f"# printer: {printer_name}",
        f"# fingerprint: 0x{fingerprint & 0xFFFFFFFF:08x}",
        f"# rate_hz: {rate:.10g}",
        "# columns: " + ", ".join(f"{n} {u}" for n, u in zip(names, units)),
    ]
    lines += [f"# {k}: {v}" for k, v in check_metadata(metadata).items()]
    lines.append(",".join(names))
    return "\n".join(lines) + "\n"


def format_rows(t, q, e, tool) -> str:
    """Rows of the CSV for arrays t (n,), q (n,J), e (n,), tool (n,)."""
    n, nj = q.shape
    if n == 0:
        return ""
    table = np.empty((n, nj + 3))
    table[:, 0] = t
    table[:, 1 : nj + 1] = q
    table[:, nj + 1] = e
    table[:, nj + 2] = tool
    row = "%.9f," + "%.10f," * (nj + 1) + "%.9f\n"
    return (row * n) % tuple(table.ravel().tolist())


def check_finite(samples: Samples, first_index: int) -> None:
    for name in ("t", "q", "e", "tool"):
        arr = getattr(samples, name)
        if np.isfinite(arr).all():
            continue
        bad = ~np.isfinite(arr)
        if bad.any():
            i = int(np.flatnonzero(bad.reshape(len(arr), -1).any(axis=1))[0])
            raise StreamError(f"sample {first_index + i}: non-finite {name} value: the trajectory cannot be written")


_EVENT_LINE = re.compile(r"^# event t=(\S+) kind=(\w+) value=(\S+)\s*$", re.M)
_EVENT_KINDS = {name: int(k) for k, name in EVENT_NAMES.items()}


def event_line(index: int, kind: int, value: float, rate: float) -> str:
    """The comment line of one event before sample ``index``."""
    return f"# event t={index / rate:.9f} kind={EVENT_NAMES[EventKind(kind)]} value={value:.10g}\n"


def _rows_with_events(samples: Samples, first: int, events: list, rate: float) -> str:
    """Rows of one block with the comment lines of the events whose index falls in it."""
    n = len(samples)
    cut = 0
    parts = []
    while events and events[0][0] < first + n:
        i, kind, value = events.pop(0)
        at = max(i - first, 0)
        if at > cut:
            parts.append(format_rows(samples.t[cut:at], samples.q[cut:at], samples.e[cut:at], samples.tool[cut:at]))
            cut = at
        parts.append(event_line(i, kind, value, rate))
    parts.append(format_rows(samples.t[cut:], samples.q[cut:], samples.e[cut:], samples.tool[cut:]))
    return "".join(parts)


def write_csv(blocks, printer, f, *, rate: float, metadata: dict | None = None, events=()) -> int:
    """Write Samples blocks as setpoints CSV to the binary file ``f``. Returns bytes written.

    events: ``(sample_index, kind, value)``, in order; written as ``# event`` lines."""
    units = list(printer.limits.units[:-1])
    header = comment_lines(printer.name, printer.fingerprint(), rate, units, metadata or {})
    size = 0
    index = 0
    pending = sorted(((int(i), int(k), float(v)) for i, k, v in events), key=lambda ev: ev[0])
    data = header.encode()
    f.write(data)
    size += len(data)
    for samples in blocks:
        if samples.n_joints != printer.n_joints:
            raise StreamError(f"samples have {samples.n_joints} joints, printer {printer.name} has {printer.n_joints}")
        check_finite(samples, index)
        data = _rows_with_events(samples, index, pending, rate).encode()
        f.write(data)
        size += len(data)
        index += len(samples)
    data = "".join(event_line(i, k, v, rate) for i, k, v in pending).encode()  # at or after the end
    f.write(data)
    size += len(data)
    return size


def parse_comments(lines: list[str]) -> dict[str, str]:
    meta = {}
    for line in lines:
        body = line[1:].strip()
        if ":" in body:
            k, v = body.split(":", 1)
            meta[k.strip()] = v.strip()
    return meta


def read_csv(f, path: str = "<csv>") -> tuple[dict[str, str], Samples]:
    """(metadata, Samples) of a setpoints CSV read from the binary file ``f`` (named ``path``
    in messages). Raises StreamError on a malformed file."""
    try:
        text = f.read().decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise StreamError(f"{path}: cannot read setpoints CSV: {exc}") from None
    comments, pos = [], 0
    while text.startswith("#", pos):
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end
        comments.append(text[pos:end])
        pos = end + 1
    end = text.find("\n", pos)
    header = text[pos : (len(text) if end < 0 else end)].strip()
    names = header.split(",")
    if len(names) < 4 or names[0] != "t" or names[-2:] != ["e", "tool"]:
        raise StreamError(f"{path}: line {len(comments) + 1}: expected the header row t,q1,...,qJ,e,tool, got {header[:80]!r}")
    ncol = len(names)
    body = text[end + 1 :] if end >= 0 else ""
    try:
        table = np.loadtxt(io.StringIO(body), delimiter=",", dtype=float, ndmin=2) if body.strip() else np.zeros((0, ncol))
    except ValueError as exc:
        raise StreamError(f"{path}: malformed setpoint row: {exc}") from None
    if table.size == 0:
        table = np.zeros((0, ncol))
    if table.shape[1] != ncol:
        raise StreamError(f"{path}: rows have {table.shape[1]} columns, the header names {ncol}")
    meta = parse_comments(comments)
    meta["format"] = "csv"
    events = []
    for m in _EVENT_LINE.finditer(body):
        try:
            rate = float(meta.get("rate_hz", "nan"))
            i, value = int(round(float(m.group(1)) * rate)), float(m.group(3))
            kind = _EVENT_KINDS[m.group(2)]
        except (ValueError, KeyError, OverflowError):
            raise StreamError(f"{path}: malformed event line {m.group(0)!r}") from None
        events.append((i, kind, value))
    if events:
        meta["events"] = tuple(events)
    return meta, Samples(table[:, 0], table[:, 1:-2], table[:, -2], table[:, -1])
