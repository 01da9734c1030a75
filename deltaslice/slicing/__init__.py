"""Slicing: a :class:`~deltaslice.mesh.Mesh` in, a layered :class:`~deltaslice.toolpath.Toolpath` out.

:func:`slice_mesh` (:mod:`.slicer`) takes the mesh, the slicing settings and the tool, layer by
layer. One module per concern: :mod:`.layers` (layer heights), :mod:`.sections` (per-layer
cross-sections: manifold3d for a closed part, open meshes cut triangle by triangle and closed),
:mod:`.perimeters` (inward offsets, seams, overhangs), :mod:`.gapfill` (gap fill and thin walls
along the medial axis), :mod:`.bridges` (solid regions over air, lines across the span),
:mod:`.infill` (solid regions from neighbouring layers, rectilinear lines), :mod:`.skirt` (skirt
and brim), :mod:`.support` (support regions under overhangs, all layers in one pass),
:mod:`.ordering` (path order, travels, retracts), :mod:`.extrusion` (filament amounts, feeds),
:mod:`.heaters` (hot-end and bed set-and-wait events at the start), :mod:`.cooling` (minimum layer
time and part-fan events, on the finished toolpath).
"""

from .slicer import slice_mesh

__all__ = ["slice_mesh"]
