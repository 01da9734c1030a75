"""slice_mesh: chain the slicing stages layer by layer."""

from __future__ import annotations

import math

import numpy as np
from manifold3d import CrossSection

from ..errors import DeltasliceError, MeshError
from ..toolpath import Role, Toolpath, ToolpathBuilder
from .extrusion import bead_spacing, feed_for
from .heaters import start_heating
from .infill import clean, rectilinear, solid_masks
from .layers import layer_heights
from .ordering import MoveWriter, Path, nearest_order
from .perimeters import infill_boundary, perimeter_loops
from .sections import mesh_sections
from .skirt import skirt_loops


def slice_mesh(mesh, settings, tool, *, progress=None, name: str = "this printer") -> Toolpath:
    """Slice ``mesh`` (a placed :class:`~deltaslice.mesh.Mesh`) with ``settings``
    (:class:`~deltaslice.machine.SlicingSettings`) for ``tool`` (an
    :class:`~deltaslice.machine.Extruder`); name: the printer's, for messages;
    progress: ``callable(done, total)`` called once per layer.
    Returns a :class:`Toolpath` in the bed frame starting at (0, 0, 0): per layer
    the skirt (first layer), then island by island perimeters (innermost first,
    external last) and infill (top solid, internal solid, sparse).
    """
    s = settings
    if tool.channel_kind != "extruder":
        raise DeltasliceError(
            f"{name}: slicing a mesh needs an extruder, this printer has a {tool.channel_kind}: "
            "give it an image or G-code instead"
        )
    height = float(mesh.vertices[:, 2].max())
    top, mid, thick = layer_heights(height, s.layer_height, s.first_layer_height)
    if len(top) == 0:
        raise MeshError(f"{mesh.path}: the part is {height:.3f} mm tall, too thin for a {s.first_layer_height:g} mm first layer")
    sections = mesh_sections(mesh, mid)  # manifold3d, or layer by layer for an open mesh
    n = len(sections)

    builder = ToolpathBuilder(start=(0.0, 0.0, 0.0))
    start_heating(builder, tool)
    writer = MoveWriter(builder, s, tool, tool.filament_area)
    P = int(s.perimeters)
    for li in range(n):
        first = li == 0
        writer.new_layer(float(top[li]), first)
        here = sections[li]
        if not here.is_empty():
            _slice_layer(writer, sections, li, float(thick[li]), s, P, first)
        if progress is not None:
            progress(li + 1, n)
    if writer.retracted:
        builder.add(builder.pos, tool.retract_speed, tool.retract_length, 0.0, Role.RETRACT)
    return builder.build()


def _emit(writer: MoveWriter, ordered, height: float, s, first: bool) -> None:
    for pts, path in ordered:
        writer.extrude(pts, path.role, path.width, height, feed_for(path.role, s, first))


def _slice_layer(writer: MoveWriter, sections: list[CrossSection], li: int, h: float, s, P: int, first: bool) -> None:
    here = sections[li]
    w_p = s.first_layer_width if first else s.perimeter_width
    w_i = s.first_layer_width if first else s.infill_width
    sp_p, sp_i = bead_spacing(w_p, h), bead_spacing(w_i, h)
    angle = s.fill_angle + (math.pi / 2 if li % 2 else 0.0)

    if first and s.skirt_loops > 0:
        loops = [Path(p, Role.SKIRT, w_p, closed=True) for p in skirt_loops(here, s.skirt_loops, s.skirt_distance, w_p)]
        _emit(writer, nearest_order(loops, writer.b.pos, "nearest"), h, s, first)

    near_top, near_bottom = solid_masks(sections, li, s.top_solid_layers, s.bottom_solid_layers)
    need_solid = near_top + near_bottom
    exposed = here - sections[li + 1] if li + 1 < len(sections) else here

    islands = here.decompose()
    # islands nearest first (by their bounding-box centre)
    centres = np.array([[(b[0] + b[2]) / 2, (b[1] + b[3]) / 2] for b in (isl.bounds() for isl in islands)])
    alive = np.ones(len(islands), bool)
    for _ in range(len(islands)):
        idx = np.flatnonzero(alive)
        pos = writer.b.pos[:2]
        j = int(idx[np.argmin(np.sum((centres[idx] - pos) ** 2, axis=1))])
        alive[j] = False
        island = islands[j]

        # perimeters: innermost depth first, the external loop last
        loops = perimeter_loops(island, w_p, P, sp_p)
        for depth in sorted({d for d, _ in loops}, reverse=True):
            role = Role.EXTERNAL_PERIMETER if depth == 0 else Role.PERIMETER
            paths = [Path(p, role, w_p, closed=True) for d, p in loops if d == depth]
            _emit(writer, nearest_order(paths, writer.b.pos, s.seam), h, s, first)

        # infill
        fill = infill_boundary(island, w_p, P, s.infill_overlap * w_p - sp_i / 2, sp_p)
        if fill.is_empty():
            continue
        solid = clean(fill ^ need_solid, w_i / 4) if not need_solid.is_empty() else CrossSection()
        top_region = clean(solid ^ exposed, w_i / 4) if not solid.is_empty() and not exposed.is_empty() else CrossSection()
        internal = solid - top_region if not top_region.is_empty() else solid
        sparse = fill - solid if not solid.is_empty() else fill
        paths = []
        for region, role in ((top_region, Role.TOP_SOLID_INFILL), (internal, Role.SOLID_INFILL)):
            paths += [Path(p, role, w_i) for p in rectilinear(region, angle, sp_i, w_i)]
        if s.fill_density > 0 and not sparse.is_empty():
            dens = min(float(s.fill_density), 1.0)
            role = Role.SOLID_INFILL if dens >= 0.999 else Role.INFILL
            paths += [Path(p, role, w_i) for p in rectilinear(sparse, angle, sp_i / dens, w_i)]
        _emit(writer, nearest_order(paths, writer.b.pos), h, s, first)
