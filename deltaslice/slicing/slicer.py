"""slice_mesh: chain the slicing stages layer by layer."""

from __future__ import annotations

import math

import numpy as np
import shapely
from manifold3d import CrossSection, JoinType, OpType

from ..errors import DeltasliceError, MeshError
from ..toolpath import Role, Toolpath, ToolpathBuilder
from .bridges import bridge_angle, bridge_region
from .extrusion import bead_spacing, bridge_flow, feed_for
from .gapfill import medial_lines, to_shapely
from .heaters import start_heating
from .infill import clean, rectilinear, solid_masks
from .layers import layer_heights
from .ordering import MoveWriter, Path, nearest_order
from .perimeters import infill_boundary, overhang_segments, perimeter_loops
from .sections import mesh_sections
from .skirt import skirt_loops

INFILL_ANCHOR_MAX = 50.0  # mm: infill lines are joined along the outline up to this far apart (PrusaSlicer's infill_anchor_max)
GAP_MIN_WIDTH = 0.2  # gaps thinner than this fraction of a perimeter width are left empty


def slice_mesh(mesh, settings, tool, *, progress=None, name: str = "this printer") -> Toolpath:
    """Slice ``mesh`` (a placed :class:`~deltaslice.mesh.Mesh`) with ``settings``
    (:class:`~deltaslice.machine.SlicingSettings`) for ``tool`` (an
    :class:`~deltaslice.machine.Extruder`); name: the printer's, for messages;
    progress: ``callable(done, total)`` called once per layer.
    Returns a :class:`Toolpath` in the bed frame starting at (0, 0, 0): per layer
    the skirt (first layer), then island by island perimeters (innermost first,
    external last, overhang segments flagged), gap fill, then bridges, solid
    (top and internal) and sparse infill.
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
    if s.gcode_resolution > 0:
        # drop the mesh's facet noise once, so every offset and path has fewer vertices
        sections = [c.simplify(float(s.gcode_resolution)) for c in sections]
    n = len(sections)

    builder = ToolpathBuilder(start=(0.0, 0.0, 0.0))
    start_heating(builder, tool)
    writer = MoveWriter(builder, s, tool, tool.filament_area)
    P = int(s.perimeters)
    # each layer's section less its perimeter band: what counts as covering the layers
    # around it (vertical shells)
    band = s.perimeter_width / 2 + (P - 0.5) * bead_spacing(s.perimeter_width, s.layer_height) if P else 0.0
    shells = [c.offset(-band, JoinType.Miter, 3.0) for c in sections] if band > 0 else sections
    prev_sparse = CrossSection()
    for li in range(n):
        first = li == 0
        writer.new_layer(float(top[li]), first)
        here = sections[li]
        if not here.is_empty():
            prev_sparse = _slice_layer(writer, sections, li, float(thick[li]), s, P, first, tool.nozzle_diameter, prev_sparse,
                                       shells)
        else:
            prev_sparse = CrossSection()
        if progress is not None:
            progress(li + 1, n)
    if writer.retracted:
        builder.add(builder.pos, tool.retract_speed, tool.retract_length, 0.0, Role.RETRACT)
    return builder.build()


def _emit(writer: MoveWriter, ordered, height: float, s, first: bool) -> None:
    for pts, path in ordered:
        writer.extrude(pts, path.role, path.width, height, feed_for(path.role, s, first), path.flow)


def _coverage(loops: list[tuple[int, np.ndarray]], spacing: float) -> CrossSection:
    """Area the perimeter beads cover: each depth's loops (outlines counter-clockwise,
    holes clockwise: the positive fill rule keeps the material) widened by half a
    bead spacing either side."""
    beads = []
    for depth in sorted({d for d, _ in loops}):
        ring = CrossSection([p for d, p in loops if d == depth])
        if not ring.is_empty():
            beads.append(ring.offset(spacing / 2, JoinType.Miter, 3.0) - ring.offset(-spacing / 2, JoinType.Miter, 3.0))
    if not beads:
        return CrossSection()
    return CrossSection.batch_boolean(beads, OpType.Add) if len(beads) > 1 else beads[0]


def _slice_layer(writer: MoveWriter, sections: list[CrossSection], li: int, h: float, s, P: int, first: bool,
                 nozzle: float, prev_sparse: CrossSection, shells: list[CrossSection]) -> CrossSection:
    """Emit layer ``li``; returns its sparse infill region (for internal bridges on the next layer)."""
    here = sections[li]
    w_p = s.first_layer_width if first else s.perimeter_width
    w_i = s.first_layer_width if first else s.infill_width
    sp_p, sp_i = bead_spacing(w_p, h), bead_spacing(w_i, h)
    angle = s.fill_angle + (math.pi / 2 if li % 2 else 0.0)
    res = float(s.gcode_resolution)

    if first and s.skirt_loops > 0:
        loops = [Path(p, Role.SKIRT, w_p, closed=True) for p in skirt_loops(here, s.skirt_loops, s.skirt_distance, w_p)]
        _emit(writer, nearest_order(loops, writer.b.pos, "nearest"), h, s, first)

    near_top, near_bottom = solid_masks(sections, li, s.top_solid_layers, s.bottom_solid_layers, shells)
    need_solid = near_top + near_bottom
    exposed = here - sections[li + 1] if li + 1 < len(sections) else here
    below = sections[li - 1] if li > 0 else CrossSection()
    # what holds up a solid layer: the layer below, except where that layer is sparse infill
    support = (below - prev_sparse) if not prev_sparse.is_empty() else below
    overhang_test = None
    if not below.is_empty():
        overhang_test = to_shapely(below.offset(w_p / 2, JoinType.Miter, 3.0))
        shapely.prepare(overhang_test)
    bridge_fpm = bridge_flow(nozzle, writer.area, s.bridge_flow)
    support_sh = None
    sparse_all = []

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
        writer.inside = None
        # travels that stay inside the external perimeter's centre line cross no visible
        # surface: no retraction (PrusaSlicer's "retract only when crossing perimeters")
        inner = island.offset(-w_p / 4, JoinType.Miter, 3.0)
        if not inner.is_empty():
            writer.inside = to_shapely(inner)
            shapely.prepare(writer.inside)

        # perimeters: innermost depth first, the external loop last; external segments over air
        # are overhang perimeters
        loops = perimeter_loops(island, w_p, P, sp_p)
        for depth in sorted({d for d, _ in loops}, reverse=True):
            paths = []
            for d, p in loops:
                if d != depth:
                    continue
                role = Role.EXTERNAL_PERIMETER if depth == 0 else Role.PERIMETER
                if depth == 0 and overhang_test is not None:
                    dense, over = overhang_segments(p, overhang_test, w_p / 4)
                    if over.any():
                        p = dense
                        role = np.where(over, int(Role.OVERHANG_PERIMETER), int(role)).astype(np.uint8)
                paths.append(Path(p, role, w_p, closed=True))
            _emit(writer, nearest_order(paths, writer.b.pos, s.seam), h, s, first)

        # gap fill: what neither the perimeter beads nor the infill reach (narrow walls, thin
        # features, tiny islands), one variable-width line down its middle
        # (printed right after the perimeters, as PrusaSlicer does)
        fill = infill_boundary(island, w_p, P, s.infill_overlap * w_p - sp_i / 2, sp_p)
        covered = _coverage(loops, sp_p)
        if not fill.is_empty():
            covered = covered + fill.offset(sp_i / 2, JoinType.Miter, 3.0)
        gap = island - covered if not covered.is_empty() else island
        min_w = GAP_MIN_WIDTH * w_p
        gap = clean(gap, min_w / 2)
        paths = []
        if not gap.is_empty():
            # a whole island too small for a loop is always printed; inside an island, a blob
            # smaller than a bead is not worth a travel
            blob = 0.0 if not loops else w_p**2
            for pts, widths in medial_lines(to_shapely(gap), min_w, 2.0 * w_p, min_w / 2, max(res, 1e-4), w_p, blob):
                # the gap is measured between bead spacings: fill its rectangle, width x height
                flow = widths * h / writer.area * s.extrusion_multiplier
                paths.append(Path(pts, Role.GAP_FILL, widths, flow=flow))
        _emit(writer, nearest_order(paths, writer.b.pos), h, s, first)

        # infill region; small regions are filled solid (PrusaSlicer's solid_infill_below_area)
        solid_here = need_solid
        if not fill.is_empty() and s.solid_infill_below_area > 0:
            small = [c for c in fill.decompose() if c.area() < s.solid_infill_below_area]
            if small:
                solid_here = solid_here + CrossSection.batch_boolean(small, OpType.Add) if len(small) > 1 else solid_here + small[0]
        groups: list[list[Path]] = []  # printed group after group: bridges, solid, sparse
        if not fill.is_empty():
            solid = clean(fill ^ solid_here, w_i / 4) if not solid_here.is_empty() else CrossSection()
            bridge = CrossSection()
            if li > 0 and not solid.is_empty():
                bridge, _ = bridge_region(solid, support, 2 * w_i, w_i)
                if not bridge.is_empty() and support_sh is None and not support.is_empty():
                    support_sh = to_shapely(support)
                    shapely.prepare(support_sh)
                if not bridge.is_empty():
                    b_angle = bridge_angle(bridge, support_sh, nozzle, angle)
                    groups.append([Path(p, Role.BRIDGE_INFILL, nozzle, flow=bridge_fpm)
                                   for p in rectilinear(bridge, b_angle, nozzle, nozzle)])
                    solid = solid - bridge
            top_region = clean(solid ^ exposed, w_i / 4) if not solid.is_empty() and not exposed.is_empty() else CrossSection()
            internal = solid - top_region if not top_region.is_empty() else solid
            sparse = fill - solid - bridge if not solid.is_empty() or not bridge.is_empty() else fill
            if s.solid_infill_below_area > 0 and not sparse.is_empty() and (not solid.is_empty() or not bridge.is_empty()):
                # sparse scraps left between solid regions are small surfaces too: solid
                small = [c for c in sparse.decompose() if c.area() < s.solid_infill_below_area]
                if small:
                    scraps = CrossSection.batch_boolean(small, OpType.Add) if len(small) > 1 else small[0]
                    internal, sparse = internal + scraps, sparse - scraps
            groups.append([Path(p, role, w_i) for region, role in ((top_region, Role.TOP_SOLID_INFILL), (internal, Role.SOLID_INFILL))
                           for p in rectilinear(region, angle, sp_i, w_i, INFILL_ANCHOR_MAX)])
            if s.fill_density > 0 and not sparse.is_empty():
                dens = min(float(s.fill_density), 1.0)
                role = Role.SOLID_INFILL if dens >= 0.999 else Role.INFILL
                groups.append([Path(p, role, w_i) for p in rectilinear(sparse, angle, sp_i / dens, w_i, INFILL_ANCHOR_MAX)])
                if dens < 0.999:
                    sparse_all.append(sparse)

        for group in groups:
            _emit(writer, nearest_order(group, writer.b.pos), h, s, first)
    writer.inside = None
    if not sparse_all:
        return CrossSection()
    return CrossSection.batch_boolean(sparse_all, OpType.Add) if len(sparse_all) > 1 else sparse_all[0]
