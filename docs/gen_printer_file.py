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
from deltaslice.machine.dynamics import CURVES, read_actuators  # noqa: E402
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
    ("tool", "max_retract_length"): ("mm", "Longest retraction a G-code may ask for: filament pulled back below where it last extruded (retractions in a row add up); a longer one is refused naming its line. The default is Marlin's FWRETRACT `MAX_AUTORETRACT` (10 mm: longer standing E moves are filament loads, not retractions). At least `retract_length`.", None),
    ("tool", "retract_speed"): ("mm/s", "Filament speed of retracts and re-primes (the extruder's idle speed limit).", None),
    ("tool", "z_hop"): ("mm", "Lift of the nozzle during retracted travels.", None),
    ("tool", "retract_min_travel"): ("mm", "Travels shorter than this do not retract.", None),
    ("tool", "counts_per_mm"): ("steps/mm", "Extruder steps per mm of filament.", None),
    ("tool", "max_power"): ("W", "Laser optical power at full duty: verify reports the peak power in W.", None),
    ("tool", "power_counts"): ("counts", "Counts of full laser power in the stream (e.g. 255 for 8-bit PWM).", None),
    ("tool", "travel_height"): ("mm", "Lift of the laser head during travels.", None),
    ("tool", "spot_size"): ("mm", "Focused laser spot diameter: the default raster line pitch.", None),
    ("tool", "s_max"): ("", "G-code S value of full laser power (GRBL's $30): S / s_max is the power fraction.", None),
    ("tool", "hotend_temperature"): ("deg C", "Hot-end temperature a sliced part is printed at (set and waited for at the start).", None),
    ("tool", "bed_temperature"): ("deg C", "Bed temperature a sliced part is printed at; 0: an unheated bed (no bed events).", None),
    # bed
    ("bed", "shape"): ("", "`circle` (deltas) or `rectangle`.", None),
    ("bed", "radius"): ("mm", "Printable radius of a circular bed: the work envelope's edge; every commanded point (travels included) must lie within it.", None),
    ("bed", "size_x"): ("mm", "Printable width of a rectangular bed (centred on the origin): the work envelope's extent in x.", None),
    ("bed", "size_y"): ("mm", "Printable depth of a rectangular bed: the work envelope's extent in y.", None),
    ("bed", "max_height"): ("mm", "Tallest part the machine prints (z above the bed): the top of the work envelope; a commanded point above it, or below the bed surface, is refused.", None),
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
    ("slicing", "travel_speed"): ("mm/s", "Feed of travels that have none: deltaslice's own slice, a G-code before its first F. Under `--speed-limit feed` no travel goes faster than its feed (the planner may go slower), and the moves from and back to the rest pose no faster than this speed or the input's fastest feed, whichever is lower; `machine` ignores it.", None),
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
    ("slicing", "fill_pattern"): ("", "Sparse infill: `rectilinear` (lines one way, turned 90 deg every layer) or `grid` (both ways on every layer, each set twice as far apart: the same plastic, a stiffer lattice; PrusaSlicer's grid).", None),
    ("slicing", "brim_width"): ("mm", "Width of the brim: loops touching the outer outline of every island of the first layer, from the part outward (PrusaSlicer's outer-only brim, no gap); the skirt goes around it. 0: no brim.", None),
    ("slicing", "support"): ("", "`auto`: support under every overhang flatter than `support_angle` (cantilevers, flat undersides, bridges), built from the bed or the part below; `none`: no support.", None),
    ("slicing", "support_angle"): ("deg from vertical", "Walls leaning further than this from vertical are supported (each layer reaching more than `h x tan(angle)` beyond the one below); Cura's support_angle.", None),
    ("slicing", "support_z_gap"): ("mm", "Air between a support's top and the part above it (and between the part's top and a support standing on it), rounded to whole layers; PrusaSlicer's support_material_contact_distance.", "layer_height"),
    ("slicing", "support_xy_gap"): ("mm", "Gap between support lines' edges and the part's side; PrusaSlicer's support_material_xy_spacing (50 % of the perimeter width).", "half the perimeter_width"),
    ("slicing", "support_interface_layers"): ("", "Dense layers at the top of each support, lines across the body's (the face the overhang is printed on); PrusaSlicer's support_material_interface_layers.", None),
    ("slicing", "support_spacing"): ("mm", "Distance between the centre lines of the support's body; PrusaSlicer's support_material_spacing.", None),
    ("slicing", "support_type"): ("", "`everywhere`: supports stand on the bed or on the part; `buildplate`: only where nothing of the part lies below (Cura's support_type).", None),
    ("slicing", "support_pattern"): ("", "`rectilinear`: the body's lines in one direction on every layer (they stack into thin walls that break away line by line, and keep each layer's moves short and straight); `grid`: the direction alternates by layer (stiffer, harder to remove).", None),
    # cooling (PrusaSlicer's names and defaults)
    ("cooling", "min_fan_speed"): ("%", "Part-fan speed of layers that take `fan_below_layer_time` or longer (the fan stays on, as PrusaSlicer's fan_always_on).", None),
    ("cooling", "max_fan_speed"): ("%", "Part-fan speed of layers quicker than `slowdown_below_layer_time`; between the two times the speed falls linearly to `min_fan_speed`. 0 with the other speeds: a machine without a part fan.", None),
    ("cooling", "bridge_fan_speed"): ("%", "Part-fan speed while bridge infill prints.", None),
    ("cooling", "overhang_fan_speed"): ("%", "Part-fan speed while overhang perimeters print (PrusaSlicer 2.5 uses its bridge fan speed there).", None),
    ("cooling", "disable_fan_first_layers"): ("layers", "The fan stays off on this many first layers (bridges and overhangs included).", None),
    ("cooling", "fan_below_layer_time"): ("s", "Layers quicker than this run the fan above `min_fan_speed`.", None),
    ("cooling", "slowdown_below_layer_time"): ("s", "Minimum layer time: a quicker layer's printing moves are slowed by one factor until it takes this long (times at the requested feeds, travels included); 0: no slowdown.", None),
    ("cooling", "min_print_speed"): ("mm/s", "The slowdown never takes a printing move below this speed.", None),
    # dynamics: the actuators (every family)
    ("dynamics", "stall_torque"): ("N m (N)", "Each actuator's torque at rest, at the joint (a linear joint's force): stall for a DC motor or servo, pull-out at low speed for a stepper.", None),
    ("dynamics", "no_load_speed"): (JOINT + "/s", "Joint speed at which the actuator gives no torque any more (a servo's rated 60 deg time: 60 / t).", None),
    ("dynamics", "speed_torque_curve"): ("", "Torque available while driving: `linear`, stall to none at no_load_speed (servo, DC motor, Dynamixel); `pull_out` (stepper: stall_torque to corner_speed, then x corner_speed / speed, none from no_load_speed); `table` (curve_points). Braking: stall torque.", "`pull_out` for `actuator = \"stepper\"`, else `linear`"),
    ("dynamics", "corner_speed"): (JOINT + "/s", "`pull_out` only: the speed up to which a stepper keeps its low-speed pull-out torque.", None),
    ("dynamics", "curve_points"): ("fractions", "`table` only: `[[speed / no_load_speed, torque / stall_torque], ...]` from `[0, 1]`, speeds increasing; linear between points, none beyond the last.", None),
    # dynamics: rotary delta
    ("rotary_delta dynamics", "upper_arm_mass"): ("kg", "One upper arm (shoulder to elbow), for its gravity torque.", None),
    ("rotary_delta dynamics", "upper_arm_inertia"): ("kg m²", "One upper arm's inertia about its shoulder axis.", "a uniform bar: upper_arm_mass x upper_arm² / 3"),
    ("rotary_delta dynamics", "upper_arm_com"): ("mm", "Shoulder axis to the upper arm's centre of mass, along the arm.", "upper_arm / 2"),
    ("rotary_delta dynamics", "elbow_mass"): ("kg", "What moves with one elbow point: the elbow-side rod ends, nuts, axle.", None),
    ("rotary_delta dynamics", "forearm_mass"): ("kg", "Both rods of one forearm parallelogram (modelled as uniform rods between the ball-joint centres).", None),
    ("rotary_delta dynamics", "platform_mass"): ("kg", "The moving platform with the platform-side rod ends, nuts and axles (the tool apart).", None),
    ("rotary_delta dynamics", "tool_mass"): ("kg", "The tool on the platform (extruder, hot end, laser module).", None),
    ("rotary_delta dynamics", "rotor_inertia"): ("kg m²", "Each motor's rotor and gears reflected to the joint (rotor inertia x gear ratio²).", None),
    # dynamics: linear delta
    ("linear_delta dynamics", "carriage_mass"): ("kg", "One carriage with its rollers or bearings and the carriage-side rod ends.", None),
    ("linear_delta dynamics", "rod_mass"): ("kg", "Both rods of one carriage (modelled as uniform rods between the joint centres).", None),
    ("linear_delta dynamics", "effector_mass"): ("kg", "The effector with the effector-side rod ends (the tool apart).", None),
    ("linear_delta dynamics", "tool_mass"): ("kg", "The tool on the effector (hot end, fan, probe).", None),
    ("linear_delta dynamics", "drive_mass"): ("kg", "Each motor's rotor and pulley reflected to its carriage (inertia / pulley radius²) plus the belt.", None),
    # dynamics: five-bar
    ("five_bar dynamics", "proximal_mass"): ("kg", "Link A-B (and C-D), each.", None),
    ("five_bar dynamics", "proximal_inertia"): ("kg m²", "Links A-B and C-D, each about its motor axis.", "a uniform bar: proximal_mass x link length² / 3, per link"),
    ("five_bar dynamics", "elbow_mass"): ("kg", "The joint hardware at B and at D, each.", None),
    ("five_bar dynamics", "distal_mass"): ("kg", "Link B-P (and D-P), each (modelled as a uniform rod).", None),
    ("five_bar dynamics", "tool_mass"): ("kg", "What rides at P: the print head.", None),
    ("five_bar dynamics", "z_mass"): ("kg", "What the lead screw lifts, with the rotor and screw reflected (rotor inertia x (2 pi / lead)²).", None),
    ("five_bar dynamics", "z_carries"): ("", "`bed` (it moves down as the part grows) or `head`: which way gravity loads the screw.", None),
    ("five_bar dynamics", "rotor_inertia"): ("kg m²", "Each arm motor's rotor and reduction reflected to the arm joint.", None),
    # planning
    ("planning", "output_rate"): ("Hz", "Setpoint rate of the outputs (the firmware's control loop rate).", None),
    ("planning", "blend_tolerance"): ("mm", "Largest distance a blended corner leaves the toolpath's corner point.", None),
    ("planning", "limit_margin"): ("fraction", "Share of every limit the planner keeps in reserve.", None),
    ("planning", "travel_lift"): ("mm", "Clearance over the printed part of a lifted joint-space travel.", None),
    ("planning", "singularity_limit"): ("", "Largest Jacobian condition number allowed: poses beyond it count as unreachable.", None),
    ("planning", "approach_height"): ("mm", "Height above the first point from which every job comes down onto it, and above the printed part to which it lifts at the end (lower where the machine cannot reach so high). Default: Marlin's Z_CLEARANCE_BETWEEN_PROBES.", None),
    ("planning", "approach_speed"): ("mm/s", "Speed of that vertical descent and lift, in both speed limits. Default: Marlin's Z homing feed (HOMING_FEEDRATE_MM_M, 4*60 mm/min).", None),
    ("planning", "torque_limit"): ("", "Where the file has `[dynamics]`: `on` plans runs and travels within the actuators' stall torque and speed-torque line as well as the joints' limits; `off` to the joints' constant limits alone.", None),
    ("planning", "jerk_limit"): ("", "`on` re-times runs and straight travels so that each joint's acceleration changes no faster than its `jerk_max` (the path kept; docs/architecture.md); `off` (the default: the re-timing costs 70-500x the planning) leaves them bang-bang in path acceleration.", None),
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
                 "bed", "slicing", "cooling", "planning", "dynamics", "rotary_delta dynamics", "linear_delta dynamics",
                 "five_bar dynamics", "safety", "homing"]


def collect():
    """{(section, key): KeySpec} over the shipped printers and every family's geometry reader."""
    found = {}
    geometries = {}  # a shipped geometry per family, which a family's dynamics defaults are taken from
    with recording() as calls:
        for name in shipped_names():
            p = load_printer(name)
            geometries.setdefault(p.family, p.geometry)
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
    with recording() as dynamics_calls:
        for fam, geometry in geometries.items():
            reader = getattr(family(fam), "read_dynamics", None)
            if reader is not None:
                reader(Section("<empty>", "dynamics", {}, Problems("<empty>")), geometry)
                for spec in dynamics_calls:
                    found.setdefault((f"{fam} dynamics", spec.key), spec)
            dynamics_calls.clear()
        for curve in CURVES:  # every curve's keys, used by a shipped file or not
            try:
                read_actuators(Section("<empty>", "dynamics", {"speed_torque_curve": curve}, Problems("<empty>")),
                               ("revolute",) * 3)
            except _Stop:
                pass
        for spec in dynamics_calls:
            found.setdefault(("dynamics", spec.key), spec)
    for spec in calls:
        if (spec.section == "kinematics" and spec.key != "family") or spec.section == "dynamics":
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
              "cartesian": "[kinematics] of `family = \"cartesian\"`",
              "dynamics": "[dynamics] (optional): the actuators",
              "rotary_delta dynamics": "[dynamics] of a rotary delta: its moving parts",
              "linear_delta dynamics": "[dynamics] of a linear delta: its moving parts",
              "five_bar dynamics": "[dynamics] of a five-bar: its moving parts"}
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
