"""slice_mesh: chain the slicing stages layer by layer."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from manifold3d import CrossSection, JoinType, OpType

from ..errors import DeltasliceError, MeshError
from ..pool import can_fork, check_workers, forked_map, inherited
from ..toolpath import Role, Toolpath, ToolpathBuilder
from .bridges import bridge_angle, bridge_region
from .cooling import apply_cooling
from .extrusion import bead_spacing, bridge_flow, filament_per_mm
from .gapfill import medial_lines, to_shapely
from .heaters import start_heating
from .infill import clean, dense_flow_scale, rectilinear, solid_masks
from .layers import layer_heights
from .ordering import MoveWriter, Path, nearest_order
from .perimeters import infill_boundary, overhang_segments, perimeter_loops
from .sections import mesh_sections
from .skirt import brim_extent, brim_loops, skirt_loops
from .support import support_layers

INFILL_ANCHOR_MAX = 50.0  # mm: infill lines are joined along the outline up to this far apart (PrusaSlicer's infill_anchor_max)
GAP_MIN_WIDTH = 0.2  # gaps thinner than this fraction of a perimeter width are left empty
LAYERS_PER_TASK = 4  # layers a slicing worker plans at a time (each range recomputes one sparse region)
BRIDGE_ANCHOR = 3.0  # mm a bridge reaches into the solid infill around it (PrusaSlicer's EXTERNAL_INFILL_MARGIN)
SUPPORT_INTERFACE_GAP = 0.2  # mm of air between interface beads (PrusaSlicer's support_material_interface_spacing)
STARTED_TASKS = 4  # ranges in flight per worker while slice_mesh's ``started`` runs (about half a second)


def slice_mesh(mesh, settings, tool, *, progress=None, name: str = "this printer", workers: int = 1,
               started=None) -> Toolpath:
    """Slice ``mesh`` (a placed :class:`~deltaslice.mesh.Mesh`) with ``settings``
    (:class:`~deltaslice.machine.SlicingSettings`) for ``tool`` (an
    :class:`~deltaslice.machine.Extruder`); name: the printer's, for messages;
    progress: ``callable(done, total)`` called once per layer; workers: processes computing
    the layers' regions and paths (forked: they share the sections) while this process orders
    them and writes the moves; the toolpath is the same for any number. started: a callable
    run here once the workers have their first layers (before the first layer where the layers
    are planned here): work this process does meanwhile, such as loading numba, which the
    workers do not need; what it raises stops the slicing.
    Returns a :class:`Toolpath` in the bed frame starting at (0, 0, 0): per layer
    the skirt and brim (first layer), the support, then island by island perimeters (a hole's
    or outline's loops together, innermost first, external last, segments over air flagged on
    every loop), gap fill, then bridges, and solid (top and internal) and sparse infill
    ordered together; quick layers slowed to the minimum layer time and part-fan events added
    (:mod:`.cooling`, the settings' ``cooling``).
    """
    s = settings
    check_workers(workers, "slice_mesh")
    if not tool.takes_filament:
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
    layers = _Layers(sections, thick, s, tool)
    for li, plan in enumerate(_layer_plans(layers, workers, started)):
        first = li == 0
        writer.new_layer(float(top[li]), first)
        _order_layer(writer, plan, float(thick[li]), s)
        if progress is not None:
            progress(li + 1, n)
    writer.finish()
    return apply_cooling(builder.build(), s.cooling)


@dataclass(frozen=True)
class _Island:
    """What one island of a layer prints, before it is ordered: ``centre`` (2,) mm of its
    bounding box (islands are visited nearest first); ``inside``: the shapely region travels may
    cross without retracting, or None; perimeter groups (an outline or a hole: its external loop
    and the inner loops nearest it), each its paths by depth (innermost first); gap-fill paths,
    and the infill groups printed one after the other (bridges, then solid and sparse
    together)."""

    centre: np.ndarray
    inside: object
    perimeters: list
    gaps: list
    groups: list


@dataclass(frozen=True)
class _LayerPlan:
    """A layer's paths, independent of where the tool comes from: the skirt and the brim (first
    layer only), the support and the islands."""

    skirt: list
    islands: list
    brim: list = ()
    support: list = ()


class _Layers:
    """Everything a layer's paths are made from: the sections, what each counts as covering its
    neighbours (vertical shells), the layer thicknesses, the settings and the tool."""

    def __init__(self, sections, thick, s, tool):
        self.sections, self.thick, self.s, self.tool = sections, thick, s, tool
        self.P = int(s.perimeters)
        # each layer's section less its perimeter band: what counts as covering the layers
        # around it (vertical shells)
        band = s.perimeter_width / 2 + (self.P - 0.5) * bead_spacing(s.perimeter_width, s.layer_height) if self.P else 0.0
        self.shells = [c.offset(-band, JoinType.Miter, 3.0) for c in sections] if band > 0 else sections
        # whether the sparse region is infill the next layer's bridges do not count as support
        # (none at 0 %, solid lines at 100 %)
        self.sparse_infill = 0 < min(float(s.fill_density), 1.0) < 0.999
        # every layer's support regions, in one pass down the layers (before any worker forks)
        self.support = support_layers(sections, thick, s.layer_height, s, s.infill_width)

    def plan(self, li: int, prev_sparse: CrossSection) -> tuple[_LayerPlan, CrossSection]:
        """Layer ``li``'s plan and its sparse infill region (what the next layer's internal
        bridges count as no support); prev_sparse: the layer below's."""
        if self.sections[li].is_empty():
            return _LayerPlan([], [], support=_support_paths(self, li)), CrossSection()
        return _layer_plan(self, li, prev_sparse)

    def sparse(self, li: int) -> CrossSection:
        """Layer ``li``'s sparse infill region alone (the start of a range of layers planned in
        another process): the same region :meth:`plan` gives, without the paths."""
        if li < 0 or self.sections[li].is_empty() or not self.sparse_infill:
            return CrossSection()
        g = _LayerGeometry(self, li)
        return _union([g.fill_regions(island)[2] for island in self.sections[li].decompose()])


def _union(regions: list) -> CrossSection:
    regions = [r for r in regions if not r.is_empty()]
    if not regions:
        return CrossSection()
    return CrossSection.batch_boolean(regions, OpType.Add) if len(regions) > 1 else regions[0]


class _LayerGeometry:
    """Widths, spacings and the regions shared by the islands of one layer."""

    def __init__(self, layers: _Layers, li: int):
        s, sections = layers.s, layers.sections
        self.layers, self.li = layers, li
        self.first = li == 0
        self.h = float(layers.thick[li])
        self.w_p = s.first_layer_width if self.first else s.perimeter_width
        self.w_i = s.first_layer_width if self.first else s.infill_width
        self.sp_p, self.sp_i = bead_spacing(self.w_p, self.h), bead_spacing(self.w_i, self.h)
        self.here = sections[li]
        near_top, near_bottom = solid_masks(sections, li, s.top_solid_layers, s.bottom_solid_layers, layers.shells)
        self.need_solid = near_top + near_bottom

    def fill_regions(self, island) -> tuple[CrossSection, CrossSection, CrossSection, CrossSection]:
        """(fill, solid, sparse, scraps) of one island: its infill region, the part of it filled
        solid (near the top or bottom, or too small for sparse infill), the rest, sparse, less
        the scraps of it left between solid regions (small surfaces too: filled solid)."""
        s, w_p, w_i = self.layers.s, self.w_p, self.w_i
        fill = infill_boundary(island, w_p, self.layers.P, s.infill_overlap * w_p - self.sp_i / 2, self.sp_p)
        if fill.is_empty():
            return fill, CrossSection(), CrossSection(), CrossSection()
        # small regions are filled solid (PrusaSlicer's solid_infill_below_area)
        solid_here = self.need_solid
        if s.solid_infill_below_area > 0:
            small = [c for c in fill.decompose() if c.area() < s.solid_infill_below_area]
            if small:
                solid_here = solid_here + _union(small)
        solid = clean(fill ^ solid_here, w_i / 4) if not solid_here.is_empty() else CrossSection()
        scraps = CrossSection()
        if solid.is_empty():
            return fill, solid, fill, scraps
        sparse = fill - solid
        if s.solid_infill_below_area > 0 and not sparse.is_empty():
            small = [c for c in sparse.decompose() if c.area() < s.solid_infill_below_area]
            if small:
                scraps = _union(small)
                sparse = sparse - scraps
        return fill, solid, sparse, scraps


def _layer_plan(layers: _Layers, li: int, prev_sparse: CrossSection) -> tuple[_LayerPlan, CrossSection]:
    sections = layers.sections
    g = _LayerGeometry(layers, li)
    here, first, w_p, sp_p = g.here, g.first, g.w_p, g.sp_p
    skirt, brim = _skirt_and_brim(layers, here, w_p, sp_p) if first else ([], [])
    exposed = here - sections[li + 1] if li + 1 < len(sections) else here
    below = sections[li - 1] if li > 0 else CrossSection()
    # what holds up a solid layer: the layer below, except where that layer is sparse infill
    support = (below - prev_sparse) if not prev_sparse.is_empty() else below
    overhang_test = None
    below_grown = CrossSection()
    if not below.is_empty():
        below_grown = below.offset(w_p / 2, JoinType.Miter, 3.0)
        overhang_test = to_shapely(below_grown)
        shapely.prepare(overhang_test)
    fills = _Fills(layers, g, li, exposed, below, support)
    sparse_all = []
    islands = []
    for island in here.decompose():
        b = island.bounds()
        # travels that stay inside the external perimeter's centre line cross no visible
        # surface: no retraction (PrusaSlicer's "retract only when crossing perimeters")
        inner = island.offset(-w_p / 4, JoinType.Miter, 3.0)
        inside = None if inner.is_empty() else to_shapely(inner)

        # perimeters: innermost depth first, the external loop last; segments of any loop over
        # air are overhang perimeters (an inner loop of a cantilever has nothing under it either)
        loops = perimeter_loops(island, w_p, layers.P, sp_p)
        # an island wholly over the grown layer below has no loop over air: no loop to test
        test = overhang_test if overhang_test is not None and not (island - below_grown).is_empty() else None
        perimeters = _perimeter_paths(loops, test, w_p)
        fill, solid, sparse, scraps = g.fill_regions(island)
        to_fill, gaps = _gap_fill(layers, g, island, loops, fill)
        groups, sparse = fills.groups(fill, solid, sparse, scraps, to_fill)
        if layers.sparse_infill and not fill.is_empty() and not sparse.is_empty():
            sparse_all.append(sparse)
        islands.append(_Island(np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2]), inside, perimeters, gaps, groups))
    return _LayerPlan(skirt, islands, brim, _support_paths(layers, li)), _union(sparse_all)


def _skirt_and_brim(layers: _Layers, here: CrossSection, w_p: float, sp_p: float) -> tuple[list, list]:
    """(skirt, brim) paths of the first layer."""
    s = layers.s
    skirt, brim = [], []
    if s.brim_width > 0:
        brim = [Path(p, Role.SKIRT, w_p, closed=True) for p in brim_loops(here, s.brim_width, w_p, sp_p)]
    if s.skirt_loops > 0:
        # the skirt keeps its distance from the brim's outer edge and from the support's first layer
        extent = brim_extent(s.brim_width, w_p, sp_p)
        around = here.offset(extent, JoinType.Round, 2.0, 72) if extent > 0 else here
        sup = layers.support[0]
        for region in (sup.body, sup.interface):
            if not region.is_empty():
                around = around + region.offset(w_p / 2, JoinType.Miter, 3.0)
        skirt = [Path(p, Role.SKIRT, w_p, closed=True) for p in skirt_loops(around, s.skirt_loops, s.skirt_distance, w_p)]
    return skirt, brim


def _perimeter_paths(loops, test, w_p: float) -> list:
    """An island's perimeters per loop group, per depth (innermost first): paths whose segments
    over air (outside ``test``, the grown layer below, when given) are overhang perimeters."""
    owner = _loop_groups(loops)
    perimeters = []
    for group in range(int(owner.max()) + 1 if len(owner) else 0):
        by_depth = []
        for depth in sorted({d for (d, _), o in zip(loops, owner) if o == group}, reverse=True):
            paths = []
            for (d, p), o in zip(loops, owner):
                if d != depth or o != group:
                    continue
                role = Role.EXTERNAL_PERIMETER if depth == 0 else Role.PERIMETER
                if test is not None:
                    dense, over = overhang_segments(p, test, w_p / 4)
                    if over.any():
                        p = dense
                        role = np.where(over, int(Role.OVERHANG_PERIMETER), int(role)).astype(np.uint8)
                paths.append(Path(p, role, w_p, closed=True))
            by_depth.append(paths)
        perimeters.append(by_depth)
    return perimeters


def _gap_fill(layers: _Layers, g: _LayerGeometry, island: CrossSection, loops, fill: CrossSection):
    """(what the infill must fill: the island less the perimeter beads, the gap fill paths). Gap
    fill: what neither the perimeter beads nor the infill reach (narrow walls, thin features, tiny
    islands), one variable-width line down its middle (printed right after the perimeters, as
    PrusaSlicer does)."""
    s, w_p, h = layers.s, g.w_p, g.h
    covered = _coverage(loops, g.sp_p)
    to_fill = island - covered if not covered.is_empty() else island
    if not fill.is_empty():
        covered = covered + fill.offset(g.sp_i / 2, JoinType.Miter, 3.0)
    gap = island - covered if not covered.is_empty() else island
    min_w = GAP_MIN_WIDTH * w_p
    gap = clean(gap, min_w / 2)
    gaps = []
    if not gap.is_empty():
        # a whole island too small for a loop is always printed; inside an island, a blob
        # smaller than a bead is not worth a travel
        blob = 0.0 if not loops else w_p**2
        res = float(s.gcode_resolution)
        for pts, widths in medial_lines(to_shapely(gap), min_w, 2.0 * w_p, min_w / 2, max(res, 1e-4), w_p, blob):
            # the gap is measured between bead spacings: fill its rectangle, width x height
            flow = widths * h / layers.tool.filament_area * s.extrusion_multiplier
            gaps.append(Path(pts, Role.GAP_FILL, widths, flow=flow))
    return to_fill, gaps


class _Fills:
    """A layer's infill, island by island: bridges, then solid and sparse lines (:meth:`groups`)."""

    def __init__(self, layers: _Layers, g: _LayerGeometry, li: int, exposed, below, support):
        self.layers, self.g, self.li = layers, g, li
        self.exposed, self.below, self.support = exposed, below, support
        self.nozzle = layers.tool.nozzle_diameter
        self.angle = layers.s.fill_angle + (math.pi / 2 if li % 2 else 0.0)
        self.bridge_fpm = bridge_flow(self.nozzle, layers.tool.filament_area, layers.s.bridge_flow)
        self.support_sh = None  # the support region as a prepared shapely geometry, made at the first bridge

    def _bridges(self, fill, solid):
        """(the bridge region, its paths or None) of an island's solid infill over air."""
        g, support, below, nozzle = self.g, self.support, self.below, self.nozzle
        bridge, air = bridge_region(solid, support, BRIDGE_ANCHOR, g.w_i)
        over_nothing = air - below if not below.is_empty() else air
        if not over_nothing.is_empty():
            # a bridge over air is anchored in whatever infill surrounds it, sparse too (PrusaSlicer
            # expands bridges into internal surfaces); one over sparse infill stays in the solid
            bridge = bridge + (over_nothing.offset(BRIDGE_ANCHOR, JoinType.Miter, 3.0) ^ fill)
        if bridge.is_empty():
            return bridge, None
        if self.support_sh is None and not support.is_empty():
            self.support_sh = to_shapely(support)
            shapely.prepare(self.support_sh)
        air_sh = to_shapely(air)
        shapely.prepare(air_sh)
        b_angle = bridge_angle(bridge, self.support_sh, nozzle, self.angle, air_sh)
        return bridge, [Path(p, Role.BRIDGE_INFILL, nozzle, flow=self.bridge_fpm)
                        for p in rectilinear(bridge, b_angle, nozzle, nozzle)]

    def groups(self, fill, solid, sparse, scraps, to_fill) -> tuple[list, CrossSection]:
        """(the island's fill groups, printed group after group; its sparse region less its bridges)."""
        s, g, angle = self.layers.s, self.g, self.angle
        w_i, sp_i, h = g.w_i, g.sp_i, g.h
        groups: list[list[Path]] = []
        if fill.is_empty():
            return groups, sparse
        bridge = CrossSection()
        if self.li > 0 and not solid.is_empty():
            bridge, paths = self._bridges(fill, solid)
            if paths is not None:
                groups.append(paths)
                solid = solid - bridge
                if not sparse.is_empty():
                    sparse = sparse - bridge
                if not scraps.is_empty():
                    scraps = scraps - bridge
        exposed = self.exposed
        top_region = clean(solid ^ exposed, w_i / 4) if not solid.is_empty() and not exposed.is_empty() else CrossSection()
        internal = solid - top_region if not top_region.is_empty() else solid
        if not scraps.is_empty():
            internal = internal + scraps
        dens = min(float(s.fill_density), 1.0)
        dense = [(top_region, Role.TOP_SOLID_INFILL), (internal, Role.SOLID_INFILL)]
        if dens >= 0.999 and not sparse.is_empty():
            dense.append((sparse, Role.SOLID_INFILL))  # 100 % sparse infill is solid lines too
        lines = [(rectilinear(region, angle, sp_i, w_i, INFILL_ANCHOR_MAX), role) for region, role in dense]
        # dense lines overlap the perimeters (infill_overlap) and run along the outline: their
        # flow is scaled so they lay what the region between the perimeters holds, no more
        fpm = filament_per_mm(w_i, h, self.layers.tool.filament_area, s.extrusion_multiplier) * dense_flow_scale(
            _union([r for r, _ in dense]), to_fill - bridge if not bridge.is_empty() else to_fill,
            [p for ps, _ in lines for p in ps], sp_i)
        # solid and sparse lines in one group, ordered together from where the perimeters end
        # (PrusaSlicer chains a region's fills together): a solid strip across the island
        # need not cost a travel there and back
        fills = [Path(p, role, w_i, flow=fpm) for ps, role in lines for p in ps]
        if len(lines) == 2 and s.fill_density > 0 and not sparse.is_empty():
            fills += [Path(p, Role.INFILL, w_i) for p in _sparse_lines(sparse, angle, sp_i / dens, w_i, s.fill_pattern)]
        groups.append(fills)
        return groups, sparse


def _sparse_lines(region: CrossSection, angle: float, spacing: float, width: float, pattern: str) -> list:
    """Sparse infill polylines ((k, 2) mm) at ``spacing`` for the density: ``rectilinear`` lines
    at ``angle`` (the slicer turns it 90 deg every layer), or ``grid``: lines both ways on every
    layer, each set twice as far apart (the same plastic, a stiffer lattice; PrusaSlicer's grid)."""
    if pattern == "grid":
        return [p for a in (angle, angle + math.pi / 2) for p in rectilinear(region, a, 2 * spacing, width, INFILL_ANCHOR_MAX)]
    return rectilinear(region, angle, spacing, width, INFILL_ANCHOR_MAX)


def _support_paths(layers: _Layers, li: int) -> list:
    """Layer ``li``'s support paths: the body's lines ``support_spacing`` apart (at the infill
    angle; ``grid``: turned 90 deg every other layer), the interface's across them, a
    ``SUPPORT_INTERFACE_GAP`` of air between neighbouring beads."""
    sup = layers.support[li]
    if sup.body.is_empty() and sup.interface.is_empty():
        return []
    s = layers.s
    h = float(layers.thick[li])
    w = s.first_layer_width if li == 0 else s.infill_width
    sp = bead_spacing(w, h)
    angle = s.fill_angle + (math.pi / 2 if s.support_pattern == "grid" and li % 2 else 0.0)
    # zig-zag lines without links along the outline: a support's outline is ragged (cut by the part
    # and by every overhang above) and its lines are meant to break away one by one
    paths = [Path(p, Role.SUPPORT, w) for p in rectilinear(sup.body, angle, max(s.support_spacing, sp), w)]
    paths += [Path(p, Role.SUPPORT_INTERFACE, w) for p in rectilinear(sup.interface, angle + math.pi / 2, sp + SUPPORT_INTERFACE_GAP, w)]
    return paths


def _loop_groups(loops: list) -> np.ndarray:
    """(len(loops),) int: the group of each ``(depth, polygon)`` loop: the index of the external
    (depth 0) loop nearest its first vertex; one group when there is no external loop."""
    ext = [i for i, (d, _) in enumerate(loops) if d == 0]
    owner = np.zeros(len(loops), np.intp)
    if len(ext) < 2:
        return owner
    rings = np.array([shapely.LinearRing(loops[i][1]) for i in ext], dtype=object)
    for i, (d, p) in enumerate(loops):
        owner[i] = ext.index(i) if d == 0 else int(np.argmin(shapely.distance(rings, shapely.Point(p[0]))))
    return owner


def _nearest_groups(groups: list, position: np.ndarray):
    """Perimeter groups (lists of path lists by depth) greedily nearest first from
    ``position``: the next is the one with a vertex of its first loops nearest where the
    previous group ended (its external loop)."""
    if len(groups) < 2:
        yield from groups
        return
    pos = np.asarray(position[:2], float)
    firsts = [np.concatenate([p.points for p in g[0]]) if g and g[0] else np.zeros((1, 2)) for g in groups]
    lasts = [np.concatenate([p.points for p in g[-1]]) if g and g[-1] else np.zeros((1, 2)) for g in groups]
    alive = list(range(len(groups)))
    while alive:
        j = min(alive, key=lambda k: float(np.min(np.sum((firsts[k] - pos) ** 2, axis=1))))
        alive.remove(j)
        yield groups[j]
        # the group ends on its external loop, somewhere on it: its vertex nearest the next start is
        # not known yet, so go on from the loop's nearest vertex to the old position
        last = lasts[j]
        pos = last[int(np.argmin(np.sum((last - pos) ** 2, axis=1)))]


def _order_layer(writer: MoveWriter, plan: _LayerPlan, h: float, s) -> None:
    """Write a layer's paths: the skirt, the brim, the support, then the islands nearest first (by their bounding-box
    centre), each from where the tool is: perimeter groups nearest first (each innermost loop
    first, its external loop last, as PrusaSlicer prints a hole's loops before moving on), gap
    fill, infill groups."""
    if plan.skirt:
        _emit(writer, nearest_order(plan.skirt, writer.pos, "nearest"), h)
    if plan.brim:
        _emit(writer, nearest_order(list(plan.brim), writer.pos, "nearest"), h)
    if plan.support:
        _emit(writer, nearest_order(list(plan.support), writer.pos), h)
    islands = plan.islands
    centres = np.array([isl.centre for isl in islands]).reshape(-1, 2)
    alive = np.ones(len(islands), bool)
    for _ in range(len(islands)):
        idx = np.flatnonzero(alive)
        pos = writer.pos[:2]
        j = int(idx[np.argmin(np.sum((centres[idx] - pos) ** 2, axis=1))])
        alive[j] = False
        island = islands[j]
        writer.inside = island.inside
        if writer.inside is not None:
            shapely.prepare(writer.inside)
        for group in _nearest_groups(island.perimeters, writer.pos):
            for paths in group:
                _emit(writer, nearest_order(paths, writer.pos, s.seam), h)
        _emit(writer, nearest_order(island.gaps, writer.pos), h)
        for group in island.groups:
            _emit(writer, nearest_order(group, writer.pos), h)
    writer.inside = None


def _layer_plans(layers: _Layers, workers: int, started=None):
    """Every layer's plan, in order: computed here, or by forked workers a range of layers at a
    time (each range starts from its first layer's :meth:`_Layers.sparse` of the layer below).
    started: see :func:`slice_mesh`."""
    n = len(layers.sections)
    if workers <= 1 or n < 2 * LAYERS_PER_TASK or not can_fork():
        if started is not None:
            started()
        prev_sparse = CrossSection()
        for li in range(n):
            plan, prev_sparse = layers.plan(li, prev_sparse)
            yield plan
        return
    tasks = ((a, min(a + LAYERS_PER_TASK, n)) for a in range(0, n, LAYERS_PER_TASK))
    # while ``started`` runs nothing is taken from the workers: more ranges queued keep them busy
    in_flight = STARTED_TASKS if started is not None else 2
    for plans in forked_map(_plan_range, tasks, workers, started=started, in_flight=in_flight, layers=layers):
        yield from plans


def _plan_range(a: int, b: int) -> list:
    """In a forked worker: the plans of layers a..b of the inherited layers."""
    layers = inherited("layers")
    prev_sparse = layers.sparse(a - 1)
    plans = []
    for li in range(a, b):
        plan, prev_sparse = layers.plan(li, prev_sparse)
        plans.append(plan)
    return plans


def _emit(writer: MoveWriter, ordered, height: float) -> None:
    for pts, path in ordered:
        writer.extrude(pts, path.role, path.width, height, path.flow)


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
