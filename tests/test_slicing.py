import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from matplotlib.path import Path as MplPath

from deltaslice.machine import load_printer
from deltaslice.slicing import slice_mesh
from deltaslice.slicing.layers import layer_heights
from deltaslice.toolpath import Role

from . import meshes

SOLID = (Role.SOLID_INFILL, Role.TOP_SOLID_INFILL, Role.BRIDGE_INFILL)


@pytest.fixture(scope="module")
def etitc():
    return load_printer("printers/delta_etitc.toml")


@pytest.fixture(scope="module")
def cube_tp(etitc):
    return slice_mesh(meshes.box(20, 20, 20), etitc.slicing, etitc.tool)


def run_roles(tp, layer):
    """Role of each run (continuous extrusion) in a layer."""
    sl = tp.layer_slices()[layer]
    return [int(tp.role[a]) for a, b in tp.runs() if sl.start <= a < sl.stop]


def roles_in(tp, layer):
    sl = tp.layer_slices()[layer]
    return set(tp.role[sl][tp.working[sl]].tolist())


def test_layer_heights():
    top, mid, th = layer_heights(20.0, 0.4, 0.5)
    assert len(top) == 50
    assert top[0] == pytest.approx(0.5) and np.allclose(np.diff(top), 0.4)
    assert np.all(mid < 20) and th[0] == 0.5


def test_cube_layers_and_moves(cube_tp, etitc):
    tp = cube_tp
    s = etitc.slicing
    assert tp.n_layers == 50
    assert np.allclose(tp.layer_z[:3], [0.5, 0.9, 1.3])
    work = tp.working
    assert np.all(tp.e[work] > 0)
    assert np.all(tp.tool[~work] == 0)
    travel = tp.role == Role.TRAVEL
    assert np.all(tp.e[travel] == 0)
    retract = tp.role == Role.RETRACT
    assert np.allclose(tp.lengths[retract], 0) and np.allclose(np.abs(tp.e[retract]), etitc.tool.retract_length)
    assert tp.e[retract].sum() == pytest.approx(0)  # every retract is undone
    # feeds: first layer speed on layer 0, travel speed on travels
    l0 = tp.layer == 0
    assert np.allclose(tp.feed[l0 & work], s.first_layer_speed)
    assert np.allclose(tp.feed[travel], s.travel_speed)
    later = (tp.layer > 0) & work
    assert np.allclose(tp.feed[later & (tp.role == Role.INFILL)], s.infill_speed)
    assert np.allclose(tp.feed[later & (tp.role == Role.PERIMETER)], s.perimeter_speed)
    # working moves sit at their layer's top
    assert np.allclose(tp.xyz[work, 2], tp.layer_z[tp.layer[work]])
    # skirt on the first layer only, skirt_distance outside the part
    sk = tp.role == Role.SKIRT
    assert np.all(tp.layer[sk] == 0)
    out = np.maximum(np.abs(tp.xyz[sk, :2]) - 10, 0)
    assert np.hypot(out[:, 0], out[:, 1]).min() >= s.skirt_distance - 0.01


def test_cube_perimeter_loops(cube_tp):
    for layer in (0, 10, 49):
        rr = run_roles(cube_tp, layer)
        assert rr.count(Role.EXTERNAL_PERIMETER) == 1
        assert rr.count(Role.PERIMETER) == 2
        # innermost first, external last
        i_ext = rr.index(Role.EXTERNAL_PERIMETER)
        assert all(r == Role.PERIMETER for r in rr[i_ext - 2:i_ext])


def test_cube_solid_layers(cube_tp):
    for layer in range(50):
        roles = roles_in(cube_tp, layer)
        if layer < 3 or layer >= 47:
            assert roles & set(SOLID) and Role.INFILL not in roles, layer
        else:
            assert Role.INFILL in roles and not roles & set(SOLID), layer
    assert Role.TOP_SOLID_INFILL in roles_in(cube_tp, 49)
    assert Role.TOP_SOLID_INFILL not in roles_in(cube_tp, 48)


def test_infill_angle_alternates(cube_tp):
    def angles(layer):
        sl = cube_tp.layer_slices()[layer]
        m = (cube_tp.role[sl] == Role.INFILL)
        d = (cube_tp.xyz[sl] - cube_tp.starts[sl])[m][:, :2]
        long = np.linalg.norm(d, axis=1) > 5
        a = np.degrees(np.arctan2(d[long, 1], d[long, 0])) % 180
        return np.round(a).astype(int)

    assert set(angles(10)) == {45}
    assert set(angles(11)) == {135}


def test_hole_gets_its_own_perimeters(etitc):
    tp = slice_mesh(meshes.cube_with_hole(20, 4), etitc.slicing, etitc.tool)
    rr = run_roles(tp, 20)
    assert rr.count(Role.EXTERNAL_PERIMETER) == 2
    assert rr.count(Role.PERIMETER) == 4
    # nothing extruded inside the hole
    w = tp.working & (tp.layer > 0)
    r = np.hypot(tp.xyz[w, 0], tp.xyz[w, 1])
    assert r.min() >= 4 + etitc.slicing.perimeter_width / 2 - 0.05


def _inside_outline(points, section, tol):
    """Even-odd containment in the outline grown by ``tol`` (manifold3d offset)."""
    polys = section.offset(tol).to_polygons()
    inside = np.zeros(len(points), int)
    for p in polys:
        inside += MplPath(p).contains_points(points)
    return inside % 2 == 1


@pytest.mark.parametrize("maker", [lambda: meshes.cube_with_hole(20, 4), lambda: meshes.step(), lambda: meshes.cylinder(8, 6)])
def test_every_extrusion_inside_the_layer_outline(etitc, maker):
    mesh = maker()
    tp = slice_mesh(mesh, etitc.slicing, etitc.tool)
    man = mesh.to_manifold()
    for layer in range(0, tp.n_layers, 3):
        sl = tp.layer_slices()[layer]
        w = tp.working[sl] & (tp.role[sl] != Role.SKIRT)
        z_mid = tp.layer_z[layer] - (0.5 if layer == 0 else 0.4) / 2
        sec = man.slice(z_mid)
        for pts in (tp.xyz[sl][w, :2], tp.starts[sl][w, :2]):
            ok = _inside_outline(pts, sec, 0.02)
            assert ok.all(), f"layer {layer}: {int((~ok).sum())} points outside, e.g. {pts[~ok][0]}"


def test_mid_height_top_surface_is_solid(etitc):
    tp = slice_mesh(meshes.step(20, 8, 16), etitc.slicing, etitc.tool)
    # the step's top at z = 8 covers x in (0, 10); the tall half is x in (-10, 0)
    mids = tp.layer_z - 0.2  # layer mid-heights (the first layer is far below)
    layers_below = [l for l in range(tp.n_layers) if 8 - 3 * 0.4 < mids[l] < 8]
    assert len(layers_below) == 3
    for l in layers_below:
        sl = tp.layer_slices()[l]
        solid = np.isin(tp.role[sl], SOLID) & tp.working[sl]
        pts = tp.xyz[sl][solid]
        assert len(pts) > 10
        # under the exposed half, plus the perimeter band of the tall half's wall above
        # (vertical shell: the wall at x = 0 above needs solid under it)
        s = etitc.slicing
        band = s.perimeter_width / 2 + (s.perimeters - 0.5) * (s.perimeter_width - s.layer_height * (1 - np.pi / 4))
        assert pts[:, 0].min() > -band - 0.5, "solid infill only under the exposed half and its shell"
        sparse = tp.xyz[sl][(tp.role[sl] == Role.INFILL)]
        assert len(sparse) and sparse[:, 0].max() < 0.5
    top_layer = layers_below[-1]
    assert Role.TOP_SOLID_INFILL in roles_in(tp, top_layer)
    # well below and above the step: no solid
    mid = [l for l in range(tp.n_layers) if 3 < tp.layer_z[l] < 5 or 10 < tp.layer_z[l] < 14]
    for l in mid:
        assert not roles_in(tp, l) & set(SOLID), l


def test_thin_wall_keeps_outer_loop_only(etitc):
    tp = slice_mesh(meshes.thin_wall(1.2, 20, 6), etitc.slicing, etitc.tool)
    rr = run_roles(tp, 5)
    assert rr.count(Role.EXTERNAL_PERIMETER) == 1
    assert Role.PERIMETER not in rr and Role.INFILL not in rr


def expected_volume(tp, sections_area, inner_area, settings):
    """Volume from areas: solid layers fill the whole outline; other layers fill the
    perimeter band fully and the inside at the fill density."""
    vol = 0.0
    for l in range(tp.n_layers):
        h = settings.first_layer_height if l == 0 else settings.layer_height
        roles = roles_in(tp, l)
        if Role.INFILL in roles:
            vol += h * ((sections_area - inner_area) + settings.fill_density * inner_area)
        else:
            vol += h * sections_area
    return vol


def extruded_without_skirt(tp, filament_diameter):
    w = tp.working & (tp.role != Role.SKIRT)
    return float(tp.e[w].sum() * np.pi * filament_diameter**2 / 4)


def test_cube_volume_from_areas(cube_tp, etitc):
    s = etitc.slicing
    from deltaslice.slicing.extrusion import bead_spacing

    # perimeters fill a band up to half a bead spacing inside the innermost loop
    band = s.perimeter_width / 2 + (s.perimeters - 0.5) * bead_spacing(s.perimeter_width, s.layer_height)
    inner_side = 20 - 2 * band
    exp = expected_volume(cube_tp, 400.0, inner_side**2, s)
    got = extruded_without_skirt(cube_tp, etitc.tool.filament_diameter)
    # the zig-zag links between sparse lines (extruded along the perimeter) add a little
    assert exp < got < 1.05 * exp


def test_extrusion_multiplier_and_settings_override(etitc):
    mesh = meshes.box(10, 10, 4)
    base = slice_mesh(mesh, etitc.slicing, etitc.tool)
    more = slice_mesh(mesh, dataclasses.replace(etitc.slicing, extrusion_multiplier=1.1), etitc.tool)
    assert more.e[more.working].sum() == pytest.approx(1.1 * base.e[base.working].sum())
    one = slice_mesh(mesh, dataclasses.replace(etitc.slicing, perimeters=1, skirt_loops=0), etitc.tool)
    rr = run_roles(one, 4)
    assert rr.count(Role.EXTERNAL_PERIMETER) == 1 and Role.PERIMETER not in rr
    assert not np.any(one.role == Role.SKIRT)


def test_z_hop_on_long_travels(etitc):
    tool = dataclasses.replace(etitc.tool, z_hop=0.6)
    printer = dataclasses.replace(etitc, tool=tool)
    # two towers: the travel from one to the other crosses perimeters (travels inside
    # one island do not lift)
    tp = slice_mesh(meshes.towers_with_deck(), printer.slicing, printer.tool)
    trav = (tp.role == Role.TRAVEL) & (tp.layer > 0)
    lifted = tp.xyz[trav, 2] > tp.layer_z[tp.layer[trav]] + 0.5
    assert lifted.any()


def test_progress_called_per_layer(etitc):
    calls = []
    tp = slice_mesh(meshes.box(10, 10, 4), etitc.slicing, etitc.tool, progress=lambda d, t: calls.append((d, t)))
    assert calls == [(i + 1, tp.n_layers) for i in range(tp.n_layers)]


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    x=st.floats(8, 30), y=st.floats(8, 30), z=st.floats(3, 12),
)
def test_solid_box_volume_conserved(etitc, x, y, z):
    """At 100 % fill every layer is solid: the plastic equals the sliced volume."""
    s = dataclasses.replace(etitc.slicing, fill_density=1.0, skirt_loops=0, first_layer_width=etitc.slicing.perimeter_width)
    tp = slice_mesh(meshes.box(x, y, z), s, etitc.tool)
    sliced_height = tp.layer_z[-1]
    got = tp.extruded_volume(etitc.tool.filament_diameter)
    assert got == pytest.approx(x * y * sliced_height, rel=0.06)


def _same_toolpath(a, b):
    for name in ("xyz", "feed", "e", "tool", "role", "layer", "layer_z"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(a.events, b.events)


@pytest.mark.parametrize("make", [lambda: meshes.box(30, 30, 8), lambda: meshes.towers_with_deck(gap=20.0, height=4.0),
                                  lambda: meshes.ring(), lambda: meshes.blind_hole()])
def test_layers_sliced_in_workers_are_the_layers_sliced_here(etitc, make, monkeypatch):
    """Forked workers plan ranges of layers while this process orders them: the same toolpath as
    slicing here, one layer a range (every layer starts from the sparse infill of the layer below
    recomputed on its own: the box's internal bridge over sparse infill needs it)."""
    from deltaslice import pool
    from deltaslice.slicing import slicer

    monkeypatch.setattr(slicer, "LAYERS_PER_TASK", 1)
    mesh = make()
    here = slice_mesh(mesh, etitc.slicing, etitc.tool)
    forked = slice_mesh(mesh, etitc.slicing, etitc.tool, workers=2)
    _same_toolpath(here, forked)
    assert not pool._INHERITED  # the parent keeps no reference


@pytest.mark.parametrize("workers", [1, 2])
def test_slice_mesh_runs_started_once_while_its_workers_slice(etitc, workers):
    """``started`` runs here once, after the workers have their first ranges (before the first
    layer with one process), and changes nothing sliced; what it raises stops the slicing and
    its workers."""
    import multiprocessing
    import os

    mesh = meshes.box(30, 30, 8)
    calls = []

    def started():
        calls.append((os.getpid(), len(multiprocessing.active_children())))

    got = slice_mesh(mesh, etitc.slicing, etitc.tool, workers=workers, started=started)
    assert calls == [(os.getpid(), workers if workers > 1 else 0)]
    _same_toolpath(slice_mesh(mesh, etitc.slicing, etitc.tool), got)

    class Refused(Exception):
        pass

    def refuse():
        raise Refused()

    with pytest.raises(Refused):
        slice_mesh(mesh, etitc.slicing, etitc.tool, workers=workers, started=refuse)
    assert not multiprocessing.active_children()


def test_a_real_part_sliced_in_workers_is_the_part_sliced_here(etitc):
    """featuretype at 5x: 68 layers of islands, gap fill, bridges and solid/sparse switches."""
    from pathlib import Path

    from deltaslice.mesh import load_mesh

    part = Path(__file__).resolve().parents[2] / "shared" / "parts" / "featuretype.STL"
    if not part.exists():
        pytest.skip("../shared/parts is not here")
    mesh = load_mesh(part, scale=5.0)
    _same_toolpath(slice_mesh(mesh, etitc.slicing, etitc.tool), slice_mesh(mesh, etitc.slicing, etitc.tool, workers=2))



def _scanline_segments(rng):
    """Segments (k, xa, xb) on a few scanlines (some lines empty), some with touching ends."""
    lines = np.sort(rng.choice(12, size=int(rng.integers(1, 10)), replace=False))
    k, xa, xb = [], [], []
    for line in lines:
        cuts = np.sort(rng.uniform(0, 20, 2 * int(rng.integers(1, 5))))
        if rng.random() < 0.3:
            cuts = np.round(cuts)  # touching ends: open intervals do not overlap there
        keep = cuts[1::2] > cuts[0::2]
        k += [line] * int(keep.sum())
        xa += cuts[0::2][keep].tolist()
        xb += cuts[1::2][keep].tolist()
    if not k:  # every pair of rounded cuts came out equal: one segment, so there is something to chain
        k, xa, xb = [int(lines[0])], [0.0], [1.0]
    return np.array(k, dtype=np.int64), np.array(xa), np.array(xb)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_infill_chains_link_exactly_the_sole_overlaps_of_neighbouring_lines(seed):
    """chain_segments against its rule evaluated pair by pair (no link too long to cut): segment i
    of scanline k is followed by segment j of scanline k + 1 exactly when each is the other's only
    overlapping segment (open intervals); every segment is in one chain."""
    from deltaslice.slicing.infill import chain_segments

    k, xa, xb = _scanline_segments(np.random.default_rng(seed))
    chains = chain_segments(k, xa, xb, 0.5, np.inf)
    assert sorted(np.concatenate(chains).tolist()) == list(range(len(k)))

    def overlap(i, j):
        return xa[i] < xb[j] and xa[j] < xb[i]

    def sole(i, j):
        return (k[j] == k[i] + 1 and overlap(i, j)
                and sum(overlap(i, m) for m in range(len(k)) if k[m] == k[j]) == 1
                and sum(overlap(m, j) for m in range(len(k)) if k[m] == k[i]) == 1)

    follows = {int(i): int(j) for c in chains for i, j in zip(c[:-1], c[1:])}
    for i in range(len(k)):
        for j in range(len(k)):
            assert (follows.get(i) == j) == sole(i, j), (i, j)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 100_000), max_link=st.floats(0.6, 8.0))
def test_infill_zigzag_links_as_drawn_are_no_longer_than_the_limit(seed, max_link):
    """Every link of every zig-zag polyline, as chain_polylines draws it (each chain's first
    segment forward, then alternating), is at most ``max_link`` long; a chain is cut only where
    its next link, drawn so, would be longer. Cutting with the directions of the chain before the
    cut left 52 of featuretype's 19,141 links up to 3.2 times the limit."""
    from deltaslice.slicing.infill import chain_polylines, chain_segments

    k, xa, xb = _scanline_segments(np.random.default_rng(seed))
    spacing = 0.5
    whole = chain_segments(k, xa, xb, spacing, np.inf)
    chains = chain_segments(k, xa, xb, spacing, max_link)
    assert np.array_equal(np.concatenate(chains), np.concatenate(whole))  # the same order, only cut
    for line in chain_polylines(k, xa, xb, chains, spacing, 0.0):
        links = np.linalg.norm(line[2::2] - line[1:-1:2], axis=1)
        assert np.all(links <= max_link + 1e-12)
    follows = {int(i): int(j) for c in whole for i, j in zip(c[:-1], c[1:])}
    for c in chains[:-1]:
        i = int(c[-1])
        if i in follows:  # a cut: the link this chain would have drawn next is too long
            j = follows[i]
            forward = len(c) % 2 == 1  # the direction of c's last segment
            gap = xb[i] - xb[j] if forward else xa[i] - xa[j]
            assert np.hypot(gap, spacing) > max_link


def test_infill_chains_refuse_segments_not_as_scanlines_give_them():
    """chain_segments finds each segment's overlaps by binary search, which needs a line's
    segments disjoint and in order and the lines in increasing order: other input is refused,
    not chained wrongly."""
    from deltaslice.slicing.infill import chain_segments

    ok = chain_segments(np.array([0, 0, 1]), np.array([0.0, 2.0, 1.0]), np.array([2.0, 3.0, 2.5]), 0.5, np.inf)
    assert [c.tolist() for c in ok] == [[0], [1], [2]]  # touching ends: 2 overlaps, no link
    for k, xa, xb in (([0, 0], [0.0, 1.0], [2.0, 3.0]),  # overlapping on one line
                      ([0, 0], [2.0, 0.0], [3.0, 1.0]),  # out of order on one line
                      ([1, 0], [0.0, 0.0], [1.0, 1.0]),  # lines out of order
                      ([0], [1.0], [1.0])):  # empty segment
        with pytest.raises(ValueError, match="scanline_segments"):
            chain_segments(np.array(k), np.array(xa), np.array(xb), 0.5, np.inf)


def test_infill_chain_cut_restarts_the_zigzag_directions():
    """A chain cut after its first segment starts again forward: the link after the cut is
    measured the way the new chain draws it (xb to xb), not the way the uncut chain would have
    (xa to xa, 0.2 mm here, which let a 15 mm link through)."""
    from deltaslice.slicing.infill import chain_polylines, chain_segments

    k = np.array([0, 1, 2])
    xa, xb = np.array([0.0, 5.0, 5.2]), np.array([10.0, 15.0, 30.0])
    chains = chain_segments(k, xa, xb, 0.5, 2.0)
    assert [c.tolist() for c in chains] == [[0], [1], [2]]
    assert [c.tolist() for c in chain_segments(k, xa, xb, 0.5, 20.0)] == [[0, 1, 2]]
    assert all(len(line) == 2 for line in chain_polylines(k, xa, xb, chains, 0.5, 0.0))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 100_000), anchor=st.floats(0.5, 6.0))
def test_infill_anchors_link_each_line_once_along_the_outline_to_the_nearest_end(seed, anchor):
    """link_along_boundary on a region of rings (many short lines whose ends lie on its
    contours): every line is used once, whole, in its order or reversed; every link follows the
    contour (its points and its segments' midpoints on it) for at most ``anchor`` mm; and each link
    goes to the nearest end along the contour of any line not used yet (shapely's projection,
    measured here afresh), as the greedy chaining promises."""
    import shapely
    from manifold3d import CrossSection

    from deltaslice.slicing.infill import chain_polylines, chain_segments, link_along_boundary, scanline_segments

    rng = np.random.default_rng(seed)
    rings = []
    for _ in range(int(rng.integers(1, 4))):
        c, r = rng.uniform(-15, 15, 2), rng.uniform(3, 8)
        outer = CrossSection.circle(r, int(rng.integers(6, 40))).translate(c)
        rings.append(outer - CrossSection.circle(r * rng.uniform(0.5, 0.85), int(rng.integers(6, 40))).translate(c))
    region = rings[0]
    for ring in rings[1:]:
        region = region + ring
    angle, spacing = float(rng.uniform(0, np.pi)), 0.5
    k, xa, xb = scanline_segments(region, angle, spacing, min_length=0.25)
    lines = chain_polylines(k, xa, xb, chain_segments(k, xa, xb, spacing, 1.0), spacing, angle)
    out = link_along_boundary(lines, region, anchor)
    contours = [shapely.LinearRing(np.asarray(p, float)) for p in region.to_polygons()]
    boundary = shapely.MultiLineString([list(c.coords) for c in contours])

    def on_contour(p):
        d = [c.distance(shapely.Point(p)) for c in contours]
        return int(np.argmin(d)) if min(d) < 1e-6 else -1

    def along(c, p, q):  # distance along contour c between its points p and q, either way
        L, a, b = contours[c].length, contours[c].project(shapely.Point(p)), contours[c].project(shapely.Point(q))
        f = (b - a) % L
        return min(f, L - f)

    used = np.zeros(len(lines), bool)

    def lines_at(poly, j):  # the unused input lines that start at poly[j], whole, forward or reversed
        return [(i, rev) for i, ln in enumerate(lines) for rev in (False, True)
                if not used[i] and len(poly) - j >= len(ln) and np.array_equal(poly[j : j + len(ln)], ln[::-1] if rev else ln)]

    for poly in out:
        at = 0
        last = None
        while at < len(poly):
            hits = lines_at(poly, at)
            if last is not None and not hits:  # a link: points on the outline up to the next line
                j = at
                while not hits:
                    j += 1
                    assert j < len(poly), "a link leads to no line"
                    hits = lines_at(poly, j)
                link = poly[at - 1 : j + 1]
            else:
                j, link = at, poly[at - 1 : at + 1] if last is not None else None
            assert hits, "a polyline does not start with a line"
            i, rev = hits[0]
            if link is not None:
                mids = 0.5 * (link[1:] + link[:-1])
                assert all(boundary.distance(shapely.Point(p)) < 1e-6 for p in np.vstack([link, mids]))
                assert np.linalg.norm(np.diff(link, axis=0), axis=1).sum() <= anchor + 1e-6
                c = on_contour(last)
                here = along(c, last, lines[i][-1] if rev else lines[i][0])
                for o in np.flatnonzero(~used):  # no end of a line left is nearer along that contour
                    for end in (lines[o][0], lines[o][-1]):
                        if on_contour(end) == c:
                            assert here <= along(c, last, end) + 1e-6
            used[i] = True
            at = j + len(lines[i])
            last = poly[at - 1]
    assert used.all() and len(out) <= len(lines)
