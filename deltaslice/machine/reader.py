"""Read a printer file (``printers/*.toml``) into a frozen, validated :class:`Printer`.

A printer file describes one machine: kinematic geometry (read by its family's module in
:mod:`deltaslice.kinematics`), joint limits and actuator counts, the tool (extruder or
laser), the bed, default slicing and planning settings, and the source of every number.
Lengths are mm, times s; angles are degrees in the file and radians in the returned
object (joint units: rad for revolute joints, mm for prismatic ones). Every problem is
reported at load as a :class:`~deltaslice.errors.PrinterFileError` naming the file, the
key, the value and the bound it broke.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..config import MISSING, Problems, Section, _shown, _Stop
from ..errors import PrinterFileError
from ..tolerances import RELATIVE_ROUNDOFF
from ..kinematics import FAMILIES, family, make_kinematics
from .dynamics import Dynamics, read_actuators
from .limits import Limits
from .printer import Printer
from .settings import Bed, CoolingSettings, HomingSettings, PlanningSettings, SafetySettings, SlicingSettings
from .tool import Extruder, Laser, Tool

ACTUATOR_KINDS = ("servo_pwm", "stepper", "dc_encoder", "dynamixel")


def _read_joints(sec: Section, kinds: tuple[str, ...]) -> dict:
    """Joint channels of the ``[joints]`` table as per-channel lists (radians inside)."""
    n = len(kinds)
    sec._record("names", "list", False, [f"q{i + 1}" for i in range(n)])
    names = sec.get("names", [f"q{i + 1}" for i in range(n)])
    if not isinstance(names, list) or len(names) != n or not all(isinstance(s, str) for s in names):
        sec.fail("names", names, f"a list of {n} strings")
    lo = sec.getfloats("position_min", n)
    hi = sec.getfloats("position_max", n)
    vel = sec.getfloats("velocity_max", n, above=0)
    acc = sec.getfloats("acceleration_max", n, above=0)
    jerk = sec.getfloats("jerk_max", n, default=[0.0] * n, minval=0)
    if "jerk_max" not in sec.data:
        jerk = (None,) * n
    cpu = sec.getfloats("counts_per_unit", n)
    zero = sec.getfloats("zero_count", n, default=[0.0] * n)
    rest = sec.getfloats("rest", n, default=[0.0] * n)
    if "rest" not in sec.data:  # the default pose is found from the kinematics (_rest_pose)
        rest = (math.nan,) * n
    sensor = _read_sensor_table(sec, n)
    if any(c == 0 for c in cpu):
        sec.fail("counts_per_unit", list(cpu), "a non-zero number for every joint (a negative one reverses the joint)")
    for i in range(n):
        if not lo[i] < hi[i]:
            sec.fail(
                "position_min", list(lo), f"position_min < position_max for every joint (joint {i + 1}: {lo[i]:g} >= {hi[i]:g})"
            )
    out = {key: [] for key in ("names", "kinds", "position_min", "position_max", "velocity", "acceleration", "jerk",
                                "counts_per_unit", "zero_count", "rest", "sensor_table")}
    for i, kind in enumerate(kinds):
        # Revolute joints are in degrees in the file and radians inside.
        k = math.radians(1.0) if kind == "revolute" else 1.0
        for key, value in (("names", names[i]), ("kinds", kind), ("position_min", lo[i] * k), ("position_max", hi[i] * k),
                           ("velocity", vel[i] * k), ("acceleration", acc[i] * k),
                           ("jerk", math.nan if jerk[i] is None else jerk[i] * k),
                           ("counts_per_unit", cpu[i] / k), ("zero_count", zero[i]), ("rest", rest[i] * k),
                           ("sensor_table", tuple((r, v * k) for r, v in sensor[i]))):
            out[key].append(value)
    return out


def _finite_number(x) -> bool:
    """A TOML int or float a float holds finitely (an integer of 310 digits does not)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return False
    try:
        return math.isfinite(float(x))
    except OverflowError:
        return False


def _read_sensor_table(sec: Section, n: int) -> tuple:
    """``[joints] sensor_table``: per joint, ``[[reading, joint value], ...]`` (raw sensor reading,
    joint value in file units), at least two points with distinct readings; () per joint when absent."""
    sec._record("sensor_table", "list", False, None)
    table = sec.get("sensor_table", None)
    if table is None:
        return ((),) * n
    expected = (f"a list of {n} tables (one per joint), each a list of at least 2 [reading, joint value] pairs of "
                "finite numbers with distinct readings")
    if not isinstance(table, list) or len(table) != n:
        sec.fail("sensor_table", table, expected)
    out = []
    for j, points in enumerate(table):
        ok = (isinstance(points, list) and len(points) >= 2 and all(
            isinstance(p, list) and len(p) == 2 and all(_finite_number(x) for x in p) for p in points))
        if not ok or len({float(p[0]) for p in points}) != len(points):
            sec.fail("sensor_table", table, f"{expected} (joint {j + 1}: {_shown(points)})")
        out.append(tuple(sorted((float(r), float(v)) for r, v in points)))
    return tuple(out)


def _limits(joints: dict, tool) -> Limits:
    """Joint channels, then the tool channel, in one :class:`Limits`."""
    ch = tool.channel_limits()
    return Limits(
        names=tuple(joints["names"]) + (tool.channel_name,),
        kinds=tuple(joints["kinds"]) + (tool.channel_kind,),
        position_min=joints["position_min"] + [ch["position_min"]],
        position_max=joints["position_max"] + [ch["position_max"]],
        velocity=joints["velocity"] + [ch["velocity"]],
        idle_velocity=joints["velocity"] + [ch["idle_velocity"]],
        acceleration=joints["acceleration"] + [ch["acceleration"]],
        jerk=joints["jerk"] + [ch["jerk"]],
        counts_per_unit=joints["counts_per_unit"] + [tool.counts_per_unit],
        zero_count=joints["zero_count"] + [0.0],
    )


def _read_tool(sec: Section) -> Tool:
    kind = sec.getstr("kind", choices=("extruder", "laser"))
    if kind == "laser":
        return Laser(
            max_power=sec.getfloat("max_power", above=0),
            power_counts=sec.getfloat("power_counts", above=0),
            travel_height=sec.getfloat("travel_height", 0.0, minval=0),
            spot_size=sec.getfloat("spot_size", 0.1, above=0, maxval=10),
            s_max=sec.getfloat("s_max", 1000.0, above=0),
        )
    nozzle = sec.getfloat("nozzle_diameter", above=0, maxval=5)
    extruder = Extruder(
        nozzle_diameter=nozzle,
        filament_diameter=sec.getfloat("filament_diameter", minval=0.1, maxval=5),  # its square divides
        max_volumetric_flow=sec.getfloat("max_volumetric_flow", above=0),
        max_filament_acceleration=sec.getfloat("max_filament_acceleration", above=0),
        retract_length=sec.getfloat("retract_length", 0.0, minval=0),
        # Marlin's FWRETRACT takes standing E moves up to MAX_AUTORETRACT = 10 mm as retractions; a
        # longer pull is a filament unload, not something a print asks for
        max_retract_length=sec.getfloat("max_retract_length", 10.0, above=0),
        retract_speed=sec.getfloat("retract_speed", 30.0, above=0),
        z_hop=sec.getfloat("z_hop", 0.0, minval=0),
        retract_min_travel=sec.getfloat("retract_min_travel", 2.0, minval=0),
        counts_per_mm=sec.getfloat("counts_per_mm", above=0),
        hotend_temperature=sec.getfloat("hotend_temperature", 200.0, minval=0, maxval=500),
        bed_temperature=sec.getfloat("bed_temperature", 0.0, minval=0, maxval=200),
    )
    if extruder.max_retract_length < extruder.retract_length:
        sec.fail("max_retract_length", extruder.max_retract_length,
                 f"a length >= [tool] retract_length ({extruder.retract_length:g} mm)")
    return extruder


def _number(value, fallback: float) -> float:
    """A default taken from another key's raw value: that value if it is a finite number, else
    ``fallback`` (the other key's own getter reports what is wrong with it)."""
    return float(value) if _finite_number(value) else fallback


def _read_slicing(sec: Section, tool: Tool) -> SlicingSettings:
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
        overhang_speed=sec.getfloat("overhang_speed", 0.5 * _number(sec.data.get("external_perimeter_speed",
                                                                                 sec.data.get("perimeter_speed")), 30.0), above=0),
        fill_pattern=sec.getstr("fill_pattern", "rectilinear", choices=("rectilinear", "grid"), required=False),
        brim_width=sec.getfloat("brim_width", 0.0, minval=0, maxval=100),
        support=sec.getstr("support", "none", choices=("none", "auto"), required=False),
        support_angle=math.radians(sec.getfloat("support_angle", 50.0, minval=0, maxval=89)),
        support_z_gap=sec.getfloat("support_z_gap", layer, minval=0, maxval=5),
        support_xy_gap=sec.getfloat("support_xy_gap", 0.5 * _number(sec.data.get("perimeter_width"), nozzle * 1.125),
                                    minval=0, maxval=20),
        support_interface_layers=sec.getint("support_interface_layers", 3, minval=0, maxval=50),
        support_spacing=sec.getfloat("support_spacing", 2.5, above=0, maxval=50),
        support_type=sec.getstr("support_type", "everywhere", choices=("everywhere", "buildplate"), required=False),
        support_pattern=sec.getstr("support_pattern", "rectilinear", choices=("rectilinear", "grid"), required=False),
    )
    if s.support_spacing < s.infill_width:
        sec.fail("support_spacing", s.support_spacing, f"a spacing >= infill_width ({s.infill_width:g} mm): lines that far apart")
    if s.first_layer_height > 0 and isinstance(tool, Extruder) and s.layer_height > tool.nozzle_diameter * 1.5:
        sec.fail("layer_height", layer, f"a layer height <= 1.5 x nozzle diameter ({1.5 * tool.nozzle_diameter:g} mm)")
    return s


def _read_cooling(sec: Section) -> CoolingSettings:
    """``[cooling]``: PrusaSlicer's names and defaults (fan speeds in percent)."""
    d = CoolingSettings()
    pct = {"minval": 0, "maxval": 100}
    low = sec.getfloat("min_fan_speed", d.min_fan_speed, **pct)
    high = sec.getfloat("max_fan_speed", d.max_fan_speed, **pct)
    c = CoolingSettings(
        min_fan_speed=low,
        max_fan_speed=high,
        bridge_fan_speed=sec.getfloat("bridge_fan_speed", d.bridge_fan_speed, **pct),
        overhang_fan_speed=sec.getfloat("overhang_fan_speed", d.overhang_fan_speed, **pct),
        disable_fan_first_layers=sec.getint("disable_fan_first_layers", d.disable_fan_first_layers, minval=0, maxval=1000),
        fan_below_layer_time=sec.getfloat("fan_below_layer_time", d.fan_below_layer_time, minval=0, maxval=3600),
        slowdown_below_layer_time=sec.getfloat("slowdown_below_layer_time", d.slowdown_below_layer_time, minval=0,
                                               maxval=3600),
        min_print_speed=sec.getfloat("min_print_speed", d.min_print_speed, above=0),
    )
    if low > high:
        sec.fail("min_fan_speed", low, f"a speed <= max_fan_speed ({high:g} %)")
    return c


def _read_dynamics(sec: Section, module, geometry, actuator) -> Dynamics | None:
    """``[dynamics]``: the family's masses (its module's ``read_dynamics``) and the actuators' curves."""
    reader = getattr(module, "read_dynamics", None)
    masses = None
    if reader is None:
        sec.used.update(sec.data)
        sec.fail(None, sec.data, f"no [dynamics] table: the {module.FAMILY} family has no dynamics model")
    if geometry is not None:
        masses = sec._soft(lambda: reader(sec, geometry), None)
    else:
        sec.used.update(sec.data)  # the geometry's problems are reported; the masses need it
    actuators = read_actuators(sec, module.KINEMATICS.joint_kinds, actuator)
    return None if masses is None else Dynamics(masses=masses, actuators=actuators)


def _read_planning(sec: Section) -> PlanningSettings:
    return PlanningSettings(
        output_rate=sec.getfloat("output_rate", 1000.0, minval=50, maxval=100000),
        blend_tolerance=sec.getfloat("blend_tolerance", 0.02, above=0, maxval=5),
        limit_margin=sec.getfloat("limit_margin", 0.01, minval=0, maxval=0.5),
        travel_lift=sec.getfloat("travel_lift", 1.0, minval=0),
        singularity_limit=sec.getfloat("singularity_limit", 50.0, above=1),
        # Marlin's Z_CLEARANCE_BETWEEN_PROBES (5 mm) and its Z homing feed (HOMING_FEEDRATE_MM_M, 4*60 mm/min)
        approach_height=sec.getfloat("approach_height", 5.0, minval=0, maxval=100),
        approach_speed=sec.getfloat("approach_speed", 4.0, above=0, maxval=100),
        torque_limit=sec.getstr("torque_limit", "on", choices=("on", "off"), required=False),
        jerk_limit=sec.getstr("jerk_limit", "off", choices=("on", "off"), required=False),
    )


def _read_bed(sec: Section) -> Bed:
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


def _read_safety(sec: Section, tool: Tool | None) -> SafetySettings:
    """``[safety]``: the firmware players' heater protection and host time-out (defaults:
    :class:`SafetySettings`). The print temperatures must sit below the maxima with Marlin's
    margins (HOTEND_OVERSHOOT 15 C, BED_OVERSHOOT 10 C), or bang-bang overshoot would trip them."""
    d = SafetySettings()
    got = {}
    for heater in ("hotend", "bed"):
        lo = sec.getfloat(f"{heater}_min_temp", getattr(d, f"{heater}_min_temp"), minval=0, maxval=100)
        hi = sec.getfloat(f"{heater}_max_temp", getattr(d, f"{heater}_max_temp"), above=0, maxval=500)
        if lo >= hi:
            sec.fail(f"{heater}_min_temp", lo, f"below {heater}_max_temp = {hi:g} C")
        got[f"{heater}_min_temp"], got[f"{heater}_max_temp"] = lo, hi
    for key in ("hotend_heating_period", "bed_heating_period", "hotend_hold_period", "bed_hold_period"):
        got[key] = sec.getfloat(key, getattr(d, key), minval=1, maxval=600)
    for key in ("hotend_heating_gain", "bed_heating_gain", "hotend_hold_drop", "bed_hold_drop"):
        got[key] = sec.getfloat(key, getattr(d, key), above=0, maxval=50)
    got["wait_timeout"] = sec.getfloat("wait_timeout", d.wait_timeout, minval=10, maxval=3600)
    got["host_timeout"] = sec.getfloat("host_timeout", d.host_timeout, minval=1, maxval=60)
    if isinstance(tool, Extruder):
        for heater, margin in (("hotend", 15.0), ("bed", 10.0)):
            temp, hi = getattr(tool, f"{heater}_temperature"), got[f"{heater}_max_temp"]
            if temp > 0 and temp > hi - margin:
                sec.fail(f"{heater}_max_temp", hi, f"at least [tool] {heater}_temperature + {margin:g} C = "
                         f"{temp + margin:g} C (the bang-bang overshoot must not trip it)")
    return SafetySettings(**got)


def _read_homing(sec: Section, joints: dict | None) -> HomingSettings | None:
    """``[homing]``: per joint the end stop's side (+1 high end, -1 low end, 0 none), the joint
    position where it trips (file units, within the joint's limits) and the approach speed (file
    units per s, default a tenth of velocity_max, at most velocity_max). None without joints."""
    if joints is None:
        sec.used.update(sec.data)
        return None
    n = len(joints["kinds"])
    ks = [math.radians(1.0) if kind == "revolute" else 1.0 for kind in joints["kinds"]]
    side = sec.getfloats("endstop", n, default=[0.0] * n, minval=-1, maxval=1)
    lo = [v / k for v, k in zip(joints["position_min"], ks)]
    hi = [v / k for v, k in zip(joints["position_max"], ks)]
    vmax = [v / k for v, k in zip(joints["velocity"], ks)]
    default = [lo[i] if side[i] < 0 else hi[i] for i in range(n)]
    pos = sec.getfloats("endstop_position", n, default=default)
    speed = sec.getfloats("speed", n, default=[v / 10 for v in vmax], above=0)
    if any(v not in (-1.0, 0.0, 1.0) for v in side):
        sec.fail("endstop", list(side), "-1 (a switch at the joint's low end), 1 (high end) or 0 (none) per joint")
    for i in range(n):
        if side[i] and not lo[i] <= pos[i] <= hi[i]:
            sec.fail("endstop_position", list(pos), f"within the joint limits (joint {i + 1}: {lo[i]:g}..{hi[i]:g})")
        if speed[i] > vmax[i] * (1 + RELATIVE_ROUNDOFF):
            sec.fail("speed", list(speed), f"at most [joints] velocity_max (joint {i + 1}: {vmax[i]:g})")
    return HomingSettings(endstop=tuple(int(v) for v in side), position=tuple(p * k for p, k in zip(pos, ks)),
                          speed=tuple(v * k for v, k in zip(speed, ks)))


SECTIONS = ("kinematics", "joints", "tool", "bed", "slicing", "cooling", "planning", "dynamics", "safety", "homing",
            "sources")


def resolve_printer(path) -> Path:
    """The file a ``--printer`` value names: an existing path, else a shipped printer's name
    (``delta_etitc``, see ``deltaslice printers``). Raises PrinterFileError for neither."""
    from ..printers import shipped_names, shipped_path

    if path is None or not isinstance(path, (str, Path)) or not str(path):
        raise PrinterFileError(f"printer: expected a printer file path or a shipped printer's name, got {path!r}")
    p = Path(path)
    if p.exists() or p.suffix or len(p.parts) > 1:
        return p
    shipped = shipped_path(str(path))
    if shipped is None:
        close = difflib.get_close_matches(str(path), shipped_names(), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise PrinterFileError(
            f"{path}: no such printer file or shipped printer{hint}: shipped are {', '.join(shipped_names())}"
        )
    return shipped


def _checked_overrides(overrides) -> dict | None:
    """``overrides`` as the library takes them: None, or a mapping of "section.key" strings to
    values (what --set builds); anything else is refused as the CLI refuses a malformed --set."""
    if overrides is None:
        return None
    if not isinstance(overrides, Mapping):
        raise PrinterFileError(f"overrides = {_shown(overrides)}: expected a dict of {{'section.key': value}}, "
                               "e.g. {'slicing.layer_height': 0.3}")
    for key in overrides:
        if not isinstance(key, str):
            raise PrinterFileError(f"overrides: key {_shown(key)}: expected a 'section.key' string, e.g. 'slicing.layer_height'")
    return dict(overrides)


def apply_overrides(data: dict, overrides, path: str) -> dict:
    """A copy of a parsed printer file with ``{"section.key": value}`` set (``--set``); the
    result is validated like the file itself. Raises PrinterFileError on a malformed key."""
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()}
    for dotted, value in (_checked_overrides(overrides) or {}).items():
        section, _, key = str(dotted).partition(".")
        if not section or not key or "." in key:
            raise PrinterFileError(f"--set {dotted}: expected section.key=value (e.g. slicing.layer_height=0.3)")
        if section not in SECTIONS:
            close = difflib.get_close_matches(section, SECTIONS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise PrinterFileError(f"--set {dotted}: no section [{section}]{hint}: expected one of {', '.join(SECTIONS)}")
        table = out.setdefault(section, {})
        if not isinstance(table, dict):
            raise PrinterFileError(f"{path}: [{section}] expected a table (setting --set {dotted})")
        table[key] = value
    return out


def load_printer(path: str | Path, overrides: dict | None = None, *, reach_checks: bool = True) -> Printer:
    """Read and validate a printer file.

    path: a ``.toml`` printer file or the name of a shipped printer. overrides:
    ``{"section.key": value}`` applied before validation. Returns a frozen :class:`Printer`.
    Raises :class:`PrinterFileError` naming the file, key, value and bound of every problem.
    reach_checks: False leaves out what needs the compiled kinematics (the default rest pose and
    the check that the geometry reaches the bed): :func:`check_reach` does it later, so that a
    compile can start its slicing workers before this process loads numba.
    """
    overrides = _checked_overrides(overrides)
    if not isinstance(reach_checks, bool):
        raise PrinterFileError(f"load_printer: reach_checks = {reach_checks!r}: expected True or False")
    path = resolve_printer(path)
    shown = str(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise PrinterFileError(f"{shown}: no such printer file (the shipped ones: deltaslice printers)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise PrinterFileError(f"{shown}: cannot read printer file: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise PrinterFileError(f"{shown}: not valid TOML: {exc}") from None
    if overrides:
        data = apply_overrides(data, overrides, shown)
    return printer_from_dict(data, shown, overridden=[str(k).split(".", 1) for k in dict(overrides or {})],
                             reach_checks=reach_checks)


def printer_from_dict(data: dict, path: str = "<printer>", *, overridden=(), reach_checks: bool = True) -> Printer:
    """Validate an already-parsed printer description (same rules as :func:`load_printer`).

    Every section is read even after a problem, and one PrinterFileError lists them all.
    overridden: ``(section, key)`` pairs set by ``--set``, whose problems are reported as the
    ``--set``'s rather than the file's. reach_checks: as :func:`load_printer`'s."""
    if not isinstance(data, dict):
        raise PrinterFileError(f"{path}: expected a table of sections, got {type(data).__name__}")
    problems = Problems(str(path), overridden)

    def section(name, default=MISSING):
        raw = data.get(name, {} if default is not MISSING else None)
        if raw is None:
            problems.add("top level", name, f"[{name}] missing: expected a table (required section)", missing=True)
            return None
        try:
            return Section(path, name, raw, problems)
        except _Stop:
            return None

    def read(sec, fn, *args):
        """fn(sec, *args) with sec's problems collected; None if the section could not be read."""
        if sec is None:
            return None
        try:
            value = fn(sec, *args)
        except _Stop:
            value = None
        sec.check_unknown()
        return value

    top = Section(path, "top level", data, problems)
    name = top._soft(lambda: top.getstr("name"), "")
    description = top.getstr("description", "", required=False) or ""
    top.used.update(SECTIONS)
    top.check_unknown()

    ksec, jsec, tsec = section("kinematics"), section("joints"), section("tool")
    bsec, ssec, psec = section("bed"), section("slicing"), section("planning", default={})
    csec = section("cooling", default={})
    fsec = section("safety", default={})
    hsec = section("homing", default={})

    family_name = module = None
    if ksec is not None:
        family_name = ksec._soft(lambda: ksec.getstr("family", choices=FAMILIES), None)
        if family_name is not None and not any(k == "family" for _s, k, _m, _x in problems.items):
            module = family(family_name)
    geometry = read(ksec, module.read_geometry) if module is not None else None
    if module is None and ksec is not None:
        ksec.used.update(ksec.data)  # the family decides which keys are valid
    actuator = jsec._soft(lambda: jsec.getstr("actuator", choices=ACTUATOR_KINDS), None) if jsec is not None else None
    joints = read(jsec, _read_joints, module.KINEMATICS.joint_kinds) if module is not None else None
    if module is None and jsec is not None:
        jsec.used.update(jsec.data)
    tool = read(tsec, _read_tool)
    bed = read(bsec, _read_bed)
    slicing = read(ssec, _read_slicing, tool) if tool is not None else read(ssec, _read_slicing, Laser(1.0, 1.0, 0.0))
    planning = read(psec, _read_planning)
    cooling = read(csec, _read_cooling)
    dynamics = None
    if "dynamics" in data:
        dsec = section("dynamics")
        dynamics = read(dsec, _read_dynamics, module, geometry, actuator) if module is not None else None
    safety = read(fsec, _read_safety, tool)
    homing = read(hsec, _read_homing, joints)

    sources = data.get("sources", {})
    if not isinstance(sources, dict) or not all(isinstance(v, str) for v in sources.values()):
        problems.add("sources", None, '[sources] expected a table of key = "where the number comes from"')
    problems.raise_if_any()

    slicing = replace(slicing, cooling=cooling)
    limits = _limits(joints, tool)
    J = limits.n_joints
    kinematics = make_kinematics(geometry, limits.position_min[:J], limits.position_max[:J], planning.singularity_limit)
    rest = np.array(joints["rest"])
    rest = _given_rest_pose(path, rest, kinematics) if not np.all(np.isnan(rest)) else None
    printer = Printer(
        name=name,
        path=path,
        description=description,
        family=family_name,
        geometry=geometry,
        limits=limits,
        actuator=actuator,
        tool=tool,
        bed=bed,
        slicing=slicing,
        planning=planning,
        kinematics_=kinematics,
        rest_pose=rest,
        sensor_table=tuple(joints["sensor_table"]),
        dynamics=dynamics,
        sources=dict(sources),
        reach_checked=False,
        safety=safety,
        homing=homing,
    )
    return check_reach(printer) if reach_checks else printer


def check_reach(printer: Printer) -> Printer:
    """The printer as :func:`load_printer` gives it: with its default rest pose where the file
    gives none, and PrinterFileError where its geometry reaches nothing above the bed. Returns
    ``printer`` itself where that is done already (these use the compiled kinematics)."""
    if printer.reach_checked:
        return printer
    rest = printer.rest_pose
    if rest is None:
        rest = _default_rest_pose(printer.kinematics(), printer.bed)
    checked = replace(printer, rest_pose=rest, reach_checked=True)
    _check_reaches_something(checked)
    return checked


def _default_rest_pose(kin, bed) -> np.ndarray:
    """The joint positions the machine rests at (where it is when the player starts and where it
    parks) when ``[joints] rest`` gives none: the highest reachable point above the bed centre up
    to ``max_height``."""
    z = np.linspace(bed.max_height, 0.0, 81)
    pts = np.column_stack([np.zeros((len(z), 2)), z])
    ok = kin.reachable(pts)
    if not ok.any():
        return np.full(kin.n_joints, np.nan)  # reported by _check_reaches_something
    return kin.inverse(pts[np.flatnonzero(ok)[0]][None])[0]


def _given_rest_pose(path: str, rest: np.ndarray, kin) -> np.ndarray:
    """``[joints] rest`` (file units): it must be within the joint limits and hold the tool above
    the bed."""
    p = kin.forward(rest[None])[0]
    if not kin.within_joint_limits(rest[None])[0] or not np.all(np.isfinite(p)) or p[2] < 0:
        where = "outside the joint limits" if not kin.within_joint_limits(rest[None])[0] else (
            "a pose the mechanism cannot close" if not np.all(np.isfinite(p)) else f"the tool at z = {p[2]:.1f} mm, below the bed")
        raise PrinterFileError(f"{path}: [joints] rest: {where}: expected joint positions within the limits that hold "
                               "the tool above the bed")
    return rest


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
