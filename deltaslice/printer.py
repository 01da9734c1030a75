"""Printer files: read ``printers/*.toml`` into a frozen, validated :class:`Printer`.

A printer file describes one machine: kinematic geometry, joint limits, actuator
counts, the tool (extruder or laser), default slicing and planning settings, and
the source of every number. Lengths are mm, times s; angles are degrees in the
file and radians in the returned object (joint units: rad for revolute joints,
mm for prismatic ones). Every problem is reported once, at load, as a
:class:`~deltaslice.errors.PrinterFileError` naming the file, the key, the value
and the bound it broke.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import PrinterFileError

FAMILIES = ("rotary_delta", "linear_delta", "five_bar", "cartesian")
ACTUATOR_KINDS = ("servo_pwm", "stepper", "dc_encoder", "dynamixel")

# Joint kinds per family, in joint order.
_JOINT_KINDS = {
    "rotary_delta": ("revolute", "revolute", "revolute"),
    "linear_delta": ("prismatic", "prismatic", "prismatic"),
    "five_bar": ("revolute", "revolute", "prismatic"),
    "cartesian": ("prismatic", "prismatic", "prismatic"),
}


# --------------------------------------------------------------------------- geometry


@dataclass(frozen=True)
class RotaryDeltaGeometry:
    """Clavel (3-RSS) delta. Lengths in mm, angles in rad.

    Motor i's shoulder axis sits at ``base_radius`` from the base centre at
    ``i * 120 deg`` counter-clockwise from +x, ``shoulder_height`` above the bed.
    ``tool_offset`` is the distance from the platform's ball-joint plane down to
    the tool tip; ``ball_joint_tilt_max`` limits the forearms' sideways tilt
    (None: no limit).
    """

    base_radius: float
    platform_radius: float
    upper_arm: float
    forearm: float
    shoulder_height: float
    tool_offset: float = 0.0
    ball_joint_tilt_max: float | None = None


@dataclass(frozen=True)
class LinearDeltaGeometry:
    """Rostock/Kossel delta: carriages on three vertical towers. mm.

    ``delta_radius`` is the horizontal distance from a carriage's rod joint to
    the effector's rod joint when the effector is centred (tower radius minus
    effector and carriage offsets). Tower i stands at ``i * 120 deg``
    counter-clockwise from +x. A joint value is the height of the carriage's rod
    joint above the bed; ``tool_offset`` is the tool tip below the effector joints.
    """

    delta_radius: float
    diagonal_rod: float
    tool_offset: float = 0.0


@dataclass(frozen=True)
class FiveBarGeometry:
    """Planar 5R linkage for x-y plus a lead-screw z. mm.

    Motor A at ``(origin_x, origin_y)`` on the bed, motor C at ``base_length``
    further along +x; links A-B (``proximal_a``), B-P (``distal_a``), C-D
    (``proximal_c``), D-P (``distal_c``). ``codo1`` and ``codo2`` (+1 or -1) pick
    the working mode as in the Atlas paper: the sign of the elbow angle added to
    the direction from each motor to P.
    """

    base_length: float
    proximal_a: float
    distal_a: float
    proximal_c: float
    distal_c: float
    origin_x: float
    origin_y: float
    codo1: int = 1
    codo2: int = -1


@dataclass(frozen=True)
class CartesianGeometry:
    """Three orthogonal axes; the joint value is the bed-frame coordinate plus ``offset``. mm."""

    offset_x: float = 0.0
    offset_y: float = 0.0
    offset_z: float = 0.0


Geometry = RotaryDeltaGeometry | LinearDeltaGeometry | FiveBarGeometry | CartesianGeometry


# --------------------------------------------------------------------------- the rest


@dataclass(frozen=True)
class Joint:
    """One actuated joint. Units: rad (revolute) or mm (prismatic), per s, per s^2, per s^3.

    ``counts_per_unit`` converts a joint value to actuator counts (PWM microseconds,
    microsteps, encoder or Dynamixel ticks): ``count = zero_count + counts_per_unit * q``.
    """

    name: str
    kind: str
    position_min: float
    position_max: float
    velocity_max: float
    acceleration_max: float
    jerk_max: float | None
    counts_per_unit: float
    zero_count: float

    @property
    def unit(self) -> str:
        return "rad" if self.kind == "revolute" else "mm"


@dataclass(frozen=True)
class Extruder:
    """Filament extruder. mm, mm/s, mm^3/s."""

    nozzle_diameter: float
    filament_diameter: float
    max_volumetric_flow: float
    max_filament_acceleration: float
    retract_length: float
    retract_speed: float
    z_hop: float
    retract_min_travel: float
    counts_per_mm: float

    @property
    def filament_area(self) -> float:
        return math.pi * self.filament_diameter**2 / 4.0

    @property
    def max_filament_speed(self) -> float:
        """Filament feed speed at the maximum volumetric flow, mm/s."""
        return self.max_volumetric_flow / self.filament_area


@dataclass(frozen=True)
class Laser:
    """Laser module switched or PWM-dimmed by the controller."""

    max_power: float
    power_counts: float
    travel_height: float


Tool = Extruder | Laser


@dataclass(frozen=True)
class Bed:
    """Printable area on the bed, centred on the bed-frame origin. mm."""

    shape: str
    radius: float
    size_x: float
    size_y: float
    max_height: float

    def contains_xy(self, xy: np.ndarray) -> np.ndarray:
        """xy: (n, 2) float, mm -> (n,) bool."""
        xy = np.asarray(xy, dtype=float)
        if self.shape == "circle":
            return np.hypot(xy[:, 0], xy[:, 1]) <= self.radius + 1e-9
        return (np.abs(xy[:, 0]) <= self.size_x / 2 + 1e-9) & (np.abs(xy[:, 1]) <= self.size_y / 2 + 1e-9)


@dataclass(frozen=True)
class SlicingSettings:
    """Default slicing settings. mm, mm/s, fractions."""

    layer_height: float
    first_layer_height: float
    perimeters: int
    top_solid_layers: int
    bottom_solid_layers: int
    fill_density: float
    fill_angle: float
    infill_overlap: float
    perimeter_speed: float
    external_perimeter_speed: float
    infill_speed: float
    solid_infill_speed: float
    first_layer_speed: float
    travel_speed: float
    perimeter_width: float
    infill_width: float
    first_layer_width: float
    extrusion_multiplier: float
    skirt_loops: int
    skirt_distance: float
    seam: str
    gcode_resolution: float = 0.0125  # mm: paths simplified within this deviation (PrusaSlicer gcode_resolution)
    solid_infill_below_area: float = 70.0  # mm^2: infill regions smaller than this are filled solid
    bridge_speed: float = 30.0  # mm/s
    bridge_flow: float = 1.0  # multiplier on a round bead of nozzle diameter over air
    overhang_speed: float = 15.0  # mm/s: perimeters over air


@dataclass(frozen=True)
class PlanningSettings:
    """Planner settings: output sample rate (Hz), corner blend tolerance (mm),
    fraction of each limit kept in reserve for discretisation (toppra only
    enforces limits at grid points)."""

    output_rate: float
    blend_tolerance: float
    limit_margin: float
    travel_lift: float
    singularity_limit: float


@dataclass(frozen=True)
class Printer:
    """A validated printer file. Frozen: share it freely between stages and processes."""

    name: str
    path: str
    description: str
    family: str
    geometry: Geometry
    joints: tuple[Joint, ...]
    actuator: str
    tool: Tool
    bed: Bed
    slicing: SlicingSettings
    planning: PlanningSettings
    sources: dict = field(default_factory=dict, compare=False, hash=False)

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def is_laser(self) -> bool:
        return isinstance(self.tool, Laser)

    def joint_array(self, attribute: str) -> np.ndarray:
        """One attribute of every joint as a (J,) float array, e.g. ``"velocity_max"``."""
        return np.array([getattr(j, attribute) for j in self.joints], dtype=float)

    def kinematics(self):
        """The kinematics object of this printer's family (see :mod:`deltaslice.kinematics`)."""
        from .kinematics import make_kinematics

        return make_kinematics(
            self.geometry,
            self.joint_array("position_min"),
            self.joint_array("position_max"),
            self.planning.singularity_limit,
        )

    def fingerprint(self) -> int:
        """A 32-bit CRC of the geometry and joint counts: a stream compiled for one
        printer is refused by another."""
        import zlib

        text = repr((self.family, self.geometry, [(j.counts_per_unit, j.zero_count) for j in self.joints]))
        return zlib.crc32(text.encode())


# --------------------------------------------------------------------------- reading


class _Section:
    """Typed access to one TOML table, in the manner of Klipper's config getters:
    every failure names the file, the key, the value and the bound."""

    def __init__(self, path: str, name: str, data: Any):
        self.path = path
        self.name = name
        if not isinstance(data, dict):
            self._fail(None, data, "a table")
        self.data = data
        self.used: set[str] = set()

    def _where(self, key: str | None) -> str:
        return f"[{self.name}]" if key is None else f"[{self.name}] {key}"

    def _fail(self, key, value, expected):
        shown = "missing" if value is _MISSING else f"= {value!r}"
        raise PrinterFileError(f"{self.path}: {self._where(key)} {shown}: expected {expected}")

    def _get(self, key, default):
        self.used.add(key)
        if key in self.data:
            return self.data[key]
        if default is _MISSING:
            self._fail(key, _MISSING, "a value (required key)")
        return default

    def getstr(self, key, default=None, choices=None, required=True):
        value = self._get(key, _MISSING if required else default)
        if value is None and not required:
            return None
        if not isinstance(value, str):
            self._fail(key, value, "a string")
        if choices is not None and value not in choices:
            self._fail(key, value, "one of " + ", ".join(choices))
        return value

    def getfloat(self, key, default=None, *, required=None, above=None, minval=None, maxval=None):
        required = default is None if required is None else required
        value = self._get(key, _MISSING if required else default)
        if value is None:
            return None
        return self._check_float(key, value, above, minval, maxval)

    def _check_float(self, key, value, above, minval, maxval):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self._fail(key, value, "a number")
        value = float(value)
        if not math.isfinite(value):
            self._fail(key, value, "a finite number")
        if above is not None and not value > above:
            self._fail(key, value, f"a number > {above:g}")
        if minval is not None and value < minval:
            self._fail(key, value, f"a number >= {minval:g}")
        if maxval is not None and value > maxval:
            self._fail(key, value, f"a number <= {maxval:g}")
        return value

    def getint(self, key, default=None, *, minval=None, maxval=None, choices=None):
        value = self._get(key, _MISSING if default is None else default)
        if isinstance(value, bool) or not isinstance(value, int):
            self._fail(key, value, "an integer")
        if minval is not None and value < minval:
            self._fail(key, value, f"an integer >= {minval}")
        if maxval is not None and value > maxval:
            self._fail(key, value, f"an integer <= {maxval}")
        if choices is not None and value not in choices:
            self._fail(key, value, "one of " + ", ".join(map(str, choices)))
        return value

    def getfloats(self, key, n, default=None, *, above=None, minval=None, maxval=None):
        value = self._get(key, _MISSING if default is None else default)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [value] * n
        if not isinstance(value, list) or len(value) != n:
            self._fail(key, value, f"a list of {n} numbers (one per joint) or one number")
        return tuple(self._check_float(key, v, above, minval, maxval) for v in value)

    def check_unknown(self):
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise PrinterFileError(
                f"{self.path}: [{self.name}] unknown key {unknown[0]!r}: expected one of "
                + ", ".join(sorted(self.used))
            )


class _Missing:
    def __repr__(self):
        return "<missing>"


_MISSING = _Missing()


def _read_geometry(sec: _Section, family: str) -> Geometry:
    if family == "rotary_delta":
        tilt = sec.getfloat("ball_joint_tilt_max", required=False, above=0, maxval=90)
        g = RotaryDeltaGeometry(
            base_radius=sec.getfloat("base_radius", minval=0),
            platform_radius=sec.getfloat("platform_radius", minval=0),
            upper_arm=sec.getfloat("upper_arm", above=0),
            forearm=sec.getfloat("forearm", above=0),
            shoulder_height=sec.getfloat("shoulder_height", above=0),
            tool_offset=sec.getfloat("tool_offset", 0.0, minval=0),
            ball_joint_tilt_max=None if tilt is None else math.radians(tilt),
        )
        if g.forearm <= g.upper_arm * 0.5:
            sec._fail("forearm", g.forearm, f"a forearm longer than half the upper arm ({g.upper_arm / 2:g} mm)")
        return g
    if family == "linear_delta":
        g = LinearDeltaGeometry(
            delta_radius=sec.getfloat("delta_radius", above=0),
            diagonal_rod=sec.getfloat("diagonal_rod", above=0),
            tool_offset=sec.getfloat("tool_offset", 0.0, minval=0),
        )
        if g.diagonal_rod <= g.delta_radius:
            sec._fail("diagonal_rod", g.diagonal_rod, f"a rod longer than delta_radius ({g.delta_radius:g} mm)")
        return g
    if family == "five_bar":
        return FiveBarGeometry(
            base_length=sec.getfloat("base_length", minval=0),
            proximal_a=sec.getfloat("proximal_a", above=0),
            distal_a=sec.getfloat("distal_a", above=0),
            proximal_c=sec.getfloat("proximal_c", above=0),
            distal_c=sec.getfloat("distal_c", above=0),
            origin_x=sec.getfloat("origin_x", required=True),
            origin_y=sec.getfloat("origin_y", required=True),
            codo1=sec.getint("codo1", choices=(1, -1)),
            codo2=sec.getint("codo2", choices=(1, -1)),
        )
    return CartesianGeometry(
        offset_x=sec.getfloat("offset_x", 0.0),
        offset_y=sec.getfloat("offset_y", 0.0),
        offset_z=sec.getfloat("offset_z", 0.0),
    )


def _read_joints(sec: _Section, family: str) -> tuple[Joint, ...]:
    kinds = _JOINT_KINDS[family]
    n = len(kinds)
    names = sec._get("names", [f"q{i + 1}" for i in range(n)])
    if not isinstance(names, list) or len(names) != n or not all(isinstance(s, str) for s in names):
        sec._fail("names", names, f"a list of {n} strings")
    lo = sec.getfloats("position_min", n)
    hi = sec.getfloats("position_max", n)
    vel = sec.getfloats("velocity_max", n, above=0)
    acc = sec.getfloats("acceleration_max", n, above=0)
    jerk = sec.getfloats("jerk_max", n, default=[0.0] * n, minval=0) if "jerk_max" in sec.data else (None,) * n
    cpu = sec.getfloats("counts_per_unit", n, above=0)
    zero = sec.getfloats("zero_count", n, default=[0.0] * n)
    for i in range(n):
        if not lo[i] < hi[i]:
            sec._fail(
                "position_min", list(lo), f"position_min < position_max for every joint (joint {i + 1}: {lo[i]:g} >= {hi[i]:g})"
            )
    joints = []
    for i, kind in enumerate(kinds):
        # Revolute joints are in degrees in the file and radians inside.
        k = math.radians(1.0) if kind == "revolute" else 1.0
        joints.append(
            Joint(
                name=names[i],
                kind=kind,
                position_min=lo[i] * k,
                position_max=hi[i] * k,
                velocity_max=vel[i] * k,
                acceleration_max=acc[i] * k,
                jerk_max=None if jerk[i] is None else jerk[i] * k,
                counts_per_unit=cpu[i] / k,
                zero_count=zero[i],
            )
        )
    return tuple(joints)


def _read_tool(sec: _Section) -> Tool:
    kind = sec.getstr("kind", choices=("extruder", "laser"))
    if kind == "laser":
        return Laser(
            max_power=sec.getfloat("max_power", above=0),
            power_counts=sec.getfloat("power_counts", above=0),
            travel_height=sec.getfloat("travel_height", 0.0, minval=0),
        )
    nozzle = sec.getfloat("nozzle_diameter", above=0, maxval=5)
    return Extruder(
        nozzle_diameter=nozzle,
        filament_diameter=sec.getfloat("filament_diameter", above=0, maxval=5),
        max_volumetric_flow=sec.getfloat("max_volumetric_flow", above=0),
        max_filament_acceleration=sec.getfloat("max_filament_acceleration", above=0),
        retract_length=sec.getfloat("retract_length", 0.0, minval=0),
        retract_speed=sec.getfloat("retract_speed", 30.0, above=0),
        z_hop=sec.getfloat("z_hop", 0.0, minval=0),
        retract_min_travel=sec.getfloat("retract_min_travel", 2.0, minval=0),
        counts_per_mm=sec.getfloat("counts_per_mm", above=0),
    )


def _read_slicing(sec: _Section, tool: Tool) -> SlicingSettings:
    nozzle = tool.nozzle_diameter if isinstance(tool, Extruder) else 0.2
    layer = sec.getfloat("layer_height", above=0, maxval=10)
    s = SlicingSettings(
        layer_height=layer,
        first_layer_height=sec.getfloat("first_layer_height", layer, above=0, maxval=10),
        perimeters=sec.getint("perimeters", 2, minval=0, maxval=50),
        top_solid_layers=sec.getint("top_solid_layers", 3, minval=0, maxval=100),
        bottom_solid_layers=sec.getint("bottom_solid_layers", 3, minval=0, maxval=100),
        fill_density=sec.getfloat("fill_density", 0.2, minval=0, maxval=1),
        fill_angle=math.radians(sec.getfloat("fill_angle", 45.0)),
        infill_overlap=sec.getfloat("infill_overlap", 0.25, minval=0, maxval=1),
        perimeter_speed=sec.getfloat("perimeter_speed", above=0),
        external_perimeter_speed=sec.getfloat("external_perimeter_speed", sec.data.get("perimeter_speed", 30.0), above=0),
        infill_speed=sec.getfloat("infill_speed", above=0),
        solid_infill_speed=sec.getfloat("solid_infill_speed", sec.data.get("infill_speed", 30.0), above=0),
        first_layer_speed=sec.getfloat("first_layer_speed", 20.0, above=0),
        travel_speed=sec.getfloat("travel_speed", above=0),
        perimeter_width=sec.getfloat("perimeter_width", nozzle * 1.125, above=0),
        infill_width=sec.getfloat("infill_width", nozzle * 1.125, above=0),
        first_layer_width=sec.getfloat("first_layer_width", nozzle * 1.2, above=0),
        extrusion_multiplier=sec.getfloat("extrusion_multiplier", 1.0, above=0, maxval=3),
        skirt_loops=sec.getint("skirt_loops", 1, minval=0, maxval=20),
        skirt_distance=sec.getfloat("skirt_distance", 3.0, minval=0),
        seam=sec.getstr("seam", "aligned", choices=("aligned", "nearest"), required=False),
        gcode_resolution=sec.getfloat("gcode_resolution", 0.0125, minval=0, maxval=1),
        # PrusaSlicer's 70 mm^2 is for a 0.4 mm nozzle: scale with the bead area so a small nozzle keeps
        # the same number of beads per solid patch
        solid_infill_below_area=sec.getfloat("solid_infill_below_area", 70.0 * (nozzle / 0.4) ** 2, minval=0),
        bridge_speed=sec.getfloat("bridge_speed", sec.data.get("perimeter_speed", 30.0), above=0),
        bridge_flow=sec.getfloat("bridge_flow", 1.0, above=0, maxval=3),
        overhang_speed=sec.getfloat("overhang_speed", 0.5 * float(sec.data.get("external_perimeter_speed", sec.data.get("perimeter_speed", 30.0))), above=0),
    )
    if s.first_layer_height > 0 and isinstance(tool, Extruder) and s.layer_height > tool.nozzle_diameter * 1.5:
        sec._fail("layer_height", layer, f"a layer height <= 1.5 x nozzle diameter ({1.5 * tool.nozzle_diameter:g} mm)")
    return s


def _read_planning(sec: _Section) -> PlanningSettings:
    return PlanningSettings(
        output_rate=sec.getfloat("output_rate", 1000.0, above=0, maxval=100000),
        blend_tolerance=sec.getfloat("blend_tolerance", 0.02, above=0, maxval=5),
        limit_margin=sec.getfloat("limit_margin", 0.01, minval=0, maxval=0.5),
        travel_lift=sec.getfloat("travel_lift", 1.0, minval=0),
        singularity_limit=sec.getfloat("singularity_limit", 50.0, above=1),
    )


def _read_bed(sec: _Section) -> Bed:
    shape = sec.getstr("shape", choices=("circle", "rectangle"))
    radius = sec.getfloat("radius", above=0) if shape == "circle" else 0.0
    size_x = sec.getfloat("size_x", above=0) if shape == "rectangle" else 2 * radius
    size_y = sec.getfloat("size_y", above=0) if shape == "rectangle" else 2 * radius
    return Bed(
        shape=shape,
        radius=radius if shape == "circle" else math.hypot(size_x, size_y) / 2,
        size_x=size_x,
        size_y=size_y,
        max_height=sec.getfloat("max_height", above=0),
    )


SECTIONS = ("kinematics", "joints", "tool", "bed", "slicing", "planning", "sources")


def load_printer(path: str | Path) -> Printer:
    """Read and validate a printer file.

    path: a ``.toml`` printer file. Returns a frozen :class:`Printer`.
    Raises :class:`PrinterFileError` naming the file, key, value and bound on any problem.
    """
    path = Path(path)
    shown = str(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise PrinterFileError(f"{shown}: no such printer file (the ones shipped are in printers/)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise PrinterFileError(f"{shown}: cannot read printer file: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise PrinterFileError(f"{shown}: not valid TOML: {exc}") from None
    return printer_from_dict(data, shown)


def printer_from_dict(data: dict, path: str = "<printer>") -> Printer:
    """Validate an already-parsed printer description (same rules as :func:`load_printer`)."""
    top = _Section(path, "top level", data)
    name = top.getstr("name")
    description = top.getstr("description", "", required=False) or ""
    for key in SECTIONS:
        top.used.add(key)
        if key not in data and key not in ("planning", "sources"):
            raise PrinterFileError(f"{path}: [{key}] missing: expected a table (required section)")
    top.check_unknown()

    kin = _Section(path, "kinematics", data["kinematics"])
    family = kin.getstr("family", choices=FAMILIES)
    geometry = _read_geometry(kin, family)
    kin.check_unknown()

    jsec = _Section(path, "joints", data["joints"])
    actuator = jsec.getstr("actuator", choices=ACTUATOR_KINDS)
    joints = _read_joints(jsec, family)
    jsec.check_unknown()

    tsec = _Section(path, "tool", data["tool"])
    tool = _read_tool(tsec)
    tsec.check_unknown()

    bsec = _Section(path, "bed", data["bed"])
    bed = _read_bed(bsec)
    bsec.check_unknown()

    ssec = _Section(path, "slicing", data["slicing"])
    slicing = _read_slicing(ssec, tool)
    ssec.check_unknown()

    psec = _Section(path, "planning", data.get("planning", {}))
    planning = _read_planning(psec)
    psec.check_unknown()

    sources = data.get("sources", {})
    if not isinstance(sources, dict) or not all(isinstance(v, str) for v in sources.values()):
        raise PrinterFileError(f"{path}: [sources] expected a table of key = \"where the number comes from\"")

    printer = Printer(
        name=name,
        path=path,
        description=description,
        family=family,
        geometry=geometry,
        joints=joints,
        actuator=actuator,
        tool=tool,
        bed=bed,
        slicing=slicing,
        planning=planning,
        sources=dict(sources),
    )
    _check_reaches_something(printer)
    return printer


def _check_reaches_something(printer: Printer) -> None:
    """A geometry whose workspace misses the bed entirely is a typo, not a machine."""
    kin = printer.kinematics()
    z = np.linspace(0.0, printer.bed.max_height, 41)
    pts = np.zeros((z.size, 3))
    pts[:, 2] = z
    if not kin.reachable(pts).any():
        raise PrinterFileError(
            f"{printer.path}: [kinematics] geometry reaches no point above the bed centre between z = 0 and "
            f"[bed] max_height = {printer.bed.max_height:g} mm: expected a geometry and joint range that reach the bed"
        )
