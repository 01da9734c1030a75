"""What a print shows: simplification, solid small regions, tiny islands, gap fill,
bridges, overhangs, travels without retraction inside the part, seams in corners."""

import dataclasses

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from deltaslice.machine import load_printer
from deltaslice.slicing import slice_mesh
from deltaslice.slicing.perimeters import concave_corners, seam_index
from deltaslice.toolpath import Role

from . import meshes


@pytest.fixture(scope="module")
def etitc():
    return load_printer("printers/delta_etitc.toml")


def layer_moves(tp, layer):
    sl = tp.layer_slices()[layer]
    idx = np.arange(sl.start, sl.stop)
    return idx[tp.working[sl]]


def seg_lengths(tp, idx):
    prev = np.concatenate([[tp.start], tp.xyz])[idx]
    return np.linalg.norm(tp.xyz[idx, :2] - prev[:, :2], axis=1)


def test_resolution_setting_read_with_default(etitc):
    assert etitc.slicing.gcode_resolution == pytest.approx(0.0125)


def test_simplification_drops_facet_noise(etitc):
    """A 2000-facet cylinder: within 0.0125 mm most of its 0.03 mm edges merge; the
    outline stays within the resolution of the true circle."""
    mesh = meshes.cylinder(radius=10.0, height=2.0, sections=2000)
    raw = slice_mesh(mesh, dataclasses.replace(etitc.slicing, gcode_resolution=0.0), etitc.tool)
    simp = slice_mesh(mesh, etitc.slicing, etitc.tool)
    assert simp.working.sum() < 0.5 * raw.working.sum()
    ext = simp.working & (simp.role == Role.EXTERNAL_PERIMETER) & (simp.layer == 2)
    r = np.hypot(simp.xyz[ext, 0], simp.xyz[ext, 1])
    target = 10.0 - etitc.slicing.perimeter_width / 2
    assert np.all(np.abs(r - target) < 0.0125 + 0.02)  # resolution + the 2000-gon's own sag


def test_small_region_is_solid_large_is_sparse(etitc):
    small = slice_mesh(meshes.box(8, 8, 8), etitc.slicing, etitc.tool)  # infill area ~36 mm^2 < 70 * (0.5/0.4)^2
    large = slice_mesh(meshes.box(30, 30, 8), etitc.slicing, etitc.tool)
    mid = small.n_layers // 2
    assert Role.INFILL not in set(small.role[layer_moves(small, mid)].tolist())
    assert Role.INFILL in set(large.role[layer_moves(large, mid)].tolist())
    off = slice_mesh(meshes.box(8, 8, 8), dataclasses.replace(etitc.slicing, solid_infill_below_area=0.0), etitc.tool)
    assert Role.INFILL in set(off.role[layer_moves(off, mid)].tolist())


def test_tiny_bed_contact_printed_on_first_layer(etitc):
    """A 0.9 mm post under a block: thinner than the 1.0 mm first-layer bead, yet printed."""
    tp = slice_mesh(meshes.post_on_block(post=0.9), dataclasses.replace(etitc.slicing, skirt_loops=0), etitc.tool)
    m = layer_moves(tp, 0)
    assert len(m) > 0
    assert np.all(np.abs(tp.xyz[m, :2]) < 0.45 + 1e-6)
    vol = float(tp.e[m].sum()) * etitc.tool.filament_area
    assert vol == pytest.approx(0.81 * etitc.slicing.first_layer_height, rel=0.35)


@pytest.mark.parametrize("thickness", [2.0, 2.3, 2.7])
def test_thick_wall_gap_filled(etitc, thickness):
    """2-2.7 mm walls: perimeters leave a slot the gap fill closes; the plastic in a
    middle layer matches the wall's section within 8 % (without gap fill: a void)."""
    s = dataclasses.replace(etitc.slicing, skirt_loops=0)
    tp = slice_mesh(meshes.thin_wall(thickness, 30, 6), s, etitc.tool)
    layer = tp.n_layers // 2
    m = layer_moves(tp, layer)
    vol = float(tp.e[m].sum()) * etitc.tool.filament_area
    assert vol == pytest.approx(30 * thickness * s.layer_height, rel=0.08)
    gap = m[tp.role[m] == Role.GAP_FILL]
    if len(gap):  # the slot is down the middle of the wall
        assert np.all(np.abs(tp.xyz[gap, 1]) < 0.2 * thickness)


def test_thin_wall_narrower_than_a_bead_printed(etitc):
    s = dataclasses.replace(etitc.slicing, skirt_loops=0)
    tp = slice_mesh(meshes.thin_wall(0.4, 20, 3), s, etitc.tool)
    for layer in range(1, tp.n_layers):
        m = layer_moves(tp, layer)
        assert len(m) and set(tp.role[m].tolist()) == {Role.GAP_FILL}, layer
        assert seg_lengths(tp, m).sum() > 15.0
        # the bead is as wide as the wall: filament per mm for a 0.4 mm x 0.4 mm section
        vol = float(tp.e[m].sum()) * etitc.tool.filament_area
        assert vol == pytest.approx(20 * 0.4 * s.layer_height, rel=0.2)


def test_bridge_between_towers(etitc):
    s = dataclasses.replace(etitc.slicing, skirt_loops=0)
    tp = slice_mesh(meshes.towers_with_deck(gap=20.0, height=4.0), s, etitc.tool)
    deck0 = int(np.searchsorted(tp.layer_z - s.layer_height / 2, 4.0))  # first layer sliced above the towers
    m = layer_moves(tp, deck0)
    br = m[tp.role[m] == Role.BRIDGE_INFILL]
    assert len(br) > 0
    # lines run from tower to tower (along x) and cross the whole gap
    d = tp.xyz[br, :2] - np.concatenate([[tp.start], tp.xyz])[br, :2]
    long = np.linalg.norm(d, axis=1) > 5
    assert long.any() and np.all(np.abs(d[long, 1]) < 1e-6 + 0.05 * np.abs(d[long, 0]))
    assert np.linalg.norm(d[long], axis=1).max() > 20.0
    # bridge speed and a round bead of nozzle diameter
    assert np.allclose(tp.feed[br], s.bridge_speed)
    fpm = tp.e[br] / np.linalg.norm(d, axis=1)
    assert np.allclose(fpm, np.pi * etitc.tool.nozzle_diameter**2 / 4 / etitc.tool.filament_area * s.bridge_flow)
    # the deck's outline over the gap is an overhang perimeter, slower; over the towers it is not
    ov = m[tp.role[m] == Role.OVERHANG_PERIMETER]
    assert len(ov) and np.allclose(tp.feed[ov], s.overhang_speed)
    assert np.all(np.abs(tp.xyz[ov, 0]) < 10.0 + s.perimeter_width)
    # the layers above and below have no bridges
    assert not np.any(tp.role[layer_moves(tp, deck0 + 1)] == Role.BRIDGE_INFILL)
    assert not np.any(tp.role[layer_moves(tp, deck0 - 1)] == Role.BRIDGE_INFILL)


def test_internal_bridge_over_sparse_infill(etitc):
    tp = slice_mesh(meshes.box(30, 30, 8), etitc.slicing, etitc.tool)
    layers = sorted(set(tp.layer[tp.working & (tp.role == Role.BRIDGE_INFILL)].tolist()))
    # the first solid layer over the sparse infill, and only that one
    top_solid = tp.n_layers - etitc.slicing.top_solid_layers
    assert layers == [top_solid]


def test_travels_inside_the_part_do_not_retract(etitc):
    """Perimeters and sparse infill around a hole: the travels between them stay inside
    the outer loop and off the hole, so they do not retract."""
    tp = slice_mesh(meshes.cube_with_hole(30, 6), dataclasses.replace(etitc.slicing, skirt_loops=0), etitc.tool)
    mid = tp.n_layers // 2
    sl = tp.layer_slices()[mid]
    travels = np.sum(np.diff(tp.working[sl].astype(int)) == -1)
    retracts = np.sum((~tp.working[sl]) & (tp.e[sl] < 0))
    assert travels > 5 and retracts <= 1
    # the rule is about crossing, not distance: a travel over the hole still retracts
    hole = np.hypot(tp.xyz[:, 0], tp.xyz[:, 1]) < 6.0 - 0.3
    crossing = (~tp.working) & hole
    assert not np.any(crossing)


def test_seam_prefers_concave_corner():
    # an L (counter-clockwise): the inner corner at (5, 5) is its only concave vertex
    L = np.array([[0, 0], [10, 0], [10, 5], [5, 5], [5, 10], [0, 10]], float)
    assert concave_corners(L).tolist() == [False, False, False, True, False, False]
    assert seam_index(L, "aligned", np.zeros(2)) == 3
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    assert seam_index(square, "aligned", np.zeros(2)) == 3  # no concave corner: rear, then left


def test_gcode_type_comments(etitc, tmp_path):
    from deltaslice.pipeline import write_gcode

    tp = slice_mesh(meshes.towers_with_deck(), etitc.slicing, etitc.tool)
    out = tmp_path / "deck.gcode"
    write_gcode(tp, out)
    text = out.read_text()
    for name in ("Bridge infill", "Overhang perimeter", "External perimeter"):
        assert f";TYPE:{name}\n" in text


def test_infill_anchored_along_the_outline(etitc):
    """A narrow ring: sparse lines across it are joined along its outline into a few
    paths, not a dash (and a travel) per line."""
    from deltaslice.slicing import slicer

    tp = slice_mesh(meshes.ring(20, 16, 4), etitc.slicing, etitc.tool)
    mid = tp.n_layers // 2
    sl = tp.layer_slices()[mid]
    w = tp.working[sl] & (tp.role[sl] == Role.INFILL)
    runs = int(np.sum(w[1:] & ~w[:-1]) + w[0])
    assert 0 < runs <= 3
    # and without anchors the same ring needs many
    old = slicer.INFILL_ANCHOR_MAX
    try:
        slicer.INFILL_ANCHOR_MAX = 0.0
        tp0 = slice_mesh(meshes.ring(20, 16, 4), etitc.slicing, etitc.tool)
    finally:
        slicer.INFILL_ANCHOR_MAX = old
    sl0 = tp0.layer_slices()[mid]
    w0 = tp0.working[sl0] & (tp0.role[sl0] == Role.INFILL)
    # 5 runs without anchors (6 before zig-zag links were measured as drawn, which joins one more)
    assert int(np.sum(w0[1:] & ~w0[:-1]) + w0[0]) >= 5 * runs


def test_vertical_shell_around_a_hole_starting_above(etitc):
    """A hole opens at z = 5: the layers just under it are solid under the hole and under
    the perimeter band around it (PrusaSlicer's vertical shell); further out, sparse."""
    s = etitc.slicing
    tp = slice_mesh(meshes.blind_hole(20, 10, 4, 5), etitc.slicing, etitc.tool)
    band = s.perimeter_width / 2 + (s.perimeters - 0.5) * (s.perimeter_width - s.layer_height * (1 - np.pi / 4))
    mids = tp.layer_z - s.layer_height / 2
    below = [l for l in range(tp.n_layers) if 5 - s.top_solid_layers * s.layer_height < mids[l] < 5]
    assert below
    for l in below:
        sl = tp.layer_slices()[l]
        r = np.hypot(tp.xyz[sl, 0], tp.xyz[sl, 1])
        solid = tp.working[sl] & np.isin(tp.role[sl], (Role.SOLID_INFILL, Role.TOP_SOLID_INFILL, Role.BRIDGE_INFILL))
        sparse = tp.working[sl] & (tp.role[sl] == Role.INFILL)
        assert r[solid].max() > 4 + band - 0.6
        assert sparse.any() and r[sparse].min() > 4 + band - 0.6


def test_wavering_wall_gets_one_gap_line_not_specks(etitc):
    """A 2.46 mm wall whose one side is a 0.15 mm sawtooth: the third perimeter barely fits
    and would break into specks; they are left to the gap fill, which runs the whole
    length in a few lines."""
    import shapely
    import trimesh

    from deltaslice.mesh import mesh_from_arrays

    x = np.linspace(0, 20, 41)
    saw = np.where(np.arange(41) % 2 == 0, 0.0, 0.15)
    outline = np.vstack([np.column_stack([x, saw]), [[20, 2.456], [0, 2.456]]])
    tm = trimesh.creation.extrude_polygon(shapely.Polygon(outline), 3.0)
    tp = slice_mesh(mesh_from_arrays(tm.vertices, tm.faces, name="sawtooth wall"),
                    dataclasses.replace(etitc.slicing, skirt_loops=0), etitc.tool)
    layer = tp.n_layers // 2
    sl = tp.layer_slices()[layer]
    w = tp.working[sl]
    runs = tp.role[sl][w & ~np.concatenate([[False], w[:-1]])]
    assert np.sum(runs == Role.PERIMETER) <= 2  # the second loop, not a speck per tooth
    assert 1 <= np.sum(runs == Role.GAP_FILL) <= 3
    m = layer_moves(tp, layer)
    g = m[tp.role[m] == Role.GAP_FILL]
    assert seg_lengths(tp, g).sum() > 15.0


@pytest.mark.parametrize("seed", range(4))
def test_voronoi_edges_are_geos_voronoi_and_equidistant(seed):
    """The Delaunay-dual edges are the Voronoi diagram: each end is a vertex of it (its
    nearest input points, three or more, are all at the same distance), and the finite
    edges are GEOS's, edge for edge."""
    import shapely
    from scipy.spatial import cKDTree

    from deltaslice.slicing.gapfill import voronoi_edges

    rng = np.random.default_rng(seed)
    pts = rng.uniform(-10, 10, (300, 2))
    a, b = voronoi_edges(pts)
    assert len(a) > 300
    d, _ = cKDTree(pts).query(np.vstack([a, b]), k=3)
    np.testing.assert_allclose(d[:, 2], d[:, 0], rtol=1e-9)
    # GEOS's edges with both ends well inside the cloud (away from its clipping envelope)
    segs = shapely.get_parts(shapely.get_parts(shapely.voronoi_polygons(shapely.multipoints(pts), only_edges=True)))
    c = shapely.get_coordinates(segs)
    ga, gb = c[0::2], c[1::2]
    inner = (np.abs(ga).max(axis=1) < 8) & (np.abs(gb).max(axis=1) < 8)
    ours = {tuple(np.round(np.sort(np.r_[p, q].reshape(2, 2), axis=0).ravel(), 6)) for p, q in zip(a, b)}
    theirs = [tuple(np.round(np.sort(np.r_[p, q].reshape(2, 2), axis=0).ravel(), 6)) for p, q in zip(ga[inner], gb[inner])]
    assert len(theirs) > 200
    assert all(t in ours for t in theirs)


def test_voronoi_edges_of_points_on_a_line_are_none():
    from deltaslice.slicing.gapfill import voronoi_edges

    a, b = voronoi_edges(np.c_[np.arange(10.0), np.zeros(10)])
    assert a.shape == b.shape == (0, 2)


def test_voronoi_graph_where_geos_gives_up_is_qhulls():
    """Four nearly collinear points and one apart (from seam_test_object.3mf's gap fill): GEOS's
    incremental triangulation raises LocateFailureException on them; the graph is then qhull's,
    each centre as far from its triangle's three corners."""
    from deltaslice.slicing.gapfill import _delaunay, voronoi_graph

    pts = np.array([[10.882982593244659, -1.743052532490439], [10.882924394896971, 4.738074309288118],
                    [10.882918575062202, 5.386186993465973], [10.882901115557896, 7.33052504599954],
                    [5.283212535563977, 8.26500117778778]])
    corner, vertex = _delaunay(pts)
    assert corner.shape == (3, 3, 2) and np.array_equal(pts[vertex], corner)  # 2n - 2 - 5 on the hull
    centre, i, j = voronoi_graph(pts)
    assert len(i) == 2  # the two inner sides
    r = np.linalg.norm(corner - centre[:, None], axis=2)
    np.testing.assert_allclose(r, np.repeat(r[:, :1], 3, axis=1), rtol=1e-6)


@pytest.mark.parametrize("seed", range(3))
def test_voronoi_graph_from_qhull_is_geos(seed, monkeypatch):
    """The fallback triangulation (qhull) gives the graph GEOS's does: the same centres joined
    by the same edges, on random points (GEOS made to give up)."""
    import shapely

    from deltaslice.slicing import gapfill

    pts = np.random.default_rng(seed).uniform(-10, 10, (200, 2))

    def edges(graph):
        centre, i, j = graph
        ends = np.sort(np.round(np.stack([centre[i], centre[j]], axis=1), 9).view(complex)[..., 0], axis=1)
        return sorted(map(tuple, ends))

    theirs = edges(gapfill.voronoi_graph(pts))

    def gives_up(*args, **kwargs):
        raise shapely.errors.GEOSException("LocateFailureException: Could not locate vertex.")

    monkeypatch.setattr(gapfill.shapely, "delaunay_triangles", gives_up)
    ours = edges(gapfill.voronoi_graph(pts))
    assert len(ours) > 300 and ours == theirs


@pytest.mark.parametrize("angle", [0, 13, 37, 71, 90, 133])
@pytest.mark.parametrize("mirror", [False, True])
def test_gap_lines_of_a_t_slot_are_straight_every_way_round(angle, mirror):
    """A T of 0.3 mm slots, turned and mirrored: straight lines (at most three points each,
    eight in all) whichever way the skeleton's lines run. GEOS's topology-preserving
    simplifier kept 5-20 points of an arm in one direction."""
    import shapely
    from shapely import affinity

    from deltaslice.slicing.gapfill import medial_lines

    t = shapely.union(shapely.box(0, 0, 20, 0.3), shapely.box(9.85, 0, 10.15, 5))
    t = affinity.rotate(t, angle, origin=(0, 0))
    if mirror:
        t = affinity.scale(t, -1, 1, origin=(0, 0))
    lines = medial_lines(t, 0.09, 0.9, 0.045, 0.0125, 0.45)
    sizes = [len(p) for p, _ in lines]
    assert len(lines) == 3 and max(sizes) <= 3 and sum(sizes) <= 8, sizes


def test_gap_line_down_a_straight_slot_is_straight():
    """A 20 x 0.3 mm slot: one line down its middle, two points after simplification
    (the Voronoi of the densified outline must not leave a zig-zag of the dense points),
    0.3 mm wide."""
    import shapely

    from deltaslice.slicing.gapfill import medial_lines

    slot = shapely.box(0, 0, 20, 0.3)
    lines = medial_lines(slot, 0.09, 0.9, 0.045, 0.0125, 0.45)
    assert len(lines) == 1
    p, w = lines[0]
    assert len(p) == 2
    np.testing.assert_allclose(p[:, 1], 0.15, atol=1e-9)
    assert abs(p[:, 0].max() - p[:, 0].min()) > 19.6
    np.testing.assert_allclose(w, 0.3, atol=1e-6)


_BOXES = st.lists(st.tuples(st.integers(-20, 20), st.integers(-20, 20), st.integers(1, 15), st.integers(1, 15),
                            st.booleans()), min_size=1, max_size=12)
# regions that touch themselves at a point: Clipper2 keeps each as one ring through the pinch
_PINCHES = [
    [(0, 1, 1, 1, True), (1, 0, 1, 1, True)],  # two squares meeting at a corner
    [(1, 3, 3, 3, True), (1, 2, 2, 2, False), (3, 4, 3, 3, False)],  # cut down to two squares at a corner
    [(1, 1, 2, 2, True), (0, 2, 1, 1, True), (1, 2, 1, 3, False)],  # a square hanging from a notch's corner
    [(0, 0, 1, 1, True), (2, 0, 1, 1, True), (1, 1, 1, 1, True), (0, 2, 1, 1, True), (2, 2, 1, 1, True)],  # checkers
]


def _region(boxes):
    from manifold3d import CrossSection

    region = CrossSection()
    for x, y, w, h, add in boxes:
        box = CrossSection.square([w, h]).translate([x, y])
        region = region + box if add else region - box
    return region


def _with_examples(cases):
    def wrap(f):
        for case in cases:
            f = example(case)(f)
        return f
    return wrap


@settings(max_examples=60, deadline=None)
@example([(0, 0, 10, 10, True), (2, 2, 3, 3, False)])  # a hole
@example([(0, 0, 10, 10, True), (2, 2, 6, 6, False), (4, 4, 2, 2, True), (-5, 12, 3, 3, True)])  # an island in a hole
@example([(0, 0, 10, 10, True), (1, 1, 2, 2, False), (5, 5, 2, 3, False), (3, 3, 2, 2, False)])  # holes touching
@_with_examples(_PINCHES)
@given(_BOXES)
def test_to_shapely_is_the_cross_section(boxes):
    """to_shapely (each part of manifold3d's decompose, its outline first, then its holes) against
    the even-odd overlay of all the contours it replaced: the same region, valid, of the same
    area, for rectangles added and cut in turn (holes, islands in holes, parts touching at a
    corner, a hole touching the outline)."""
    import shapely

    from deltaslice.slicing.gapfill import to_shapely

    region = _region(boxes)
    ours = to_shapely(region)
    overlay = shapely.Polygon()
    for p in region.to_polygons():
        overlay = shapely.symmetric_difference(overlay, shapely.make_valid(shapely.Polygon(np.asarray(p, float))))
    assert ours.is_valid, shapely.is_valid_reason(ours)
    assert ours.area == pytest.approx(region.area(), rel=1e-12, abs=1e-12)
    assert shapely.equals(ours, overlay) or (ours.is_empty and overlay.is_empty)
    # a part split at a pinch is two polygons; nothing else is split or merged
    assert len(shapely.get_parts(ours)) == len(shapely.get_parts(overlay))


def test_to_shapely_splits_the_pinches():
    """Each pinch example is one part to manifold3d (or two that touch) and comes out valid, as
    separate polygons: the old conversion gave a ring through the pinch on three of them."""
    import shapely

    from deltaslice.slicing.gapfill import to_shapely

    for boxes in _PINCHES:
        ours = to_shapely(_region(boxes))
        assert ours.is_valid, (boxes, shapely.is_valid_reason(ours))
        assert len(shapely.get_parts(ours)) >= 2


def _even_odd(region, xy):
    """Independent membership: a point is in the region when a ray from it crosses the region's
    contours an odd number of times. xy: (n, 2) float, mm -> (n,) bool."""
    inside = np.zeros(len(xy), bool)
    for ring in region.to_polygons():
        a = np.asarray(ring, float)
        b = np.roll(a, -1, axis=0)
        x, y = xy[:, :1], xy[:, 1:]
        straddle = (a[:, 1] > y) != (b[:, 1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            cross_x = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        inside ^= (straddle & (x < cross_x)).sum(axis=1) % 2 == 1
    return inside


@settings(max_examples=60, deadline=None)
@_with_examples(_PINCHES)
@given(_BOXES)
def test_shapely_point_tests_match_the_cross_section(boxes):
    """What the slicer asks of a converted region (bridge ends in the support, overhang tests,
    travels inside a part: shapely.contains_xy on a prepared to_shapely) against an even-odd count
    over manifold3d's own contours, on a grid of points off every box edge; and gap fill's medial
    lines run on it."""
    import shapely

    from deltaslice.slicing.gapfill import medial_lines, to_shapely

    region = _region(boxes)
    ours = to_shapely(region)
    shapely.prepare(ours)
    g = np.arange(-20.25, 36, 0.5)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    np.testing.assert_array_equal(shapely.contains_xy(ours, xy[:, 0], xy[:, 1]), _even_odd(region, xy))
    for pts, widths in medial_lines(ours, 0.1, 0.9, 0.25, 0.0125, 0.0, 0.0):
        assert len(pts) == len(widths) + 1
