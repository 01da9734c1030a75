"""File kinds by extension, in one table: what a part file is and what an output file gets."""

from __future__ import annotations

from pathlib import Path

from .errors import DeltasliceError

MESH_SUFFIXES = (".stl", ".obj", ".3mf", ".ply", ".off")
GCODE_SUFFIXES = (".gcode", ".gco", ".g", ".nc")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")  # raster images to engrave
SVG_SUFFIXES = (".svg",)  # vector drawings to engrave
ENGRAVE_SUFFIXES = IMAGE_SUFFIXES + SVG_SUFFIXES

OUTPUT_FORMATS = ("csv", "stream", "gcode")
OUTPUT_SUFFIXES = {
    ".csv": "csv",
    ".dsl": "stream",
    ".stream": "stream",
    **{suffix: "gcode" for suffix in GCODE_SUFFIXES},
}
#: compiled outputs holding samples (read back by verify, decode, preview)
SAMPLES_SUFFIXES = tuple(s for s, fmt in OUTPUT_SUFFIXES.items() if fmt in ("csv", "stream"))


def suffix(path) -> str:
    """The file's extension, lower case ("" for none)."""
    return Path(str(path)).suffix.lower()


def is_svg(path) -> bool:
    return suffix(path) in SVG_SUFFIXES


def holds_samples(path) -> bool:
    """True for a compiled output (.csv setpoints, .dsl or .stream binary stream)."""
    return suffix(path) in SAMPLES_SUFFIXES


def part_kind(path) -> str:
    """"mesh", "gcode" or "image" (an image or SVG to engrave) from a part file's extension;
    DeltasliceError otherwise."""
    suffix = Path(str(path)).suffix.lower()
    if suffix in MESH_SUFFIXES:
        return "mesh"
    if suffix in GCODE_SUFFIXES:
        return "gcode"
    if suffix in ENGRAVE_SUFFIXES:
        return "image"
    raise DeltasliceError(
        f"{path}: unknown part type {suffix or '(no extension)'!r}: expected a mesh "
        f"({', '.join(MESH_SUFFIXES)}), G-code ({', '.join(GCODE_SUFFIXES)}) or, for a laser, an image "
        f"({', '.join(ENGRAVE_SUFFIXES)})"
    )


#: An output named so is standard output (``-o -``).
STDOUT = "-"


def is_stdout(path) -> bool:
    return isinstance(path, str) and path == STDOUT


def format_for(path) -> str:
    """"csv" | "stream" | "gcode" from the output file's extension, "stream" (the default output's)
    for standard output; DeltasliceError otherwise."""
    if is_stdout(path):
        return "stream"
    suffix = Path(str(path)).suffix.lower()
    try:
        return OUTPUT_SUFFIXES[suffix]
    except KeyError:
        raise DeltasliceError(
            f"{path}: cannot tell the output format from {suffix or '(no extension)'!r}: use .csv (setpoints), "
            ".dsl or .stream (binary stream), .gcode, or --format csv|stream|gcode"
        ) from None
