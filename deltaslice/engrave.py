"""Laser engraving front end: an image (PNG, JPG, BMP, TIFF) or an SVG -> Toolpath.

Two modes, as in the ESPE engraver's own software (``drawing.py``: "vectorise or rasterise"):

* **vector**: edges of the image (Gaussian blur ``blur`` px, ``gamma`` on the grey levels,
  Canny with ``low``/``high`` thresholds and Sobel ``aperture``) traced into closed polylines,
  simplified within ``tolerance`` mm (Douglas-Peucker), ordered nearest-first from the start
  so travels stay short. SVG input: every path or shape with a stroke is burnt along its
  outline (curves flattened within ``tolerance``).
* **raster**: the image resampled to one row per ``line_pitch`` (default: the laser's
  ``[tool] spot_size``), power from the grey level (``gamma``, optional ordered dithering),
  bidirectional scan lines with ``overscan`` mm of laser-off travel beyond every burnt
  stretch so the tool is at its line speed before the laser turns on; white stretches
  longer than two overscans are skipped with travels.

Power follows speed: moves get ``Role.LASER_DYNAMIC`` (GRBL M4) by default, so the planner
samples ``power x speed / feed`` and a corner where the joints force the tool to slow burns
no darker than a line (``dynamic_power=False``: ``Role.LASER``, constant power, M3).

Why OpenCV (``opencv-python-headless``) rather than scikit-image: the source document's
software vectorises with OpenCV (its parameters smooth, gamma, aperture, lowThreshold,
highThreshold are Canny's), so the same settings mean the same edges here; and Canny,
``findContours`` (contours as ordered pixel chains, outer ones told from holes) and
``approxPolyDP`` come in one compiled wheel with no GUI libraries. scikit-image's
``find_contours`` gives sub-pixel iso-lines but no hierarchy and no simplifier of its own.

Units: images in pixels (row 0 at the top), everything returned in mm in the bed frame
(x right, y away from the viewer, origin at the bed centre), z = ``z`` mm.
"""

from __future__ import annotations

import difflib
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from .errors import DeltasliceError
from .formats import is_svg
from .tolerances import SAME_LENGTH
from .toolpath import Role, Toolpath, ToolpathBuilder

MAX_PIXELS = 25_000_000  # larger images and rasters are refused: 5000 x 5000 px is far finer than any spot
# No SVG drawing spans a billion user units (26 km at 96 per inch); a larger coordinate (1e308, a
# number of 320 digits) would overflow the scaling and the curve flattening to inf and NaN.
SVG_MAGNITUDE = 1e9
SVG_NAMESPACE = "http://www.w3.org/2000/svg"
# Points the SVG's outlines may become once curves are flattened: a curve of any chord becomes up to
# 2,000, so 250 KB of long quadratic curves asked for 2 GB. No engraving has a million corners.
MAX_SVG_POINTS = 2_000_000


class EngraveError(DeltasliceError):
    """An image or SVG cannot be turned into an engraving."""


@dataclass(frozen=True)
class EngraveOptions:
    """How to engrave. Sizes in mm, speeds in mm/s, power as a fraction 0..1.

    width/height: size of the image on the work (one given: aspect kept; none: the largest
    that fits, or an SVG's own size). feed: burning speed (default: the printer's
    perimeter_speed in vector mode, infill_speed in raster mode); travel_feed: default
    travel_speed. blur: Gaussian sigma, px; gamma: exponent on grey levels 0..1 (> 1 darkens
    mid-tones); low/high: Canny hysteresis thresholds on 0..255 grey; aperture: Sobel size
    3, 5 or 7. tolerance: polyline simplification, mm. line_pitch: raster row spacing, mm
    (default: the spot size); levels: raster power steps; overscan: mm beyond each burnt
    stretch (default: from the joints' acceleration at the raster feed)."""

    mode: str = "vector"
    width: float | None = None
    height: float | None = None
    invert: bool = False
    power: float = 1.0
    dynamic_power: bool = True
    feed: float | None = None
    travel_feed: float | None = None
    z: float = 0.0
    blur: float = 1.0
    gamma: float = 1.0
    low: float = 50.0
    high: float = 150.0
    aperture: int = 3
    tolerance: float = 0.05
    line_pitch: float | None = None
    levels: int = 16
    dither: bool = False
    overscan: float | None = None

    def check(self, where: str) -> None:
        def bad(key, value, expected):
            raise EngraveError(f"{where}: engraving option {key} = {value!r}: expected {expected}")

        for key in ("width", "height", "power", "feed", "travel_feed", "z", "blur", "gamma", "low", "high",
                    "tolerance", "line_pitch", "overscan", "aperture", "levels"):
            v = getattr(self, key)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating))):
                bad(key, v, "a number")  # a string reached numpy's isfinite as a TypeError
        for key in ("invert", "dynamic_power", "dither"):
            if not isinstance(getattr(self, key), (bool, np.bool_)):
                bad(key, getattr(self, key), "True or False")
        if self.mode not in ("vector", "raster"):
            bad("mode", self.mode, "'vector' or 'raster'")
        for key in ("width", "height", "feed", "travel_feed", "line_pitch", "overscan"):
            v = getattr(self, key)
            if v is not None and not (np.isfinite(v) and v > 0):
                bad(key, v, "a number > 0")
        if not 0 < self.power <= 1:
            bad("power", self.power, "a fraction 0 < power <= 1")
        if not (self.gamma > 0 and np.isfinite(self.gamma)):
            bad("gamma", self.gamma, "a number > 0")
        if not self.blur >= 0:
            bad("blur", self.blur, "a number >= 0")
        if not (0 <= self.low <= self.high <= 255):
            bad("low/high", (self.low, self.high), "0 <= low <= high <= 255")
        if self.aperture not in (3, 5, 7):
            bad("aperture", self.aperture, "3, 5 or 7")
        if not self.tolerance > 0:
            bad("tolerance", self.tolerance, "a number > 0")
        if not 2 <= self.levels <= 256:
            bad("levels", self.levels, "an integer 2..256")


# --------------------------------------------------------------------------- entry point


def engrave_options(options, where: str = "engrave") -> EngraveOptions:
    """``options`` as :class:`EngraveOptions`: one already, None (the defaults) or a mapping of its
    fields; anything else, or an unknown field, is refused by name."""
    if isinstance(options, EngraveOptions):
        return options
    if options is None:
        return EngraveOptions()
    if not isinstance(options, Mapping):
        raise EngraveError(f"{where}: engraving options = {options!r:.60}: expected a dict of EngraveOptions fields")
    known = {f.name for f in fields(EngraveOptions)}
    for key in options:
        if key not in known:
            close = difflib.get_close_matches(str(key), sorted(known), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise EngraveError(f"{where}: unknown engraving option {key!r}{hint}: expected one of {', '.join(sorted(known))}")
    return EngraveOptions(**options)


def engrave(path, printer, options: EngraveOptions | dict | None = None) -> Toolpath:
    """A Toolpath engraving the image or SVG at ``path`` with ``printer``'s laser."""
    where = str(path)
    opts = engrave_options(options, where)
    opts.check(where)
    if not printer.tool.takes_laser_power:
        raise EngraveError(f"{where}: printer {printer.name} has no laser ([tool] kind = 'extruder'): images are for lasers")
    if is_svg(path):
        lines, frame = svg_polylines(path, opts.tolerance)
        size = _svg_default_size(frame) if opts.width is None and opts.height is None else None
        if opts.mode == "raster":
            raise EngraveError(f"{where}: raster mode needs an image; an SVG is engraved in vector mode")
        w, h = _place(where, printer, frame[2] - frame[0], frame[3] - frame[1], opts, default=size)
        sx, sy = w / (frame[2] - frame[0]), h / (frame[3] - frame[1])
        mm = [np.column_stack([(p[:, 0] - frame[0]) * sx - w / 2, h / 2 - (p[:, 1] - frame[1]) * sy]) for p in lines]
        return _vector_toolpath(mm, printer, opts)
    grey = load_grey(path)
    if opts.invert:
        grey = 1.0 - grey
    grey = grey**opts.gamma
    if float(grey.max() - grey.min()) < 1.0 / 255:
        tone = "black" if grey.mean() < 0.5 else "white"
        raise EngraveError(f"{where}: the image is uniformly {tone} ({grey.shape[1]} x {grey.shape[0]} px): nothing to engrave")
    if opts.mode == "vector":
        w, h = _place(where, printer, grey.shape[1], grey.shape[0], opts)
        px = image_contours(grey, opts.blur, opts.low, opts.high, opts.aperture, opts.tolerance * grey.shape[1] / w)
        if not px:
            raise EngraveError(
                f"{where}: no edges found (Canny thresholds low = {opts.low:g}, high = {opts.high:g}, blur = {opts.blur:g} px): "
                "lower the thresholds or the blur"
            )
        sx, sy = w / grey.shape[1], h / grey.shape[0]
        mm = [np.column_stack([(p[:, 0] + 0.5) * sx - w / 2, h / 2 - (p[:, 1] + 0.5) * sy]) for p in px]
        return _vector_toolpath(mm, printer, opts)
    return _raster_toolpath(where, grey, printer, opts)


# --------------------------------------------------------------------------- images


def load_grey(path) -> np.ndarray:
    """Grey levels of an image: (rows, cols) f8, 0 black .. 1 white; transparency counts as white."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise EngraveError(f"{path}: no such image file")
    if path.stat().st_size == 0:
        raise EngraveError(f"{path}: empty file, not an image")
    try:
        # Pillow warns about what it skips in a damaged file (EXIF, TIFF tags) in Python's own format on
        # stderr; the image is used or refused here, in one line
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as im:
                cols, rows = im.size
                if cols * rows == 0:
                    raise EngraveError(f"{path}: the image has no pixels ({cols} x {rows})")
                if cols * rows > MAX_PIXELS:
                    raise EngraveError(
                        f"{path}: image of {cols} x {rows} px is too large ({cols * rows / 1e6:.0f} Mpx > "
                        f"{MAX_PIXELS / 1e6:.0f} Mpx): scale it down"
                    )
                la = np.asarray(im.convert("LA"), dtype=float) / 255.0
    except Image.DecompressionBombError:  # Pillow refuses to open over ~179 Mpx, before our own bound
        raise EngraveError(
            f"{path}: image is too large (over {MAX_PIXELS / 1e6:.0f} Mpx, Pillow's decompression-bomb bound): "
            "scale it down"
        ) from None
    except UnidentifiedImageError:
        raise EngraveError(f"{path}: not an image file Pillow can read (PNG, JPG, BMP, TIFF, ...)") from None
    except OSError as exc:
        if exc.strerror:  # the file system's own reason (permission denied, ...)
            raise EngraveError(f"{path}: cannot read the image: {exc.strerror}") from None
        raise EngraveError(f"{path}: the image is damaged or truncated ({exc})") from None
    except EngraveError:
        raise
    except Exception as exc:  # Pillow's decoders raise what they meet: SyntaxError for a broken PNG chunk, ValueError
        raise EngraveError(f"{path}: the image is damaged or of an unsupported kind ({exc or 'no detail'})") from None
    return la[..., 0] * la[..., 1] + (1.0 - la[..., 1])


def image_contours(grey: np.ndarray, blur: float, low: float, high: float, aperture: int, eps_px: float) -> list[np.ndarray]:
    """Closed edge polylines of a grey image (rows, cols) 0..1, in pixel coordinates
    (x = column, y = row), each (k, 2) f8 with its first point repeated at the end.

    Canny edges are one pixel wide; their outer borders (``RETR_CCOMP`` without the holes)
    give one loop per edge chain, simplified with ``approxPolyDP`` within eps_px."""
    import cv2

    img = np.clip(np.rint(grey * 255), 0, 255).astype(np.uint8)
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    edges = cv2.Canny(img, low, high, apertureSize=aperture, L2gradient=True)
    contours, hierarchy = cv2.findContours(edges, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if hierarchy is None:
        return []
    out = []
    for c, h in zip(contours, hierarchy[0]):
        if h[3] != -1 or len(c) < 3:
            continue
        p = cv2.approxPolyDP(c.astype(np.float32), max(eps_px, 1e-3), True).reshape(-1, 2).astype(float)
        if len(p) >= 2:
            out.append(np.concatenate([p, p[:1]]))
    return out


# --------------------------------------------------------------------------- SVG


def svg_polylines(path, tolerance: float) -> tuple[list[np.ndarray], tuple]:
    """Stroked outlines of an SVG as polylines (k, 2) in SVG user units (y down), curves
    flattened to chords of at most ~``tolerance`` sag, and the frame (xmin, ymin, xmax, ymax)."""
    import svgelements as se

    try:
        svg = se.SVG.parse(str(path), reify=True)
    except FileNotFoundError:
        raise EngraveError(f"{path}: no such SVG file") from None
    except SyntaxError as exc:  # xml.etree's ParseError: the message says where
        raise EngraveError(f"{path}: not well-formed XML, so not a readable SVG ({exc})") from None
    except OSError as exc:
        raise EngraveError(f"{path}: cannot read the SVG: {exc.strerror or exc}") from None
    except Exception as exc:  # svgelements raises errors of several kinds on bad attribute values
        raise EngraveError(f"{path}: not a readable SVG ({exc or 'malformed content'})") from None
    if not isinstance(svg, se.SVG):  # svgelements reads only SVG's own namespace; another root is a bare element
        tag = str(getattr(svg, "values", {}).get("tag", "?"))
        raise EngraveError(f"{path}: the root element is <{tag}>, not an SVG drawing (expected <svg> in the "
                           f"namespace {SVG_NAMESPACE})")
    lines = []
    total = [0]  # points made so far, against MAX_SVG_POINTS

    def point(p) -> np.ndarray:
        xy = np.array([[p.x, p.y]], dtype=float)
        if not (np.isfinite(xy).all() and np.abs(xy).max() <= SVG_MAGNITUDE):
            size = "overflows" if not np.isfinite(xy).all() else f"is beyond +-{SVG_MAGNITUDE:g} user units"
            raise EngraveError(
                f"{path}: an SVG coordinate ({xy[0, 0]:.4g}, {xy[0, 1]:.4g}), after the width, height, viewBox and "
                f"transforms, {size}: no drawing is that large"
            )
        return xy

    for el in svg.elements():
        if not isinstance(el, se.Shape) or el.stroke is None or el.stroke.value is None:
            continue
        if el.values.get("visibility") == "hidden":
            continue
        current: list[np.ndarray] = []
        for seg in se.Path(el).segments():
            if isinstance(seg, se.Move):
                if len(current) > 1:
                    lines.append(np.concatenate(current))
                current = [point(seg.end)]
            elif isinstance(seg, (se.Line, se.Close)):
                if seg.end is not None and current:
                    current.append(point(seg.end))
            elif current:
                chord = max(float(np.hypot(*(point(seg.end) - point(seg.start))[0])), SAME_LENGTH)
                n = int(np.clip(np.ceil(np.sqrt(chord / (8 * tolerance)) * 4), 4, 2000))
                total[0] += n
                if total[0] > MAX_SVG_POINTS:
                    raise EngraveError(
                        f"{path}: its outlines become more than {MAX_SVG_POINTS:,} points once curves are flattened "
                        f"to a tolerance of {tolerance:g}: simplify the drawing, or engrave it as an image"
                    )
                with np.errstate(all="ignore"):  # a far control point overflows: refused just below
                    flat = np.asarray(seg.npoint(np.linspace(0, 1, n + 1)[1:]), dtype=float)
                for p in flat[~(np.isfinite(flat).all(axis=1) & (np.abs(flat).max(axis=1) <= SVG_MAGNITUDE))][:1]:
                    point(se.Point(*p))  # a control point far out takes the curve there: refused as one
                current.append(flat)
        if len(current) > 1:
            lines.append(np.concatenate(current))
    lines = [p for p in lines if len(p) > 1 and np.ptp(p, axis=0).max() > 0]
    if not lines:
        raise EngraveError(f"{path}: no stroked path or shape in the SVG (a stroke is what the laser burns)")
    allp = np.concatenate(lines)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    span = np.maximum(hi - lo, 1e-6 * max(float((hi - lo).max()), 1.0))
    return lines, (float(lo[0]), float(lo[1]), float(lo[0] + span[0]), float(lo[1] + span[1]))


def _svg_default_size(frame):
    """An SVG's own size in mm (user units are CSS px, 96 per inch)."""
    return ((frame[2] - frame[0]) * 25.4 / 96, (frame[3] - frame[1]) * 25.4 / 96)


# --------------------------------------------------------------------------- placement


def _fits(kin, bed, w: float, h: float, z: float) -> bool:
    """Whether a w x h mm rectangle centred on the bed lies on the bed and in reach at z."""
    if not (np.isfinite(w) and np.isfinite(h)):
        return False
    u = np.linspace(-0.5, 0.5, 25)
    X, Y = np.meshgrid(u * w, u * h)
    pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z)])
    return bool(bed.contains_xy(pts[:, :2]).all() and kin.reachable(pts).all())


def _place(where, printer, px_w: float, px_h: float, opts: EngraveOptions, default=None, margin_x: float = 0.0):
    """Size (w, h) mm of the engraving: the requested width and/or height (aspect kept when
    one is given), else ``default``, else the largest that fits. Refuses, naming the largest
    size that fits, when it does not fit on the bed and in reach. margin_x: extra mm needed
    on both sides in x (raster overscan)."""
    kin, bed = printer.kinematics(), printer.bed
    aspect = px_h / px_w
    if opts.width is not None and opts.height is not None:
        w, h = opts.width, opts.height
    elif opts.width is not None:
        w, h = opts.width, opts.width * aspect
    elif opts.height is not None:
        w, h = opts.height / aspect, opts.height
    elif default is not None:
        w, h = default
    else:
        w, h = None, None
    ok = lambda f: _fits(kin, bed, f * base_w + 2 * margin_x, f * base_h, opts.z)  # noqa: E731
    base_w, base_h = (w, h) if w is not None else (1.0, aspect)
    if w is not None and ok(1.0):
        return w, h
    # the scale of a 1 um engraving: a requested size of any magnitude searches down to it
    tiny = 1e-3 / max(base_w, base_h)
    if not ok(tiny):
        raise EngraveError(f"{where}: no part of the work area is in reach of {printer.name} at z = {opts.z:g} mm")
    lo, hi = tiny, 1.0
    while ok(hi) and hi < 1e4:
        lo, hi = hi, hi * 2
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    fw, fh = lo * base_w, lo * base_h
    if w is None:
        return fw * 0.999, fh * 0.999
    raise EngraveError(
        f"{where}: a {w:.1f} x {h:.1f} mm engraving does not fit the reachable work area of {printer.name} "
        f"(bed {bed.size_x:g} x {bed.size_y:g} mm at z = {opts.z:g} mm); the largest that fits is "
        f"{fw:.1f} x {fh:.1f} mm (--width {np.floor(fw * 10) / 10:.1f})"
    )


# --------------------------------------------------------------------------- vector


def order_polylines(lines: list[np.ndarray], start) -> list[np.ndarray]:
    """Nearest-first order: from ``start`` (2,), repeatedly the polyline with the nearest
    entry point: any vertex of a closed one (rotated to begin there), either end of an open
    one (reversed if needed). lines: (k, 2) f8 mm. One vectorised search per polyline."""
    if not lines:
        return []
    closed = np.array([len(p) > 2 and np.allclose(p[0], p[-1]) for p in lines])
    cand, owner, index = [], [], []
    for i, p in enumerate(lines):
        idx = np.arange(len(p) - 1) if closed[i] else np.array([0, len(p) - 1])
        cand.append(p[idx])
        owner.append(np.full(len(idx), i))
        index.append(idx)
    cand, owner, index = np.concatenate(cand), np.concatenate(owner), np.concatenate(index)
    alive = np.ones(len(cand), bool)
    pos = np.asarray(start, float)[:2]
    out = []
    for _ in range(len(lines)):
        d = np.where(alive, np.einsum("ij,ij->i", cand - pos, cand - pos), np.inf)
        k = int(np.argmin(d))
        i, v = int(owner[k]), int(index[k])
        p = lines[i]
        if closed[i]:
            p = np.concatenate([p[v:-1], p[: v + 1]])
        elif v != 0:
            p = p[::-1]
        out.append(p)
        alive[owner == i] = False
        pos = p[-1]
    return out


def _vector_toolpath(lines_mm: list[np.ndarray], printer, opts: EngraveOptions) -> Toolpath:
    feed = opts.feed or printer.slicing.perimeter_speed
    travel = opts.travel_feed or printer.slicing.travel_speed
    role = Role.LASER_DYNAMIC if opts.dynamic_power else Role.LASER
    z = opts.z
    b = ToolpathBuilder(start=(0.0, 0.0, z))
    b.new_layer(z)
    for p in order_polylines(lines_mm, b.start):
        xyz = np.column_stack([p, np.full(len(p), z)])
        b.add(xyz[:1], travel, 0.0, 0.0, Role.TRAVEL)
        b.add(xyz[1:], feed, 0.0, opts.power, role)
    return b.build()


# --------------------------------------------------------------------------- raster


def default_overscan(printer, feed: float, w: float, h: float, z: float) -> float:
    """Laser-off run-up (mm) for the tool to reach ``feed`` along x anywhere in the w x h
    rectangle: v^2 / a with a the tool acceleration the weakest joint allows there (twice
    the constant-acceleration distance: the path's curvature in joint space uses some of
    the joint acceleration too), at least one millimetre."""
    kin = printer.kinematics()
    u = np.linspace(-0.5, 0.5, 9)
    X, Y = np.meshgrid(u * w, u * h)
    pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z)])
    q = kin.inverse(pts)
    dq_dx = np.abs(kin.inverse_jacobian(q)[:, :, 0])  # (N, J) rad per mm along x
    amax = printer.planned_limits().acceleration[: printer.n_joints]
    a_tool = float(np.nanmin(amax[None] / np.maximum(dq_dx, 1e-12)))
    return max(1.0, feed * feed / a_tool)


def raster_powers(grey: np.ndarray, levels: int, dither: bool, power: float) -> np.ndarray:
    """Power 0..power per pixel from grey (rows, cols) 0..1 (0 black): darkness quantised
    to ``levels`` steps, or on/off by an 8 x 8 Bayer ordered dither (vectorised, unlike
    error diffusion, and free of its worm artefacts along scan lines)."""
    dark = 1.0 - grey
    if dither:
        b = np.array([[0]])
        for _ in range(3):
            b = np.block([[4 * b, 4 * b + 2], [4 * b + 3, 4 * b + 1]])
        thr = (b + 0.5) / b.size
        r, c = grey.shape
        on = dark > np.tile(thr, (r // 8 + 1, c // 8 + 1))[:r, :c]
        return on * power
    q = np.rint(dark * (levels - 1)) / (levels - 1)
    return q * power


def _raster_toolpath(where, grey: np.ndarray, printer, opts: EngraveOptions) -> Toolpath:
    import cv2

    feed = opts.feed or printer.slicing.infill_speed
    travel = opts.travel_feed or printer.slicing.travel_speed
    pitch = opts.line_pitch or printer.tool.spot_size
    w0, h0 = _place(where, printer, grey.shape[1], grey.shape[0], opts)
    over = opts.overscan or default_overscan(printer, feed, w0, h0, opts.z)
    w, h = _place(where, printer, grey.shape[1], grey.shape[0], opts, margin_x=over)
    rows, cols = max(1.0, round(h / pitch)), max(1.0, round(w / pitch))
    if rows * cols > MAX_PIXELS:  # before OpenCV allocates it: 1e-6 mm lines asked for 3.8e16 bytes
        least = float(np.sqrt(w * h / MAX_PIXELS))
        raise EngraveError(
            f"{where}: a line pitch of {pitch:g} mm makes a raster of {cols:.4g} x {rows:.4g} dots over {w:.1f} x {h:.1f} mm, "
            f"more than {MAX_PIXELS / 1e6:.0f} Mpx: use a line pitch of at least {least:.3g} mm"
        )
    rows, cols = int(rows), int(cols)
    small = cv2.resize(grey.astype(np.float32), (cols, rows), interpolation=cv2.INTER_AREA).astype(float)
    pw = raster_powers(small, opts.levels, opts.dither, opts.power)
    pw[pw < 1.0 / printer.tool.power_counts] = 0.0
    if not pw.any():
        raise EngraveError(f"{where}: no pixel dark enough to burn at {pitch:g} mm per line")
    dx, dy = w / cols, h / rows
    xedge = -w / 2 + dx * np.arange(cols + 1)
    role = Role.LASER_DYNAMIC if opts.dynamic_power else Role.LASER
    bridge = int(np.ceil(2 * over / dx))  # shorter white gaps are crossed at speed, laser off
    z = opts.z
    b = ToolpathBuilder(start=(0.0, 0.0, z))
    b.new_layer(z)
    forward = True
    for r in range(rows):
        p = pw[r]
        dark = np.flatnonzero(p > 0)
        if dark.size == 0:
            continue
        y = h / 2 - (r + 0.5) * dy
        brk = np.flatnonzero(np.diff(dark) > bridge + 1)
        groups = list(zip(dark[np.concatenate([[0], brk + 1])], dark[np.concatenate([brk, [dark.size - 1]])] + 1))
        for c0, c1 in groups if forward else groups[::-1]:
            seg = p[c0:c1]
            change = np.flatnonzero(np.diff(seg) != 0) + 1
            bounds = np.concatenate([[0], change, [c1 - c0]]) + c0  # columns where the power changes
            xs = xedge[bounds]
            powers = p[bounds[:-1]]
            if not forward:
                xs, powers = xs[::-1], powers[::-1]
            sgn = 1.0 if forward else -1.0
            b.add([[xs[0] - sgn * over, y, z]], travel, 0.0, 0.0, Role.TRAVEL)
            xs_all = np.concatenate([xs, [xs[-1] + sgn * over]])
            tools = np.concatenate([[0.0], powers, [0.0]])
            pts = np.column_stack([np.concatenate([[xs[0]], xs_all[1:]]), np.full(len(xs_all), y), np.full(len(xs_all), z)])
            b.add(pts, feed, 0.0, tools, role)
        forward = not forward
    return b.build()
