"""Heater events at the start of a print deltaslice slices itself."""

from __future__ import annotations

from ..toolpath import EventKind, ToolpathBuilder


def start_heating(builder: ToolpathBuilder, tool) -> None:
    """Before the first move: set the bed and the hot end, then wait for both (bed first, as
    slicers do, so the hot end does not ooze while the bed heats). A bed temperature of 0 is an
    unheated bed: no bed events."""
    bed = float(tool.bed_temperature)
    if bed > 0:
        builder.event(EventKind.BED_SET, bed)
    builder.event(EventKind.HOTEND_SET, float(tool.hotend_temperature))
    if bed > 0:
        builder.event(EventKind.BED_WAIT, bed)
    builder.event(EventKind.HOTEND_WAIT, float(tool.hotend_temperature))
