"""Command line: parses arguments and calls the library. Nothing else lives here.

    deltaslice PART --printer FILE [-o OUT]      compile (the default command)
    deltaslice slice PART --printer FILE -o part.gcode
    deltaslice workspace --printer FILE [--plot ws.png]
    deltaslice decode STREAM [--units]
    deltaslice verify OUTPUT --printer FILE [--toolpath PART]
"""

from __future__ import annotations

import sys

import click

from .errors import DeltasliceError

EPILOG_COMPILE = """\b
Examples:
  deltaslice examples/parts/calibration_cube.stl --printer printers/delta_etitc.toml -o cube.csv
  deltaslice part.gcode --printer printers/delta_ucb.toml -o part.dsl --speed-limit machine
"""


class _DefaultGroup(click.Group):
    """A group whose first argument, when it is not a command name, goes to ``compile``."""

    def parse_args(self, ctx, args):
        if args and args[0] not in self.commands and args[0] not in ("--help", "-h", "--version"):
            args = ["compile", *args]
        return super().parse_args(ctx, args)


def _placement_options(fn):
    """--scale, --rotate, --keep-position: how a mesh is placed on the bed."""
    for option in reversed(
        [
            click.option("--scale", type=float, default=1.0, show_default=True, help="Scale the part."),
            click.option("--rotate", type=float, default=0.0, show_default=True, help="Rotate the part about z, degrees."),
            click.option("--keep-position", is_flag=True, help="Keep the part's x-y position instead of centring it."),
        ]
    ):
        fn = option(fn)
    return fn


def _run(fn, *args, **kwargs):
    """Call the library; turn any DeltasliceError into a one-line message and exit 1."""
    try:
        return fn(*args, **kwargs)
    except DeltasliceError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(1)


@click.group(cls=_DefaultGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="deltaslice")
def main():
    """deltaslice: compile a part (STL/OBJ/3MF or G-code) into time-stamped joint
    setpoints for a delta or five-bar robot, within its actuators' limits.

    Run `deltaslice PART --printer FILE -o OUT` to compile; see each command's --help.
    """


@main.command("compile", epilog=EPILOG_COMPILE)
@click.argument("part", type=click.Path(dir_okay=False))
@click.option("--printer", "printer_path", required=True, type=click.Path(dir_okay=False), help="Printer file (printers/*.toml).")
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="Output file: .csv setpoints, .dsl binary stream, .gcode.")
@click.option("--format", "fmt", type=click.Choice(["csv", "stream", "gcode"]), help="Override the format chosen from the extension.")
@click.option("--speed-limit", type=click.Choice(["feed", "machine"]), default="feed", show_default=True,
              help="feed: obey the toolpath's feed rates; machine: only the actuators' limits.")
@click.option("--planner", type=click.Choice(["toppra", "trapezoid"]), default="toppra", show_default=True,
              help="toppra: time-optimal in joint space; trapezoid: the conventional Cartesian planner (made safe).")
@click.option("--solver", type=click.Choice(["fast", "toppra"]), default="fast", show_default=True,
              help="The time-optimal planner's solver: fast (compiled reachability) or toppra (reference).")
@_placement_options
@click.option("--workers", type=int, default=None, help="Planning processes (default: all cores).")
@click.option("--quiet", is_flag=True, help="No progress output.")
def compile_cmd(part, printer_path, output, fmt, speed_limit, planner, solver, scale, rotate, keep_position, workers, quiet):
    """Compile PART (mesh or G-code) into a trajectory for the printer."""
    from .pipeline import compile_part

    summary = _run(
        compile_part,
        part,
        printer_path,
        output=output,
        fmt=fmt,
        speed_limit=speed_limit,
        planner=planner,
        solver=solver,
        scale=scale,
        rotate=rotate,
        keep_position=keep_position,
        workers=workers,
        progress=not quiet,
        echo=lambda s: click.echo(s, err=True),
    )
    click.echo(summary)


@main.command("slice")
@click.argument("part", type=click.Path(dir_okay=False))
@click.option("--printer", "printer_path", required=True, type=click.Path(dir_okay=False), help="Printer file (printers/*.toml).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="G-code file to write.")
@_placement_options
@click.option("--quiet", is_flag=True, help="No progress output.")
def slice_cmd(part, printer_path, output, scale, rotate, keep_position, quiet):
    """Slice a mesh into G-code (absolute E, ;LAYER:n markers, feeds in mm/min).

    \b
    Example:
      deltaslice slice examples/parts/calibration_cube.stl --printer printers/delta_etitc.toml -o cube.gcode
    """
    from .pipeline import slice_to_gcode

    summary = _run(
        slice_to_gcode,
        part,
        printer_path,
        output,
        scale=scale,
        rotate=rotate,
        keep_position=keep_position,
        progress=not quiet,
        echo=lambda s: click.echo(s, err=True),
    )
    click.echo(summary)


@main.command("workspace")
@click.option("--printer", "printer_path", required=True, type=click.Path(dir_okay=False), help="Printer file (printers/*.toml).")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), default=None,
              help="PNG to write (default: <printer name>_workspace.png).")
def workspace_cmd(printer_path, plot_path):
    """Print the reachable volume, largest cylinder and cube, singularity margin and
    resolution of a printer, and plot them.

    \b
    Example:
      deltaslice workspace --printer printers/delta_etitc.toml --plot etitc.png
    """
    from .pipeline import workspace_report

    click.echo(_run(workspace_report, printer_path, plot_path))


@main.command("decode")
@click.argument("stream", type=click.Path(dir_okay=False))
@click.option("--units", is_flag=True, help="Print the setpoints CSV format (joint units) instead of integer counts.")
@click.option("--printer", "printer_path", type=click.Path(dir_okay=False), default=None,
              help="Printer file; needed with --units only when the stream's own header is not enough.")
def decode_cmd(stream, units, printer_path):
    """Print the samples of a binary stream, one line per sample."""
    from .emit.stream import decode_to_text

    _run(decode_to_text, stream, sys.stdout, units=units, printer_path=printer_path)


@main.command("verify")
@click.argument("output", type=click.Path(dir_okay=False))
@click.option("--printer", "printer_path", required=True, type=click.Path(dir_okay=False), help="Printer file (printers/*.toml).")
@click.option("--toolpath", "toolpath_path", type=click.Path(dir_okay=False), default=None,
              help="The part or G-code compiled, to check the path deviation.")
def verify_cmd(output, printer_path, toolpath_path):
    """Replay a CSV or stream; check joint and tool limits and path deviation. Exit 1 on any violation."""
    from .verify import verify_file

    report = _run(verify_file, output, printer_path, toolpath_path=toolpath_path)
    click.echo(report.text())
    sys.exit(0 if report.ok else 1)


if __name__ == "__main__":  # pragma: no cover
    main()
