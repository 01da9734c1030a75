"""Samples: a trajectory sampled at the printer's output rate, the input of every emitter.

=======  ======  ===================================================================
array    shape   meaning
=======  ======  ===================================================================
t        (n,)    time, s, uniform steps of 1 / rate
q        (n, J)  joint positions, joint units (rad for revolute, mm for prismatic)
e        (n,)    filament position, mm (cumulative; retracts go down)
tool     (n,)    tool state: 0 off, 1 extruding, laser power fraction 0..1
=======  ======  ===================================================================

Long prints are emitted as a sequence of Samples blocks, so memory stays bounded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import DeltasliceError


def _numbers(name, value) -> np.ndarray:
    """``value`` as float64; DeltasliceError naming ``Samples.name`` for None, strings, complex
    numbers (non-finite values are kept: verify is what fails them)."""
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise DeltasliceError(f"Samples.{name}: expected an array of numbers: {exc}") from None
    if raw.dtype.kind not in "biuf":
        raise DeltasliceError(f"Samples.{name}: expected an array of real numbers, got {type(value).__name__} "
                              f"({raw.dtype} values)")
    return np.array(raw, dtype=float) if raw.dtype != np.float64 else raw


@dataclass(frozen=True)
class Samples:
    t: np.ndarray
    q: np.ndarray
    e: np.ndarray
    tool: np.ndarray

    def __post_init__(self):
        t = _numbers("t", self.t).reshape(-1)
        n = len(t)
        object.__setattr__(self, "t", t)
        for name in ("e", "tool"):
            arr = _numbers(name, getattr(self, name)).reshape(-1)
            if len(arr) != n:
                raise DeltasliceError(f"Samples.{name}: expected {n} values (one per time in t), got {len(arr)}")
            object.__setattr__(self, name, arr)
        q = _numbers("q", self.q)
        if q.ndim != 2 or len(q) != n:
            raise DeltasliceError(f"Samples.q: expected shape ({n}, J) (a row per time in t), got {q.shape}")
        object.__setattr__(self, "q", q)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def n_joints(self) -> int:
        return self.q.shape[1]

    @classmethod
    def concatenate(cls, blocks: list["Samples"]) -> "Samples":
        return cls(
            np.concatenate([b.t for b in blocks]),
            np.concatenate([b.q for b in blocks]),
            np.concatenate([b.e for b in blocks]),
            np.concatenate([b.tool for b in blocks]),
        )


def to_counts(printer, samples: Samples, with_peak: bool = False):
    """Integer actuator counts, (n, J + 1) int64: one column per joint and one for the tool
    channel (extruder microsteps from the filament position, or laser PWM counts from the
    power fraction), ``count = zero_count + counts_per_unit * value`` (see ``printer.limits``).
    with_peak: (counts, the largest |zero_count + counts_per_unit * value| before rounding,
    NaN if any is not finite)."""
    channel = np.asarray(printer.tool.channel_values(samples.e, samples.tool), dtype=float)
    return printer.limits.joint_and_channel_counts(np.asarray(samples.q, dtype=float), channel, with_peak)


def from_counts(printer, counts: np.ndarray, rate: float, t0: float = 0.0) -> Samples:
    """Inverse of :func:`to_counts` (within quantisation). counts: (n, J + 1) int."""
    values = printer.limits.from_counts(counts)
    e, tool = printer.tool.from_channel(values[:, -1])
    return Samples(t0 + np.arange(len(values)) / rate, values[:, :-1], e, tool)
