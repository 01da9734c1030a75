"""Pieces: what every planner returns, a list of them, end to end, each from rest to rest
(except the windows of a long run, :func:`.windows._iter_windows`, which join at the same point and speed).

The :class:`Piece` protocol is all the Trajectory, the emitters and the reports know of a
planned motion: its kind ("run", "travel", "retract", "trapezoid"), layer, duration, the
joint positions at both ends, the filament it pushes, the time it spends with a limit
active, and ``sample(kin, tau)``: joint positions (n, J), filament pushed since the piece
start (n,) mm and tool state (n,) at times tau (n,) s from the piece start; ``sample_into`` writes
the same values into given arrays (a block's rows: the trajectory's sampler allocates nothing per
piece).

* :class:`RunPiece`: a toppra solution along a blended path (runs and straight travels),
* :class:`JointMovePiece`: a ruckig jerk-limited joint-space move (travels),
* :class:`FilamentPiece`: a retract or unretract at rest,
* :class:`TrapezoidPiece`: the conventional planner's whole toolpath.

:class:`PieceBatch` carries lists of pieces between processes (planning workers, the spool).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from operator import attrgetter
from typing import Protocol, runtime_checkable

import numpy as np

from .blend import BlendedPath, sample_kernel
from .ruckig_profile import RuckigProfile
from .tolerances import DIVISION_FLOOR


@runtime_checkable
class Piece(Protocol):
    kind: str
    layer: int

    @property
    def duration(self) -> float: ...

    @property
    def filament_total(self) -> float: ...

    @property
    def active_time(self) -> float: ...

    @property
    def q_start(self) -> np.ndarray: ...

    @property
    def q_end(self) -> np.ndarray: ...

    def sample(self, kin, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def sample_into(self, kin, tau: np.ndarray, q: np.ndarray, de: np.ndarray, tool: np.ndarray) -> None: ...


class _Sampled:
    """``sample`` from the piece's ``sample_into``: what every piece shares."""

    def sample(self, kin, tau):
        tau = np.ascontiguousarray(tau, dtype=np.float64)
        n = len(tau)
        q = np.empty((n, kin.n_joints if kin is not None else len(self.q_start)))
        de, tool = np.empty(n), np.empty(n)
        self.sample_into(kin, tau, q, de, tool)
        return q, de, tool


@dataclass(frozen=True)
class RunPiece(_Sampled):
    """A planned run: toppra's solution on its grid.

    x: (n+1,) grid in path units; xd: (n+1,) path speed; xdd: (n,) constant path
    acceleration per stage; t: (n+1,) time at grid points, s; S: run length mm.
    cum_e: (k+1,) filament pushed at each path piece start, relative to the run start; e_ratio: (k,)
    filament per mm of each path piece; q_start, q_end: (J,) joint positions at both ends.
    """

    path: BlendedPath
    S: float
    x: np.ndarray
    xd: np.ndarray
    xdd: np.ndarray
    t: np.ndarray
    cum_e: np.ndarray
    e_ratio: np.ndarray
    tool: float
    layer: int
    active_time: float = 0.0
    kind: str = "run"
    q_start: np.ndarray | None = None
    q_end: np.ndarray | None = None
    power: np.ndarray | None = None  # (k,) laser power per piece of the blended path
    nominal_feed: np.ndarray | None = None  # (k,) mm/s, the toolpath's feed per piece (dynamic power)
    dynamic_power: bool = False

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def arc_length_at(self, tau: np.ndarray) -> np.ndarray:
        """Arc length s (mm) at times tau (s, relative to the run start). (n,)"""
        tau = np.clip(tau, 0.0, self.duration)
        i = np.clip(np.searchsorted(self.t, tau, side="right") - 1, 0, len(self.xdd) - 1)
        dt = tau - self.t[i]
        x = self.x[i] + self.xd[i] * dt + 0.5 * self.xdd[i] * dt * dt
        return np.clip(x, 0.0, 1.0) * self.S

    def speed_at(self, tau: np.ndarray) -> np.ndarray:
        """Tool speed (mm/s) at times tau (s, relative to the run start): S x_dot, exact per stage. (n,)"""
        tau = np.clip(tau, 0.0, self.duration)
        i = np.clip(np.searchsorted(self.t, tau, side="right") - 1, 0, len(self.xdd) - 1)
        return np.maximum(self.xd[i] + self.xdd[i] * (tau - self.t[i]), 0.0) * self.S

    def filament_at(self, s: np.ndarray, piece: np.ndarray) -> np.ndarray:
        """Filament pushed since the run start at arc lengths s, mm."""
        return self.cum_e[piece] + (s - self.path.piece_start[piece]) * self.e_ratio[piece]

    def sample_into(self, kin, tau: np.ndarray, q: np.ndarray, de: np.ndarray, tool: np.ndarray) -> None:
        """Joint positions q (n,J), relative filament de (n,), tool (n,) at times tau (n,) s,
        written into the given float64 arrays (C-contiguous, as the compiled passes take them).

        The points and the filament come from one compiled pass (:func:`.blend.sample_kernel`: the
        values of :meth:`arc_length_at`, ``path.locate``, ``path.frame`` and :meth:`filament_at`,
        the emitter's hottest call after the inverse kinematics)."""
        n, p = len(tau), self.path
        point, k = np.empty((n, 3)), np.empty(n, dtype=np.int64)
        sample_kernel(tau, self.t, self.x, self.xd, self.xdd, float(self.S), p.piece_start, p.kind, p.p0, p.d0,
                       p.normal, p.radius, self.cum_e, self.e_ratio, point, de, k)
        kin.inverse_into(point, q)
        if self.power is None:
            tool.fill(self.tool)
        elif self.dynamic_power:  # GRBL M4: power follows the tool's speed over the requested feed
            tool[:] = self.power[k] * np.clip(self.speed_at(tau) / self.nominal_feed[k], 0.0, 1.0)
        else:
            tool[:] = self.power[k]

    @property
    def filament_total(self) -> float:
        return float(self.cum_e[-1])


@dataclass(frozen=True)
class JointMovePiece(_Sampled):
    """A ruckig joint-space move from rest to rest, as its phases (:mod:`.ruckig_profile`);
    ``traj`` (the ruckig object, not picklable) only where the phases are not exposed."""

    profile: RuckigProfile | None
    traj: object
    q0: np.ndarray
    q1: np.ndarray
    layer: int
    kind: str = "travel"
    tool: float = 0.0

    @property
    def duration(self) -> float:
        return float(self.profile.duration if self.profile is not None else self.traj.duration)

    @property
    def q_start(self) -> np.ndarray:
        return self.q0

    @property
    def q_end(self) -> np.ndarray:
        return self.q1

    @property
    def active_time(self) -> float:
        # A time-optimal jerk-limited profile has the jerk, acceleration or velocity of its
        # limiting joint at a bound at every instant.
        return self.duration

    def sample_into(self, kin, tau, q, de, tool):
        if self.profile is not None:
            self.profile.positions(tau, out=q)
        else:
            tau = np.clip(tau, 0.0, self.duration)
            q[:] = np.array([self.traj.at_time(float(t))[0] for t in tau]).reshape(len(tau), -1)
        de.fill(0.0)
        tool.fill(0.0)

    @property
    def filament_total(self) -> float:
        return 0.0


@dataclass(frozen=True)
class FilamentPiece(_Sampled):
    """Retract or unretract at rest: a trapezoidal filament move of ``amount`` mm."""

    q: np.ndarray
    amount: float
    v: float
    a: float
    layer: int
    kind: str = "retract"
    tool: float = 0.0

    @property
    def active_time(self) -> float:
        return self.duration  # trapezoid: always at the acceleration or speed bound

    @property
    def q_start(self) -> np.ndarray:
        return self.q

    @property
    def q_end(self) -> np.ndarray:
        return self.q

    @property
    def _profile(self):
        d = abs(self.amount)
        t_acc = self.v / self.a
        if self.a * t_acc**2 >= d:  # triangular
            t_acc = np.sqrt(d / self.a)
            return t_acc, 0.0, self.a * t_acc
        return t_acc, (d - self.a * t_acc**2) / self.v, self.v

    @property
    def duration(self) -> float:
        if self.amount == 0:
            return 0.0
        ta, tc, _ = self._profile
        return 2 * ta + tc

    def sample_into(self, kin, tau, q, de, tool):
        tau = np.clip(tau, 0.0, self.duration)
        ta, tc, vp = self._profile
        a = vp / ta if ta > 0 else 0.0
        d1 = 0.5 * a * ta * ta
        pos = np.where(
            tau < ta,
            0.5 * a * tau**2,
            np.where(tau < ta + tc, d1 + vp * (tau - ta), 2 * d1 + vp * tc - 0.5 * a * (2 * ta + tc - tau) ** 2),
        )
        q[:] = self.q
        de[:] = np.sign(self.amount) * pos
        tool.fill(0.0)

    @property
    def filament_total(self) -> float:
        return float(self.amount)


@dataclass(frozen=True)
class TrapezoidPiece(_Sampled):
    """All moves of a toolpath as one piece. Arrays per move (n,)."""

    p0: np.ndarray  # (n,3) start points
    d: np.ndarray  # (n,3) unit directions (zero for filament-only moves)
    length: np.ndarray  # path length of the move, mm (|e| for filament-only moves)
    v_in: np.ndarray
    v_top: np.ndarray
    v_out: np.ndarray
    accel: np.ndarray
    t0: np.ndarray  # (n+1,) start times
    e0: np.ndarray  # (n,) filament at the move start, relative to the piece start
    e: np.ndarray  # filament of each move
    tool: np.ndarray
    filament_only: np.ndarray
    q_start: np.ndarray
    q_end: np.ndarray
    layer: int = 0
    kind: str = "trapezoid"

    @property
    def duration(self) -> float:
        return float(self.t0[-1])

    @property
    def filament_total(self) -> float:
        return float(self.e.sum())

    @property
    def active_time(self) -> float:
        return 0.0  # not a certificate this planner provides

    def sample_into(self, kin, tau, q, de, tool):
        tau = np.clip(tau, 0.0, self.duration)
        k = np.clip(np.searchsorted(self.t0, tau, side="right") - 1, 0, len(self.length) - 1)
        dt = tau - self.t0[k]
        vi, vt, vo, a, L = self.v_in[k], self.v_top[k], self.v_out[k], self.accel[k], self.length[k]
        ta = (vt - vi) / a
        la = (vt**2 - vi**2) / (2 * a)
        ld = (vt**2 - vo**2) / (2 * a)
        tc = np.maximum(L - la - ld, 0) / np.maximum(vt, DIVISION_FLOOR)
        s = np.where(
            dt < ta,
            vi * dt + 0.5 * a * dt * dt,
            np.where(
                dt < ta + tc,
                la + vt * (dt - ta),
                la + vt * tc + vt * (dt - ta - tc) - 0.5 * a * (dt - ta - tc) ** 2,
            ),
        )
        s = np.clip(s, 0, L)
        frac = np.where(L > 0, s / np.where(L > 0, L, 1), 1.0)
        moving = ~self.filament_only[k]
        pts = self.p0[k] + (s * moving)[:, None] * self.d[k]
        kin.inverse_into(pts, q)
        de[:] = self.e0[k] + frac * self.e[k]
        tool[:] = self.tool[k]


class PieceBatch:
    """Lists of pieces (``groups``: one list per job) that pickle column by column.

    A RunPiece holds about fifteen arrays, and numpy pickles each with a few microseconds of
    Python around it: handing thousands of runs from the planning workers to the parent that way
    costs more than copying their arrays. Here the
    runs' arrays of one field travel as one array with their lengths beside it, and come back as
    views of it: the same values, C-contiguous and writable, as the compiled kernels took them.
    Other pieces are pickled as they are, and so is a batch where two runs share a path (pickle
    keeps that sharing; columns would not)."""

    __slots__ = ("groups",)

    def __init__(self, groups):
        self.groups = groups

    def __reduce__(self):
        flat = [p for g in self.groups for p in g]
        return _unpack_batch, (*_pack_runs(flat), [len(g) for g in self.groups])


_RUN_FIELDS = tuple(f.name for f in fields(RunPiece) if f.name != "path")
_PATH_FIELDS = tuple(f.name for f in fields(BlendedPath))


def _pack_runs(pieces: list) -> tuple:
    """(path columns, run columns, the pieces with the RunPiece class where each run was) of
    :class:`PieceBatch`; (None, None, pieces) where there is nothing to gain."""
    runs = [p for p in pieces if type(p) is RunPiece]
    if not runs or len({id(p.path) for p in runs}) < len(runs):
        return None, None, pieces
    rest = [RunPiece if type(p) is RunPiece else p for p in pieces]  # the class: pickled by name, no piece
    return _columns([p.path for p in runs], _PATH_FIELDS), _columns(runs, _RUN_FIELDS), rest


def _columns(objs: list, names: tuple) -> list:
    """Per field of ``objs``: (lengths (n,) int64, the arrays concatenated) where every object's
    value is an array of one dtype and one shape past its first axis; else (None, the values)."""
    cols = []
    for name in names:
        vals = list(map(attrgetter(name), objs))
        data = None
        # the checks in C loops (a Python test per value cost a worker more than the rest of the
        # pickling); concatenate refuses other numbers of dimensions or other shapes past the first axis
        if set(map(type, vals)) == {np.ndarray} and len(set(map(attrgetter("dtype"), vals))) == 1:
            try:
                data = np.concatenate(vals)
            except ValueError:  # 0-d arrays, or shapes that differ past the first axis
                pass
        if data is None:
            cols.append((None, vals))
        else:
            # C order whatever the pieces' (concatenating F-ordered arrays keeps F: its rows' views would not be)
            cols.append((np.fromiter(map(len, vals), np.int64, len(vals)), np.ascontiguousarray(data)))
    return cols


def _rows(cols: list) -> zip:
    """Each object's field values back from :func:`_columns`' columns (arrays as views)."""
    out = []
    for lengths, data in cols:
        if lengths is None:
            out.append(data)
        else:
            ends = np.cumsum(lengths).tolist()
            out.append(list(map(data.__getitem__, map(slice, [0, *ends[:-1]], ends))))
    return zip(*out)


def _unpack_batch(path_cols, run_cols, rest, sizes) -> PieceBatch:
    if path_cols is not None:
        runs = (RunPiece(BlendedPath(*path), *row) for path, row in zip(_rows(path_cols), _rows(run_cols)))
        rest = [next(runs) if p is RunPiece else p for p in rest]
    groups, i = [], 0
    for n in sizes:
        groups.append(rest[i : i + n])
        i += n
    return PieceBatch(groups)
