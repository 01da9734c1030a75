"""Write docs/printer-file.md: the reference of every printer-file key, generated from the
reader's own getter calls (``deltaslice.config.recording``), so it cannot drift from the code.

    python docs/gen_printer_file.py > docs/printer-file.md

Types, defaults, required-ness and allowed ranges come from the calls; units and purposes
from ``DOCS`` below (the script stops if the reader asks for a key ``DOCS`` does not explain).
``tests/test_printer_docs.py`` checks the committed file equals this output.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from deltaslice.config import Problems, Section, _Stop, recording  # noqa: E402
from deltaslice.kinematics import FAMILIES, family  # noqa: E402
from deltaslice.machine import load_printer  # noqa: E402
from deltaslice.printers import shipped_names  # noqa: E402

JOINT = "deg (mm)"

# (section, key) -> (unit, what it is for, default shown when it is derived from another key)
DOCS = {
    ("top level", "name"): ("", "Short name of the machine; written into every output and checked by `verify`.", None),
    ("top level", "description"): ("", "One line describing the machine (shown by `deltaslice printers`).", None),
    ("kinematics", "family"): ("", "Kinematics family: which file of `deltaslice/kinematics/` reads the other `[kinematics]` keys.", None),
    # rotary delta
    ("rotary_delta", "base_radius"): ("mm", "Bed-centre axis to each motor's shoulder axis (the thesis's R).", None),
    ("rotary_delta", "platform_radius"): ("mm", "Platform centre to each ball-joint pair's midpoint (r).", None),
    ("rotary_delta", "upper_arm"): ("mm", "Shoulder axis to elbow ball-joint centre (L1).", None),
    ("rotary_delta", "forearm"): ("mm", "Ball-joint centre to ball-joint centre of the parallelogram forearm (L2).", None),
    ("rotary_delta", "shoulder_height"): ("mm", "Height of the shoulder axes above the bed surface.", None),
    ("rotary_delta", "tool_offset"): ("mm", "Height of the platform's ball-joint plane above the tool tip (nozzle or laser focus).", None),
    ("rotary_delta", "ball_joint_tilt_max"): ("deg", "Largest tilt of a forearm ball joint from its neutral axis (rod-end catalogue); poses beyond it are unreachable. Omit for no limit.", None),
    # linear delta
    ("linear_delta", "delta_radius"): ("mm", "Horizontal distance from the axis to each carriage's rod joint minus the effector's joint offset (Marlin's DELTA_RADIUS).", None),
    ("linear_delta", "diagonal_rod"): ("mm", "Rod length between ball-joint centres (DELTA_DIAGONAL_ROD).", None),
    ("linear_delta", "tool_offset"): ("mm", "Height of the effector's rod joints above the nozzle tip.", None),
    # five-bar
    ("five_bar", "base_length"): ("mm", "Distance from motor A to motor C along +x.", None),
    ("five_bar", "proximal_a"): ("mm", "Link A-B (driven by motor A).", None),
    ("five_bar", "distal_a"): ("mm", "Link B-P (to the tool).", None),
    ("five_bar", "proximal_c"): ("mm", "Link C-D (driven by motor C).", None),
    ("five_bar", "distal_c"): ("mm", "Link D-P (to the tool).", None),
    ("five_bar", "origin_x"): ("mm", "x of motor A in the bed frame (bed centre at 0).", None),
    ("five_bar", "origin_y"): ("mm", "y of motor A in the bed frame.", None),
    ("five_bar", "codo1"): ("", "Working-mode sign of the A side's elbow (+1 or -1), the Atlas paper's CODO1.", None),
    ("five_bar", "codo2"): ("", "Working-mode sign of the C side's elbow (+1 or -1), CODO2.", None),
    # cartesian
    ("cartesian", "offset_x"): ("mm", "Joint 1 reading at bed x = 0.", None),
    ("cartesian", "offset_y"): ("mm", "Joint 2 reading at bed y = 0.", None),
    ("cartesian", "offset_z"): ("mm", "Joint 3 reading at bed z = 0.", None),
    # joints
    ("joints", "actuator"): ("", "Kind of actuator, for the summary and the firmware: hobby servo PWM, stepper, DC motor with encoder, Dynamixel.", None),
    ("joints", "names"): ("", "One name per joint, used in reports and CSV comments.", "`q1`, `q2`, ..."),
    ("joints", "position_min"): (JOINT, "Lowest joint position (one number for all joints, or a list).", None),
    ("joints", "position_max"): (JOINT, "Highest joint position.", None),
    ("joints", "velocity_max"): (JOINT + "/s", "Joint speed limit the planner keeps and `verify` checks.", None),
    ("joints", "acceleration_max"): (JOINT + "/s²", "Joint acceleration limit.", None),
    ("joints", "jerk_max"): (JOINT + "/s³", "Joint jerk limit for the lifted travels (ruckig); omit for none.", "none"),
    ("joints", "counts_per_unit"): ("counts per joint unit, non-zero", "Actuator counts per degree (or mm): PWM microseconds, microsteps, encoder or Dynamixel ticks; the stream's resolution. Not 0; negative for a joint whose actuator turns the other way (counts decrease as the joint angle grows).", None),
    ("joints", "zero_count"): ("counts", "Count at joint position 0 (`count = zero_count + counts_per_unit x q`).", None),
    ("joints", "sensor_table"): ("reading, deg or mm", "Absolute joint sensors (potentiometers, absolute encoders): per joint, `[[reading, joint position], ...]`, at least 2 points with distinct readings; interpolated piecewise-linearly (`Printer.joint_from_sensor`) and written into the firmware configuration header (`deltaslice firmware-config`), where a player reads its joints at power-up.", "none"),
    ("joints", "rest"): ("deg or mm", "The rest pose: where every trajectory starts and parks (servos attached, axes homed).", "the highest reachable point above the bed centre"),
    # tool
    ("tool", "kind"): ("", "`extruder` (FDM) or `laser`: the tool channel of every output.", None),
    ("tool", "nozzle_diameter"): ("mm", "Nozzle bore; sets the default extrusion widths and the largest layer height (1.5 x).", None),
    ("tool", "filament_diameter"): ("mm", "Filament diameter, for the volume of filament per mm.", None),
    ("tool", "max_volumetric_flow"): ("mm³/s", "Hot end's melt limit: caps the filament speed while printing.", None),
    ("tool", "max_filament_acceleration"): ("mm/s²", "Extruder motor's filament acceleration limit.", None),
    ("tool", "retract_length"): ("mm", "Filament pulled back before a travel (0: no retracts).", None),
    ("tool", "retract_speed"): ("mm/s", "Filament speed of retracts and re-primes (the extruder's idle speed limit).", None),
    ("tool", "z_hop"): ("mm", "Lift of the nozzle during retracted travels.", None),
    ("tool", "retract_min_travel"): ("mm", "Travels shorter than this do not retract.", None),
    ("tool", "counts_per_mm"): ("steps/mm", "Extruder steps per mm of filament.", None),
    ("tool", "max_power"): ("W", "Laser optical power at full duty (reported only).", None),
    ("tool", "power_counts"): ("counts", "Counts of full laser power in the stream (e.g. 255 for 8-bit PWM).", None),
    ("tool", "travel_height"): ("mm", "Lift of the laser head during travels.", None),
    ("tool", "spot_size"): ("mm", "Focused laser spot diameter: the default raster line pitch.", None),
    ("tool", "s_max"): ("", "G-code S value of full laser power (GRBL's $30): S / s_max is the power fraction.", None),
    ("tool", "hotend_temperature"): ("deg C", "Hot-end temperature a sliced part is printed at (set and waited for at the start).", None),
    ("tool", "bed_temperature"): ("deg C", "Bed temperature a sliced part is printed at; 0: an unheated bed (no bed events).", None),
    # bed
    ("bed", "shape"): ("", "`circle` (deltas) or `rectangle`.", None),
    ("bed", "radius"): ("mm", "Printable radius of a circular bed; every printing move must lie within it.", None),
    ("bed", "size_x"): ("mm", "Printable width of a rectangular bed (centred on the origin).", None),
    ("bed", "size_y"): ("mm", "Printable depth of a rectangular bed.", None),
    ("bed", "max_height"): ("mm", "Tallest part the machine prints (z above the bed).", None),
    # slicing
    ("slicing", "layer_height"): ("mm", "Layer height after the first.", None),
    ("slicing", "first_layer_height"): ("mm", "First layer's height.", "layer_height"),
    ("slicing", "perimeters"): ("", "Perimeter loops per layer.", None),
    ("slicing", "top_solid_layers"): ("", "Solid layers under a top surface.", None),
    ("slicing", "bottom_solid_layers"): ("", "Solid layers over a bottom surface.", None),
    ("slicing", "fill_density"): ("fraction 0..1", "Sparse infill density.", None),
    ("slicing", "fill_angle"): ("deg", "Infill direction (alternates by 90 deg each layer).", None),
    ("slicing", "infill_overlap"): ("fraction of the perimeter width", "How far infill reaches into the innermost perimeter.", None),
    ("slicing", "perimeter_speed"): ("mm/s", "Feed of inner perimeters.", None),
    ("slicing", "external_perimeter_speed"): ("mm/s", "Feed of the outer perimeter.", "perimeter_speed"),
    ("slicing", "infill_speed"): ("mm/s", "Feed of sparse infill.", None),
    ("slicing", "solid_infill_speed"): ("mm/s", "Feed of solid infill.", "infill_speed"),
    ("slicing", "first_layer_speed"): ("mm/s", "Feed of every printing move of the first layer.", None),
    ("slicing", "travel_speed"): ("mm/s", "Feed of travels (the planner may go slower, never faster).", None),
    ("slicing", "perimeter_width"): ("mm", "Extrusion width of perimeters.", "1.125 x nozzle_diameter"),
    ("slicing", "infill_width"): ("mm", "Extrusion width of infill.", "1.125 x nozzle_diameter"),
    ("slicing", "first_layer_width"): ("mm", "Extrusion width on the first layer.", "1.2 x nozzle_diameter"),
    ("slicing", "extrusion_multiplier"): ("", "Scales every extrusion (flow calibration).", None),
    ("slicing", "skirt_loops"): ("", "Skirt loops around the first layer (0: none).", None),
    ("slicing", "skirt_distance"): ("mm", "Gap between the part and the skirt; the skirt must be on the bed too.", None),
    ("slicing", "seam"): ("", "Where perimeter loops start: `aligned` (one seam line) or `nearest`.", None),
    ("slicing", "gcode_resolution"): ("mm", "Paths are simplified within this deviation (PrusaSlicer's gcode_resolution); 0: not simplified.", None),
    ("slicing", "solid_infill_below_area"): ("mm²", "Infill regions smaller than this are filled solid (PrusaSlicer's solid_infill_below_area).", "70 x (nozzle / 0.4)²"),
    ("slicing", "bridge_speed"): ("mm/s", "Speed of bridge infill over air.", "perimeter_speed"),
    ("slicing", "bridge_flow"): ("", "Multiplier on the round bead of nozzle diameter laid over air.", None),
    ("slicing", "overhang_speed"): ("mm/s", "Speed of perimeters over air.", "half the external perimeter speed"),
    # planning
    ("planning", "output_rate"): ("Hz", "Setpoint rate of the outputs (the firmware's control loop rate).", None),
    ("planning", "blend_tolerance"): ("mm", "Largest distance a blended corner leaves the toolpath's corner point.", None),
    ("planning", "limit_margin"): ("fraction", "Share of every limit the planner keeps in reserve.", None),
    ("planning", "travel_lift"): ("mm", "Clearance over the printed part of a lifted joint-space travel.", None),
    ("planning", "singularity_limit"): ("", "Largest Jacobian condition number allowed: poses beyond it count as unreachable.", None),
    # safety (firmware players: docs/bring-up.md, "What the players guard")
    ("safety", "hotend_min_temp"): ("deg C", "A hot end that reads colder than this while set is a fault (Marlin's HEATER_0_MINTEMP): a loose or open thermistor.", None),
    ("safety", "hotend_max_temp"): ("deg C", "A hot end that reads hotter than this is a fault, set or not (HEATER_0_MAXTEMP); at least hotend_temperature + 15.", None),
    ("safety", "bed_min_temp"): ("deg C", "The bed's minimum (BED_MINTEMP).", None),
    ("safety", "bed_max_temp"): ("deg C", "The bed's maximum (BED_MAXTEMP); at least bed_temperature + 10.", None),
    ("safety", "hotend_heating_period"): ("s", "While heating towards its set point the hot end must rise by hotend_heating_gain within every such period (Marlin's WATCH_TEMP_PERIOD).", None),
    ("safety", "hotend_heating_gain"): ("deg C", "The rise expected within each heating period (WATCH_TEMP_INCREASE).", None),
    ("safety", "bed_heating_period"): ("s", "As hotend_heating_period, for the bed (WATCH_BED_TEMP_PERIOD).", None),
    ("safety", "bed_heating_gain"): ("deg C", "As hotend_heating_gain, for the bed (WATCH_BED_TEMP_INCREASE).", None),
    ("safety", "hotend_hold_period"): ("s", "Once at its set point, a hot end more than hotend_hold_drop below it for this long is a thermal runaway (THERMAL_PROTECTION_PERIOD).", None),
    ("safety", "hotend_hold_drop"): ("deg C", "The drop below the set point that starts the hold period's count (THERMAL_PROTECTION_HYSTERESIS).", None),
    ("safety", "bed_hold_period"): ("s", "As hotend_hold_period, for the bed (THERMAL_PROTECTION_BED_PERIOD).", None),
    ("safety", "bed_hold_drop"): ("deg C", "As hotend_hold_drop, for the bed (THERMAL_PROTECTION_BED_HYSTERESIS).", None),
    ("safety", "wait_timeout"): ("s", "The longest a heating wait may hold the stream; the board's `# heating` lines do not extend it.", None),
    ("safety", "host_timeout"): ("s", "A board that has asked for bytes and gets none for this long switches its heaters off, stops and reports it (the host is gone).", None),
    # homing (the Mega player: docs/bring-up.md)
    ("homing", "endstop"): ("", "Per joint, the side of its end stop: 1 at the joint's high end (it trips moving up), -1 at its low end, 0 none (put at the rest pose by hand). A player with end stops homes at the start of every job, then moves to the rest pose.", None),
    ("homing", "endstop_position"): ("deg or mm", "The joint position where its switch trips (measure it: docs/bring-up.md).", "position_max (position_min for -1)"),
    ("homing", "speed"): ("deg/s or mm/s", "Speed of the approach to the switch and of the move from it to the rest pose; at most velocity_max.", "velocity_max / 10"),
}

SECTION_ORDER = ["top level", "kinematics", "rotary_delta", "linear_delta", "five_bar", "cartesian", "joints", "tool",
                 "bed", "slicing", "planning", "safety", "homing"]


def collect():
    """{(section, key): KeySpec} over the shipped printers and every family's geometry reader."""
    found = {}
    with recording() as calls:
        for name in shipped_names():
            load_printer(name)
    with recording() as family_calls:
        for fam in FAMILIES:
            sec = Section("<empty>", "kinematics", {}, Problems("<empty>"))
            try:
                family(fam).read_geometry(sec)
            except _Stop:
                pass
            for spec in family_calls:
                found.setdefault((fam, spec.key), spec)
            family_calls.clear()
    for spec in calls:
        if spec.section == "kinematics" and spec.key != "family":
            continue  # listed per family, from the family readers
        found.setdefault((spec.section, spec.key), spec)
    return found


def _range(s) -> str:
    parts = []
    if s.choices:
        return "one of " + ", ".join(f"`{c}`" for c in s.choices)
    if s.above is not None:
        parts.append(f"> {s.above:g}")
    if s.minval is not None:
        parts.append(f">= {s.minval:g}")
    if s.maxval is not None:
        parts.append(f"<= {s.maxval:g}")
    if s.kind in ("float", "floats"):
        parts.append("finite")
    return ", ".join(parts) or "any"


def _default(s, derived) -> str:
    if s.required:
        return "required"
    if derived:
        return derived
    if isinstance(s.default, (list, tuple)):
        values = set(s.default)
        return f"{next(iter(values)):g} each" if len(values) == 1 and all(isinstance(v, float) for v in values) else f"`{list(s.default)}`"
    if s.default is None or s.default == "":
        return "none"
    return f"{s.default:g}" if isinstance(s.default, float) else f"`{s.default}`"


def render() -> str:
    found = collect()
    missing = sorted(set(found) - set(DOCS))
    if missing:
        raise SystemExit(f"gen_printer_file.py: the reader asks for keys DOCS does not explain: {missing}")
    lines = [
        "# Printer file reference",
        "",
        "<!-- generated by docs/gen_printer_file.py from the reader's own getter calls; do not edit -->",
        "",
        "A printer file is TOML: one table per section below, plus `[sources]` (key = where the number comes from).",
        "Lengths are mm, times s, angles degrees (radians inside the program). A per-joint key takes one number",
        "for every joint or a list with one number per joint; joint units are deg for revolute joints, (mm) for",
        "prismatic ones (linear towers, lead screws). `deltaslice PART --printer FILE --set section.key=value`",
        "overrides any key with the same checks. Every problem of a file is reported at once; an unknown key is",
        "named with the nearest valid one. Guide to writing one for your own delta: `docs/custom-delta.md`.",
        "",
    ]
    titles = {"top level": "Top level", "kinematics": "[kinematics]",
              "rotary_delta": "[kinematics] of `family = \"rotary_delta\"` (Clavel delta, rotary motors)",
              "linear_delta": "[kinematics] of `family = \"linear_delta\"` (Kossel-style towers)",
              "five_bar": "[kinematics] of `family = \"five_bar\"` (planar 5R + lead-screw z)",
              "cartesian": "[kinematics] of `family = \"cartesian\"`"}
    for section in SECTION_ORDER:
        keys = [k for (s, k) in found if s == section]
        if not keys:
            continue
        lines += [f"## {titles.get(section, f'[{section}]')}", "", "| key | unit | default | allowed | what it is for |",
                  "|---|---|---|---|---|"]
        for key in keys:
            spec = found[(section, key)]
            unit, text, derived = DOCS[(section, key)]
            lines.append(f"| `{key}` | {unit} | {_default(spec, derived)} | {_range(spec)} | {text} |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.stdout.write(render())
