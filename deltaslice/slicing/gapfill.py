"""Gap fill and thin walls: variable-width lines along the medial axis of narrow regions.

A region too narrow for another perimeter loop (a 2-2.7 mm wall after its loops,
a thin fin, a tiny island thinner than a bead) is filled by one line down its
middle whose width follows the local thickness. The medial axis is taken from
shapely's Voronoi diagram (GEOS) of the densified outline: edges of the diagram
that lie inside the region and stay away from the outline at both ends are the
skeleton (edges between neighbouring points of one side run out to the outline
and are dropped). manifold3d has offsets and booleans but no Voronoi, hence
shapely here.
"""

from __future__ import annotations

import numpy as np
import shapely
from manifold3d import CrossSection


def to_shapely(region: CrossSection):
    """CrossSection -> shapely (Multi)Polygon (even-odd of all contours, as manifold3d stores them)."""
    polys = region.to_polygons()
    if not polys:
        return shapely.Polygon()
    rings = [shapely.Polygon(np.asarray(p, float)) for p in polys if len(p) >= 3]
    out = shapely.Polygon()
    for r in rings:
        out = shapely.symmetric_difference(out, shapely.make_valid(r))
    return out


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


def _skeleton(region, min_width, max_width, step, tolerance, min_length):
    dense = shapely.segmentize(region, step)
    pts = shapely.get_coordinates(shapely.get_exterior_ring(shapely.get_parts(dense)))
    holes = [shapely.get_coordinates(shapely.get_interior_ring(p, i))
             for p in shapely.get_parts(dense) for i in range(shapely.get_num_interior_rings(p))]
    if holes:
        pts = np.vstack([pts] + holes)
    if len(pts) < 3:
        return []
    edges = shapely.voronoi_polygons(shapely.multipoints(pts), only_edges=True)
    segs = shapely.get_parts(shapely.get_parts(edges))
    if len(segs) == 0:
        return []
    coords, idx = shapely.get_coordinates(segs, return_index=True)
    # each Voronoi edge is a 2-point line
    a, b = coords[0::2], coords[1::2]
    shapely.prepare(region)
    inside = shapely.contains_xy(region, a[:, 0], a[:, 1]) & shapely.contains_xy(region, b[:, 0], b[:, 1])
    a, b = a[inside], b[inside]
    if len(a) == 0:
        return []
    boundary = region.boundary
    da = shapely.distance(boundary, shapely.points(a))
    db = shapely.distance(boundary, shapely.points(b))
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
    for line in shapely.get_parts(shapely.simplify(merged, tolerance)):
        p = shapely.get_coordinates(line)
        if len(p) < 2 or line.length < min_length:
            continue
        mid = 0.5 * (p[1:] + p[:-1])
        d = shapely.distance(boundary, shapely.points(mid))
        out.append((p, np.clip(2 * d, min_width, max_width)))
    return out
