"""Command line: parses arguments and calls the library. Nothing else lives here.

    deltaslice PART --printer P [-o OUT]          compile (the default command; OUT defaults to PART.dsl)
    deltaslice slice PART --printer P -o part.gcode
    deltaslice preview PART --printer P -o view.png
    deltaslice workspace --printer P [--plot ws.png]
    deltaslice decode STREAM [--units]
    deltaslice verify OUTPUT --printer P [--toolpath PART] [--assume-printer]
    deltaslice printers

P is a printer file or the name of a shipped printer (``deltaslice printers``).

Exit codes (also in ``deltaslice --help``): 0 done; 1 error (one line on stderr, no traceback);
2 usage error (unknown command or option, bad value); 3 ``verify`` found violations;
130 interrupted by Ctrl-C (any previous output is left unchanged; a Ctrl-C after the new output is in
place says it was written in full).
"""

from __future__ import annotations

from . import interrupt

# Until this module is defined, Ctrl-C exits at once with the one line and status 130 (a
# KeyboardInterrupt raised inside click's import would print a traceback); the console script
# imports this module first. Its end installs the recording handler the commands run under.
interrupt.install(at_once=True)

import json  # noqa: E402
import math  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
from dataclasses import asdict, is_dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import click  # noqa: E402

from .errors import DeltasliceError  # noqa: E402
from .pool import keep_freed_memory  # noqa: E402

# The compile's parallelism is its worker processes. OpenBLAS (numpy's and scipy's, each) would
# start a thread per core that spins whenever woken, on the workers' cores, for BLAS calls too small
# to share out, taking CPU from the workers. Set before numpy loads; the user's own setting stands.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_VERIFY_FAILED, EXIT_INTERRUPTED = 0, 1, 2, 3, interrupt.EXIT_INTERRUPTED

EPILOG_COMPILE = """\b
Examples:
  deltaslice examples/parts/calibration_cube.stl --printer delta_etitc
  deltaslice part.gcode --printer printers/delta_ucb.toml -o part.csv --speed-limit machine
  deltaslice vase.gcode --printer linear_kossel --center    # sliced for a 200 x 200 mm bed
  deltaslice logo.png --printer delta_espe_laser --width 60 --mode vector -o logo.dsl
"""

EPILOG_MAIN = """\b
Exit codes: 0 done, 1 error, 2 usage error, 3 verify found violations,
130 interrupted (Ctrl-C; any previous output is left unchanged, or the line
says the new one was already written in full).
"""


def _looks_like_part(arg: str) -> bool:
    """A first argument that is a file path (an extension, a folder, or an existing file), not a command."""
    p = Path(arg)
    return bool(p.suffix) or len(p.parts) > 1 or p.exists()


class _DefaultGroup(click.Group):
    """A group whose first argument, when it looks like a file path, goes to ``compile``; a
    mistyped command gets click's "No such command"."""

    def parse_args(self, ctx, args):
        if args and args[0] not in self.commands and not args[0].startswith("-") and _looks_like_part(args[0]):
            args = ["compile", *args]
        return super().parse_args(ctx, args)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            raise _Interrupted() from None  # click would print a blank line and "Aborted!"
        except BrokenPipeError:
            # whoever read stdout stopped (decode F | head): nothing went wrong, so end quietly with 0
            # (click's own handling exits 1); stdout goes to /dev/null so the final flush is silent
            try:
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            except (OSError, ValueError, AttributeError):  # a stdout without a descriptor (a test's)
                pass
            raise click.exceptions.Exit(EXIT_OK) from None

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        """click's main, with Ctrl-C at any moment -> one line and exit 130."""
        interrupt.install()
        interrupt.reset()
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except (_Interrupted, KeyboardInterrupt, click.exceptions.Abort):
            _interrupted()
        except click.exceptions.Exit as exc:
            sys.exit(exc.exit_code)
        except click.ClickException as exc:
            exc.show()
            sys.exit(exc.exit_code)
        except SystemExit:
            raise
        except BaseException:
            # A Ctrl-C inside a C extension's import can surface as any exception (pybind11:
            # "ImportError: initialization failed"): it is still an interrupt.
            if interrupt.requested():
                _interrupted()
            raise
        if interrupt.requested():  # a Ctrl-C some library swallowed
            _interrupted()
        if not standalone_mode:
            return rv
        sys.exit(EXIT_OK)


class _Interrupted(Exception):
    """Ctrl-C, carried past click's own KeyboardInterrupt handling."""


def _interrupted():
    click.echo(interrupt.message(), err=True)
    sys.exit(EXIT_INTERRUPTED)


def _engrave_options(fn):
    """--mode, --width, --height, --invert and the detector settings: how an image is engraved."""
    for option in reversed(
        [
            click.option("--mode", type=click.Choice(["vector", "raster"]), default="vector", show_default=True,
                         help="Image: trace edges (vector) or scan lines with grey-level power (raster)."),
            click.option("--width", type=float, default=None, help="Image width on the work, mm (default: the largest that fits)."),
            click.option("--height", type=float, default=None, help="Image height on the work, mm."),
            click.option("--invert", is_flag=True, help="Image: burn the light areas instead of the dark ones."),
            click.option("--power", type=float, default=1.0, show_default=True, help="Laser power, fraction of max_power."),
            click.option("--constant-power", is_flag=True,
                         help="Constant power (M3) instead of power proportional to the tool speed (M4)."),
            click.option("--blur", type=float, default=1.0, show_default=True, help="Vector: Gaussian blur sigma, px."),
            click.option("--gamma", type=float, default=1.0, show_default=True, help="Exponent on the grey levels (> 1 darkens)."),
            click.option("--low", type=float, default=50.0, show_default=True, help="Vector: Canny low threshold (0..255)."),
            click.option("--high", type=float, default=150.0, show_default=True, help="Vector: Canny high threshold (0..255)."),
            click.option("--line-pitch", type=float, default=None, help="Raster: line spacing, mm (default: the laser spot size)."),
            click.option("--dither", is_flag=True, help="Raster: on/off ordered dithering instead of grey-level power."),
        ]
    ):
        fn = option(fn)
    return fn


def _engrave_dict(mode, width, height, invert, power, constant_power, blur, gamma, low, high, line_pitch, dither):
    return dict(mode=mode, width=width, height=height, invert=invert, power=power, dynamic_power=not constant_power,
                blur=blur, gamma=gamma, low=low, high=high, line_pitch=line_pitch, dither=dither)


def _run(fn, *args, **kwargs):
    """Call the library; turn any DeltasliceError into a one-line message and exit 1."""
    try:
        return fn(*args, **kwargs)
    except DeltasliceError as exc:
        if interrupt.requested():
            _interrupted()
        click.echo(f"error: {exc}", err=True)
        sys.exit(EXIT_ERROR)


def _echo_json(obj, err=False, **extra):
    data = asdict(obj) if is_dataclass(obj) else dict(obj)
    data.update(extra)
    click.echo(json.dumps(_jsonable(data), indent=2, allow_nan=False), err=err)


def _to_stderr(output) -> bool:
    """Whether a command's own lines go to stderr: its output (``-o -``) is standard output."""
    from .formats import is_stdout

    return is_stdout(output)


def _jsonable(value):
    """Plain JSON: numpy values as numbers and lists, non-finite floats as null."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "tolist"):
        return _jsonable(value.tolist())
    if isinstance(value, float):
        return value if value == value and abs(value) != float("inf") else None
    if isinstance(value, Path):
        return str(value)
    return value


# ---------------------------------------------------------------------------- option groups


def _options(*decorators):
    def apply(fn):
        for option in reversed(decorators):
            fn = option(fn)
        return fn

    return apply


def _parse_set(ctx, param, values):
    """--set section.key=value (repeatable) -> {"section.key": value}; the value is read as TOML."""
    import tomllib

    out = {}
    for item in values:
        key, sep, text = item.partition("=")
        if not sep or "." not in key:
            raise click.BadParameter(f"{item!r}: expected section.key=value, e.g. slicing.layer_height=0.3")
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text  # a bare word: a string
        out[key.strip()] = value
    return out


printer_options = _options(
    click.option("--printer", "printer_path", required=True, metavar="FILE|NAME",
                 help="Printer file, or the name of a shipped printer (see `deltaslice printers`)."),
    click.option("--set", "overrides", multiple=True, callback=_parse_set, metavar="SECTION.KEY=VALUE",
                 help="Override a printer-file value (validated like the file), e.g. --set slicing.layer_height=0.3."),
)

placement_options = _options(
    click.option("--scale", type=float, default=1.0, show_default=True, help="Scale the part."),
    click.option("--rotate", type=float, default=0.0, show_default=True, help="Rotate the part about z, degrees."),
    click.option("--keep-position", is_flag=True, help="Keep the part's x-y position instead of centring it."),
)

json_option = click.option("--json", "as_json", is_flag=True, help="Print the result as JSON on stdout.")

class _Bound(click.ParamType):
    """A job bound: a finite number >= 0 (0: no bound). click's FloatRange lets nan through (every
    comparison with it is false), which then refused every job as "0.0 h exceeds the bound nan h"."""

    name = "float"

    def __init__(self, unit: str):
        self.unit = unit

    def convert(self, value, param, ctx):
        try:
            number = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number of {self.unit}", param, ctx)
        if not (math.isfinite(number) and number >= 0):
            self.fail(f"{value!r}: expected a finite number of {self.unit} >= 0 (0: no bound)", param, ctx)
        return number


bound_options = _options(
    click.option("--max-time", type=_Bound("hours"), default=48.0, show_default=True, metavar="HOURS",
                 help="Refuse a job whose print time exceeds this, before writing (0: no bound)."),
    click.option("--max-size", type=_Bound("MiB"), default=4096.0, show_default=True, metavar="MIB",
                 help="Refuse an output larger than this, before writing (0: no bound)."),
)


def _printer(printer_path, overrides, reach_checks: bool = True):
    from .machine import load_printer

    return _run(load_printer, printer_path, overrides=overrides or None, reach_checks=reach_checks)


def _placement(scale, rotate, keep_position) -> dict:
    return {"scale": scale, "rotate": rotate, "keep_position": keep_position}


# ---------------------------------------------------------------------------- commands


@click.group(cls=_DefaultGroup, context_settings={"help_option_names": ["-h", "--help"]}, epilog=EPILOG_MAIN)
@click.version_option(package_name="deltaslice")
def main():
    """deltaslice: compile a part (STL/OBJ/3MF or G-code) into time-stamped joint
    setpoints for a delta or five-bar robot, within its actuators' limits.

    Run `deltaslice PART --printer NAME` to compile (writes PART.dsl beside the part);
    `deltaslice printers` lists the shipped printers; see each command's --help.
    """


@main.command("compile", epilog=EPILOG_COMPILE)
@click.argument("part", type=click.Path(dir_okay=False))
@printer_options
@click.option("-o", "--output", type=click.Path(dir_okay=False),
              help="Output file: .dsl binary stream (default: PART.dsl beside the part), .csv setpoints, .gcode; "
              "- for standard output (a stream unless --format says otherwise).")
@click.option("--format", "fmt", type=click.Choice(["csv", "stream", "gcode"]), help="Override the format chosen from the extension.")
@click.option("--speed-limit", type=click.Choice(["feed", "machine"]), default="feed", show_default=True,
              help="feed: obey the toolpath's feed rates; machine: only the actuators' limits.")
@click.option("--planner", type=click.Choice(["toppra", "trapezoid"]), default="toppra", show_default=True,
              help="toppra: time-optimal in joint space; trapezoid: the conventional Cartesian planner (made safe).")
@click.option("--solver", type=click.Choice(["fast", "toppra"]), default="fast", show_default=True,
              help="The time-optimal planner's solver: fast (compiled reachability) or toppra (reference).")
@placement_options
@click.option("--center", is_flag=True, help="G-code: move the part's footprint to the bed centre (a file sliced for another machine; "
              "a large file is then held in memory whole).")
@_engrave_options
@click.option("--workers", type=click.IntRange(min=1), default=None, help="Processes slicing, planning and sampling (default: all cores; each runs OpenBLAS on one thread unless OPENBLAS_NUM_THREADS is set); the output is the same for any number.")
@bound_options
@click.option("--quiet", is_flag=True, help="No progress output.")
@json_option
def compile_cmd(part, printer_path, overrides, output, fmt, speed_limit, planner, solver, scale, rotate, keep_position, center,
                workers, max_time, max_size, quiet, as_json, **engrave):
    """Compile PART (mesh, G-code, or an image or SVG for a laser) into a trajectory for the printer."""
    from . import jit
    from .pipeline import compile_part
    from .progress import stderr_progress
    from .report import compile_summary

    # a first run (numba's cache empty) says it compiles the kernels, and how far it is
    with jit.first_run(stderr_progress(not quiet, jit.FIRST_RUN_LABEL, unit="kernels")):
        result = _run(
            compile_part,
            part,
            _printer(printer_path, overrides, reach_checks=False),  # compile_part checks it while slicing starts
            output=output,
            fmt=fmt,
            speed_limit=speed_limit,
            planner=planner,
            solver=solver,
            workers=workers,
            progress=not quiet,
            echo=lambda s: click.echo(s, err=True),
            max_duration_s=max_time * 3600.0 or None,
            max_bytes=max(1, round(max_size * 1024**2)) if max_size else None,
            engrave=_engrave_dict(**engrave),
            center=center,
            **_placement(scale, rotate, keep_position),
        )
    if as_json:
        _echo_json(result, err=_to_stderr(output))
    else:
        click.echo(compile_summary(result), err=_to_stderr(output))


@main.command("slice")
@click.argument("part", type=click.Path(dir_okay=False))
@printer_options
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="G-code file to write (- for standard output).")
@placement_options
@click.option("--quiet", is_flag=True, help="No progress output.")
def slice_cmd(part, printer_path, overrides, output, scale, rotate, keep_position, quiet):
    """Slice a mesh into G-code (absolute E, ;LAYER:n markers, feeds in mm/min).

    \b
    Example:
      deltaslice slice examples/parts/calibration_cube.stl --printer delta_etitc -o cube.gcode
    """
    from .pipeline import slice_to_gcode

    summary = _run(
        slice_to_gcode,
        part,
        _printer(printer_path, overrides),
        output,
        progress=not quiet,
        echo=lambda s: click.echo(s, err=True),
        **_placement(scale, rotate, keep_position),
    )
    click.echo(summary, err=_to_stderr(output))


@main.command("preview")
@click.argument("part", type=click.Path(dir_okay=False))
@printer_options
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="PNG file to write (- for standard output).")
@click.option("--layer", type=int, default=None, help="Layer to draw (default: the middle layer).")
@placement_options
def preview_cmd(part, printer_path, overrides, output, layer, scale, rotate, keep_position):
    """Draw PART as a PNG: a mesh or G-code as a layer coloured by role with its travels and a side
    view; a compiled .dsl/.csv as joint position, speed and acceleration against their limits over
    time, and the tool speed.

    \b
    Examples:
      deltaslice preview cube.stl --printer delta_etitc -o cube_layers.png
      deltaslice preview cube.dsl --printer delta_etitc -o cube_joints.png
    """
    from .pipeline import preview

    click.echo(_run(preview, part, _printer(printer_path, overrides), output, layer=layer,
                    **_placement(scale, rotate, keep_position)), err=_to_stderr(output))


@main.command("workspace")
@printer_options
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), default=None,
              help="PNG to write (default: <printer name>_workspace.png; with --json, none unless given; - for standard output).")
@json_option
def workspace_cmd(printer_path, overrides, plot_path, as_json):
    """Print the reachable volume, largest cylinder and cube, singularity margin and
    resolution of a printer, and plot them.

    \b
    Example:
      deltaslice workspace --printer delta_etitc --plot etitc.png
    """
    from .pipeline import workspace_analysis
    from .report import workspace_summary

    # --json is for programs: a picture only when --plot asks for one
    result = _run(workspace_analysis, _printer(printer_path, overrides), plot_path, draw=not as_json)
    if as_json:
        _echo_json(result, err=_to_stderr(plot_path))
    else:
        click.echo(workspace_summary(result), err=_to_stderr(plot_path))


@main.command("send")
@click.argument("stream", type=click.Path(dir_okay=False))
@click.option("--port", required=True, metavar="DEVICE",
              help="Serial port of the board (e.g. /dev/ttyACM0, COM3), or a URL such as socket://HOST:PORT.")
@click.option("--baud", type=click.IntRange(min=1), default=115200, show_default=True, help="Baud rate the player uses.")
@click.option("--timeout", type=click.FloatRange(min=0.1), default=10.0, show_default=True,
              help="Seconds without a byte from the board before giving up (heaters may take a while).")
@click.option("--printer", "printer_path", default=None, metavar="FILE|NAME",
              help="Refuse the stream unless it was compiled for this printer.")
@click.option("--quiet", is_flag=True, help="No progress output.")
def send_cmd(stream, port, baud, timeout, printer_path, quiet):
    """Send a checked .dsl stream to a board running a deltaslice player (examples/firmware), with
    its credit flow control, and report what the board played. From a terminal, type p (pause: a
    feed hold, the board ramps its clock to a stop), r (resume) or x (abort: heaters and motors
    off at once), each followed by Enter; Ctrl-C aborts too.

    \b
    Example:
      deltaslice send cube.dsl --port /dev/ttyACM0
    """
    import sys

    from .pipeline import send_file
    from .send import keyboard_commands

    commands = None
    if sys.stdin is not None and sys.stdin.isatty():
        click.echo("p + Enter: pause, r: resume, x: abort (Ctrl-C aborts too)", err=True)
        commands = keyboard_commands(echo=lambda what: click.echo(f"{what}: sent to the board", err=True))
    result = _run(send_file, stream, port, baud=baud, timeout=timeout, progress=not quiet,
                  printer=None if printer_path is None else _printer(printer_path, None), commands=commands)
    click.echo(f"sent {result.bytes_sent} bytes; the board played {result.samples} samples in {result.seconds:.1f} s")


@main.command("play")
@click.argument("stream", type=click.Path(dir_okay=False))
@click.option("--dynamixel", "bus_port", required=True, metavar="DEVICE",
              help="Serial port of the Dynamixel bus (a U2D2 or USB2Dynamixel: /dev/ttyUSB0, COM3).")
@click.option("--laser", "laser_port", default=None, metavar="DEVICE",
              help="Serial port of the laser board (examples/firmware/uno_laser_player.c).")
@click.option("--baud", type=click.IntRange(min=1), default=1_000_000, show_default=True, help="Bus baud rate.")
@click.option("--ids", default=None, metavar="1,2,3", help="Servo IDs in joint order (default 1, 2, 3, ...).")
@click.option("--protocol", type=click.Choice(["1", "2"]), default="1", show_default=True,
              help="Dynamixel protocol: 1 (AX/MX control table) or 2 (X series).")
@click.option("--interval", type=click.FloatRange(min=0.0), default=0.0, show_default=True,
              help="Least milliseconds between goal packets (default: as often as the bus carries them).")
@click.option("--release", is_flag=True, help="Torque off when playback stops (default: hold the last goal).")
@click.option("--printer", "printer_path", default=None, metavar="FILE|NAME",
              help="Refuse the stream unless it was compiled for this printer.")
@click.option("--quiet", is_flag=True, help="No progress output.")
def play_cmd(stream, bus_port, laser_port, baud, ids, protocol, interval, release, printer_path, quiet):
    """Play a checked .dsl stream in real time on Dynamixel servos (goal positions by SYNC_WRITE)
    and, with --laser, the laser board. Keys while playing: p pause (laser off), r resume, q abort;
    Ctrl-C aborts too. Every stop switches the laser off.

    \b
    Example:
      deltaslice play engraving.dsl --dynamixel /dev/ttyUSB0 --laser /dev/ttyACM0
    """
    from .pipeline import play_file

    try:
        id_list = None if ids is None else [int(x) for x in ids.split(",")]
    except ValueError:
        raise click.BadParameter(f"{ids!r}: expected IDs like 1,2,3", param_hint="--ids") from None
    try:
        result = play_file(stream, bus_port, baud=baud, ids=id_list, protocol=int(protocol), laser_port=laser_port,
                           release=release, min_interval=interval / 1e3,
                           printer=None if printer_path is None else _printer(printer_path, None), keyboard=True,
                           progress=not quiet)
    except DeltasliceError as exc:  # its line says where playback stopped and that the laser is off
        click.echo(f"error: {exc}", err=True)
        sys.exit(EXIT_INTERRUPTED if getattr(exc, "interrupted", False) else EXIT_ERROR)
    click.echo(f"played {result.samples} samples in {result.seconds:.2f} s: {result.packets} goal packets "
               f"(every {result.decimation} sample{'s' if result.decimation > 1 else ''}), "
               f"{result.laser_frames} laser frames; {result.timing()}")


@main.command("firmware-config")
@printer_options
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None,
              help="Header file to write (default, or -: print it).")
def firmware_config_cmd(printer_path, overrides, output):
    """Write the C header the firmware players include (dsl_config.h): the printer's fingerprint,
    rest pose and joint-sensor calibration in actuator counts.

    \b
    Example:
      deltaslice firmware-config --printer delta_ucb -o examples/firmware/config/delta_ucb.h
    """
    from .pipeline import write_firmware_config

    text = _run(write_firmware_config, _printer(printer_path, overrides), output)
    if output is None:
        click.echo(text, nl=False)


@main.command("decode")
@click.argument("stream", type=click.Path(dir_okay=False))
@click.option("--units", is_flag=True, help="Print the setpoints CSV format (joint units) instead of integer counts.")
@click.option("--printer", "printer_path", default=None, metavar="FILE|NAME",
              help="Printer the stream must match; needed with --units only when the stream's own header is not enough.")
def decode_cmd(stream, units, printer_path):
    """Print the samples of a binary stream, one line per sample.

    \b
    Examples:
      deltaslice decode cube.dsl | head
      deltaslice decode cube.dsl --units --printer delta_etitc > cube_setpoints.csv
    """
    from .pipeline import decode_stream

    _run(decode_stream, stream, sys.stdout, units=units, printer=None if printer_path is None else _printer(printer_path, None))


@main.command("verify")
@click.argument("output", type=click.Path(dir_okay=False))
@printer_options
@click.option("--toolpath", "toolpath_path", type=click.Path(dir_okay=False), default=None,
              help="The part or G-code compiled, to check the path deviation (give the same placement options).")
@click.option("--assume-printer", is_flag=True,
              help="The file does not say which printer it was made for (a CSV without its '#' header): check it as "
                   "made for --printer (refused otherwise); the report says the printer was assumed.")
@placement_options
@_engrave_options
@json_option
def verify_cmd(output, printer_path, overrides, toolpath_path, assume_printer, scale, rotate, keep_position, as_json,
               **engrave):
    """Replay a CSV or stream; check joint and tool limits and path deviation. Exit 3 on any violation.

    \b
    Examples:
      deltaslice verify cube.dsl --printer delta_etitc
      deltaslice verify cube.csv --printer delta_etitc --toolpath examples/parts/calibration_cube.stl --json
    """
    from .pipeline import verify_output

    report = _run(verify_output, output, _printer(printer_path, overrides), toolpath=toolpath_path,
                  assume_printer=assume_printer, engrave=_engrave_dict(**engrave),
                  **_placement(scale, rotate, keep_position))
    if as_json:
        _echo_json(report, ok=report.ok)
    else:
        click.echo(report.text())
    sys.exit(EXIT_OK if report.ok else EXIT_VERIFY_FAILED)


@main.command("printers")
@json_option
def printers_cmd(as_json):
    """List the printers shipped with deltaslice (usable by name: --printer NAME).

    \b
    Example:
      deltaslice printers --json
    """
    from .pipeline import shipped_printers

    rows = _run(shipped_printers)
    if as_json:
        click.echo(json.dumps(rows, indent=2))
        return
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        click.echo(f"{r['name']:<{width}}  {r['family']:<13} {r['tool']:<8} {r['description']}")


def run():
    """The console script: :data:`main`, then leaving at once with its status, without the
    interpreter's teardown. Every output is written, closed and renamed into place, every worker
    pool shut down and every temporary file unlinked when it was made (before main returns), so
    the teardown only frees memory: it would walk numba's and llvmlite's object graphs and join
    threads in the compile's last, single-core stretch. Leaving at once also keeps an
    interrupt's 130: Python kills itself with SIGINT at exit when a KeyboardInterrupt ever passed
    through C code (an extension's import) even if it was handled ("killed by signal").
    An exception other than SystemExit leaves as usual, with its traceback. Freed memory is kept
    for reuse (:func:`~deltaslice.pool.keep_freed_memory`)."""
    keep_freed_memory()
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code
    if code is None:
        code = 0
    elif not isinstance(code, int):  # as Python prints a non-integer exit status
        print(code, file=sys.stderr)
        code = 1
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (deltaslice ... | head): nothing more to say
            pass
    os._exit(code)


interrupt.install()  # this module is defined: from here on Ctrl-C is recorded and stops the work cleanly

if __name__ == "__main__":  # pragma: no cover
    run()
