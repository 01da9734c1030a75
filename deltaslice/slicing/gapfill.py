"""Gap fill and thin walls: variable-width lines along the medial axis of narrow regions.

A region too narrow for another perimeter loop (a 2-2.7 mm wall after its loops,
a thin fin, a tiny island thinner than a bead) is filled by one line down its
middle whose width follows the local thickness. The medial axis is taken from
the Voronoi diagram of the densified outline (the dual of GEOS's Delaunay
triangulation): edges of the diagram that lie inside the region and stay away
from the outline at both ends are the skeleton (edges between neighbouring points
of one side run out to the outline and are dropped). manifold3d has offsets and
booleans but no Voronoi, hence shapely here (GEOS, which shapely loads anyway: scipy.spatial's
qhull would add its import to every compile's start; it is used only where GEOS's
triangulation gives up, see _delaunay).
"""

from __future__ import annotations

import numpy as np
import shapely
from manifold3d import CrossSection


def to_shapely(region: CrossSection):
    """CrossSection -> valid shapely (Multi)Polygon, one polygon per connected part: manifold3d's
    decompose gives each part's contours, its outline first (Clipper2's tree: an outer node, then
    its holes), which make the polygon as they are (an overlay of all the contours costs 4x).

    Clipper2 keeps a part that touches itself at a point (two squares meeting at a corner, a
    hole touching the outline twice) as one ring through the pinch, which OGC calls invalid and
    GEOS's predicates and offsets then get wrong; only those parts are rebuilt, by GEOS's
    structure method (shells unioned, holes cut), which splits them at the pinch."""
    parts = []
    for part in region.decompose():
        rings = [np.asarray(p, float) for p in part.to_polygons()]
        if rings:  # an empty region decomposes into one empty part
            parts.append(shapely.Polygon(rings[0], rings[1:]))
    if not parts:
        return shapely.Polygon()
    if not shapely.is_valid(parts).all():
        parts = [q for p in parts
                 for q in ([p] if p.is_valid else shapely.get_parts(shapely.make_valid(p, method="structure",
                                                                                         keep_collapsed=False)))
                 if q.area > 0]
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


def medial_lines(region, min_width: float, max_width: float, step: float, tolerance: float = 0.0125,
                 min_length: float = 0.0, min_blob_area: float = 0.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Skeleton of a narrow shapely ``region`` as polylines with a width per segment.

    region: shapely (Multi)Polygon, mm; step: outline densification, mm (about a
    quarter of the thinnest width to resolve). Returns [(points (k, 2) f8 mm,
    widths (k-1,) f8 mm)], widths = twice the distance to the outline, clipped to
    ``max_width``; segments thinner than ``min_width`` are dropped, lines are
    simplified within ``tolerance`` and those shorter than ``min_length`` dropped.
    A part without a skeleton line (a blob) of at least ``min_blob_area`` mm^2 gets
    one short line along its long axis.
    """
    if region.is_empty or region.area <= 0:
        return []
    lines = _skeleton(region, min_width, max_width, step, tolerance, min_length)
    # a blob (a tiny island, a round gap) has no skeleton of constant width: one short
    # line along its long axis carrying its area
    parts = shapely.get_parts(region)
    if len(lines):
        hit = shapely.intersects(parts[:, None], np.array([shapely.LineString(p) for p, _ in lines])[None, :]).any(axis=1)
        parts = parts[~hit]
    for part in parts:
        if part.area >= min_blob_area:
            lines += _blob_line(part, min_width, max_width)
    return lines


def _blob_line(part, min_width: float, max_width: float) -> list[tuple[np.ndarray, np.ndarray]]:
    rect = shapely.get_coordinates(shapely.oriented_envelope(part))[:4]
    if len(rect) < 4:
        return []
    e1, e2 = rect[1] - rect[0], rect[2] - rect[1]
    long, short = (e1, e2) if np.hypot(*e1) >= np.hypot(*e2) else (e2, e1)
    ll, ls = float(np.hypot(*long)), float(np.hypot(*short))
    if ls < min_width:
        return []
    length = max(ll - ls / 2, ls / 2)
    width = min(part.area / length, max_width)
    c = rect.mean(axis=0)
    u = long / ll
    return [(np.array([c - u * length / 2, c + u * length / 2]), np.array([width]))]


def voronoi_edges(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The finite edges of the Voronoi diagram of ``pts`` ((n, 2) float, mm), as their
    ends ``a, b`` ((m, 2) float, mm each): the segment between the circumcentres of each
    pair of neighbouring Delaunay triangles. Rays to infinity are left out (they end
    outside any region the points outline). Cocircular points give edges of (nearly)
    zero length, which the caller's chaining absorbs.

    The dual of the Delaunay triangulation, not GEOS's ``voronoi_polygons``: that clips the
    diagram to its envelope with a full overlay, 20x the cost of the triangulation.
    """
    centre, i, j = voronoi_graph(pts)
    return centre[i], centre[j]


def voronoi_graph(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`voronoi_edges` as a graph: the Delaunay triangles' circumcentres ``centre``
    ((t, 2) float, mm; a flat triangle's not finite) and the finite edges as pairs of their
    indices ``i, j`` ((m,) int), each vertex of the diagram once however many edges meet there."""
    corner, vertex = _delaunay(pts)
    if len(corner) == 0:  # all points on one line: no triangle, no edge
        return np.empty((0, 2)), np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp)
    origin = pts.mean(axis=0)  # circumcentres relative to the cloud, against cancellation
    p = corner - origin  # (t, 3, 2)
    bv, cv = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d = 2.0 * (bv[:, 0] * cv[:, 1] - bv[:, 1] * cv[:, 0])
    b2, c2 = np.sum(bv**2, axis=1), np.sum(cv**2, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):  # a flat triangle's centre is at infinity
        ux = (cv[:, 1] * b2 - bv[:, 1] * c2) / d
        uy = (bv[:, 0] * c2 - cv[:, 0] * b2) / d
    centre = p[:, 0] + np.c_[ux, uy] + origin
    # neighbours share a side: each side's key (its two corners) sorted, equal keys side by side
    a, b = vertex, vertex[:, [1, 2, 0]]  # each side's two corners
    key = (np.minimum(a, b) * (int(vertex.max()) + 1) + np.maximum(a, b)).ravel()
    order = np.argsort(key, kind="stable")
    key, owner = key[order], np.repeat(np.arange(len(p)), 3)[order]
    shared = key[1:] == key[:-1]  # a side on the hull is in one triangle: a ray, left out
    i, j = owner[:-1][shared], owner[1:][shared]
    finite = np.isfinite(centre).all(axis=1)
    ok = finite[i] & finite[j]
    return centre, i[ok], j[ok]


def _delaunay(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Delaunay triangles of ``pts`` ((n, 2) float, mm): their corners ((t, 3, 2) float, mm)
    and the corners' vertex numbers ((t, 3) int: the same point, the same number); none where
    the points are all on one line. GEOS's triangulation; qhull's (scipy imported only then)
    where GEOS's incremental insertion gives up (``LocateFailureException``, seen on four
    nearly collinear points and one apart)."""
    none = np.empty((0, 3, 2)), np.empty((0, 3), dtype=np.intp)
    try:
        tris = shapely.get_parts(shapely.delaunay_triangles(shapely.multipoints(pts)))
    except shapely.errors.GEOSException:
        from scipy.spatial import Delaunay, QhullError

        try:
            tri = Delaunay(pts)
        except QhullError:
            return none
        return tri.points[tri.simplices], tri.simplices
    if len(tris) == 0:
        return none
    corner = shapely.get_coordinates(tris).reshape(len(tris), 4, 2)[:, :3]  # closed rings
    # GEOS gives the corners, not their indices: number them by value
    _, vertex = np.unique((corner[..., 0] + 1j * corner[..., 1]).ravel(), return_inverse=True)
    return corner, vertex.reshape(-1, 3)


def _skeleton(region, min_width, max_width, step, tolerance, min_length):
    dense = shapely.segmentize(region, step)
    pts = shapely.get_coordinates(shapely.get_exterior_ring(shapely.get_parts(dense)))
    holes = [shapely.get_coordinates(shapely.get_interior_ring(p, i))
             for p in shapely.get_parts(dense) for i in range(shapely.get_num_interior_rings(p))]
    if holes:
        pts = np.vstack([pts] + holes)
    if len(pts) < 3:
        return []
    centre, i, j = voronoi_graph(pts)
    if len(i) == 0:
        return []
    # each vertex of the diagram tested and measured once, not once per edge that ends there
    used = np.zeros(len(centre), dtype=bool)
    used[i] = used[j] = True
    shapely.prepare(region)
    inside = np.zeros(len(centre), dtype=bool)
    inside[used] = shapely.contains_xy(region, centre[used, 0], centre[used, 1])
    keep = inside[i] & inside[j]
    i, j = i[keep], j[keep]
    if len(i) == 0:
        return []
    boundary = region.boundary
    used[:] = False
    used[i] = used[j] = True
    dist = np.zeros(len(centre))
    dist[used] = shapely.distance(boundary, shapely.points(centre[used]))
    a, b, da, db = centre[i], centre[j], dist[i], dist[j]
    lo, hi = np.minimum(da, db), np.maximum(da, db)
    # skeleton edges keep their distance to the outline; spokes run out to it
    keep = (lo > 0.6 * hi) & (lo > 0.5 * min_width / 2) & (hi > step * 0.3)
    a, b, w = a[keep], b[keep], (da[keep] + db[keep])  # width = 2 * mean distance
    keep = w >= min_width
    a, b, w = a[keep], b[keep], np.minimum(w[keep], max_width)
    if len(a) == 0:
        return []
    merged = shapely.line_merge(shapely.multilinestrings(shapely.linestrings(np.stack([a, b], axis=1))))
    out = []
    # Douglas-Peucker line by line: GEOS's topology-preserving simplifier depends on a line's
    # direction (it kept 13-20 points of a slanted T-slot's straight arms one way, 2 the other)
    for line in shapely.get_parts(shapely.simplify(merged, tolerance, preserve_topology=False)):
        p = shapely.get_coordinates(line)
        if len(p) < 2 or line.length < min_length:
            continue
        mid = 0.5 * (p[1:] + p[:-1])
        d = shapely.distance(boundary, shapely.points(mid))
        out.append((p, np.clip(2 * d, min_width, max_width)))
    return out
