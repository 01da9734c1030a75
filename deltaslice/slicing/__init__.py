"""Slicing: a :class:`~deltaslice.mesh.Mesh` in, a layered :class:`~deltaslice.toolpath.Toolpath` out.

One module per concern: :mod:`.layers` (heights, manifold3d cross-sections),
:mod:`.perimeters` (inward offsets, seams), :mod:`.infill` (solid regions from
neighbouring layers, rectilinear lines), :mod:`.ordering` (path order, travels,
retracts), :mod:`.extrusion` (filament amounts, feeds), :mod:`.skirt`.
"""

from .slicer import slice_mesh

__all__ = ["slice_mesh"]
