"""The machine a G-code file was sliced for (its settings block), compared with the printer it
is compiled for."""

from __future__ import annotations

import math
import re

import numpy as np

def _first_number(v) -> float | None:
    try:
        x = float(str(v).split(",")[0].strip().strip('"'))
    except ValueError:
        return None
    return x if math.isfinite(x) and x > 0 else None


def _source_machine(settings: dict, cura: list[str]) -> dict:
    """The machine a file was sliced for, from its settings block: filament and nozzle
    diameters (mm), bed size and centre (mm, in the file's frame) where given."""
    out: dict = {}
    if cura:
        body = "".join(cura).replace("\\\\n", "\n").replace("\\n", "\n")
        for m in re.finditer(r"^\s*(\w+)\s*=\s*([^\n\"]*)", body, re.M):
            settings.setdefault("cura:" + m.group(1), m.group(2).strip())
    fd = _first_number(settings.get("filament_diameter", settings.get("cura:material_diameter")))
    nz = _first_number(settings.get("nozzle_diameter", settings.get("cura:machine_nozzle_size")))
    if fd:
        out["filament_diameter"] = fd
    if nz:
        out["nozzle_diameter"] = nz
    shape = settings.get("bed_shape")
    if shape:
        try:
            pts = np.array([[float(v) for v in p.split("x")] for p in shape.split(",")])
            if pts.ndim == 2 and pts.shape[1] == 2 and np.all(np.isfinite(pts)):
                lo, hi = pts.min(axis=0), pts.max(axis=0)
                out["bed"] = ((hi - lo).tolist(), ((hi + lo) / 2).tolist())
        except ValueError:
            pass
    cw, cd = _first_number(settings.get("cura:machine_width")), _first_number(settings.get("cura:machine_depth"))
    if cw and cd:
        centred_zero = settings.get("cura:machine_center_is_zero", "").lower() == "true"
        out["bed"] = ([cw, cd], [0.0, 0.0] if centred_zero else [cw / 2, cd / 2])
    return out


def _source_notes(source, printer, shown, say, center) -> float | None:
    """Say where the file's machine differs from ``printer``; returns the area ratio E values
    written with E words are rescaled by for another filament diameter, so the same volume of
    plastic is extruded, retractions kept at their length (:func:`_rescale_filament`), or None."""
    if printer is None or not printer.tool.takes_filament or not source:
        return None
    tool = printer.tool
    ratio = None
    fd = source.get("filament_diameter")
    if fd and abs(fd - tool.filament_diameter) > 0.01 * tool.filament_diameter:
        ratio = (fd / tool.filament_diameter) ** 2
        say(f"{shown}: sliced for {fd:g} mm filament, {printer.name} uses {tool.filament_diameter:g} mm: "
            f"E values rescaled by the area ratio {ratio:.4f} so the same volume of plastic is extruded; "
            "retractions and the unretractions that undo them kept at their length (mm of filament pulled "
            "back and pushed again, not a volume)")
    nz = source.get("nozzle_diameter")
    if nz and abs(nz - tool.nozzle_diameter) > 1e-6:
        say(f"{shown}: sliced for a {nz:g} mm nozzle, {printer.name} has {tool.nozzle_diameter:g} mm: "
            "line widths are the file's own")
    bed = source.get("bed")
    if bed:
        (sx, sy), (cx, cy) = bed
        b = printer.bed
        mine = f"a circle of radius {b.radius:g} mm" if b.shape == "circle" else f"{b.size_x:g} x {b.size_y:g} mm"
        # a round bed is written by PrusaSlicer as a polygon: its bounding box is the circle's diameter
        wx, wy = (2 * b.radius, 2 * b.radius) if b.shape == "circle" else (b.size_x, b.size_y)
        other_size = any(abs(a - m) > max(1.0, 0.01 * m) for a, m in ((sx, wx), (sy, wy)))
        off_centre = math.hypot(cx, cy) > 1.0
        if other_size or off_centre:
            what = (["a bed of another size (the part keeps its size and must fit this one)"] if other_size else []) + (
                ["--center moves the part to this bed's centre"] if off_centre and not center else [])
            say(f"{shown}: sliced for a {sx:g} x {sy:g} mm bed centred at ({cx:g}, {cy:g}); {printer.name}'s bed is "
                f"{mine} centred at (0, 0)" + (": " + "; ".join(what) if what else ""))
    return ratio
