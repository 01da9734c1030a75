"""Workspace analysis: reachable volume, the largest cylinder and box it holds,
singularity margin and Cartesian resolution.

Everything samples the kinematics' ``reachable`` mask on regular grids (one
vectorised call per grid), as the ETITC thesis did in sec. 8.4.2, but with joint
limits, ball-joint tilt and the singularity limit included.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Prism:
    """A vertical cylinder (``half_width`` = radius) or square box centred on the
    bed axis, from ``z0`` to ``z1``, mm."""

    shape: str
    half_width: float
    z0: float
    z1: float

    @property
    def height(self) -> float:
        return self.z1 - self.z0

    @property
    def volume(self) -> float:
        area = np.pi * self.half_width**2 if self.shape == "cylinder" else (2 * self.half_width) ** 2
        return float(area * self.height)

    def describe(self) -> str:
        if self.shape == "cylinder":
            return f"cylinder diameter {2 * self.half_width:.1f} mm x height {self.height:.1f} mm (z {self.z0:.1f}..{self.z1:.1f})"
        return f"box {2 * self.half_width:.1f} x {2 * self.half_width:.1f} x {self.height:.1f} mm (z {self.z0:.1f}..{self.z1:.1f})"


@dataclass(frozen=True)
class WorkspaceReport:
    """Figures of one machine's workspace. Lengths mm, volumes mm^3."""

    z: np.ndarray  # (nz,) slice heights
    disk_radius: np.ndarray  # (nz,) largest reachable disk centred on the axis at each z
    square_half: np.ndarray  # (nz,) largest reachable centred square's half-width at each z
    reachable_volume: float
    cylinder: Prism  # largest-volume cylinder anywhere
    cylinder_on_bed: Prism  # largest-volume cylinder standing on z = 0
    cube: Prism  # largest cube anywhere
    cube_on_bed: Prism  # largest cube standing on z = 0
    condition_median: float
    condition_max: float
    resolution_min: float  # mm per count, best point of the build cylinder
    resolution_median: float
    resolution_max: float  # worst point


def _nested_reach(kin, z, radii, shape, n_angles=60):
    """Largest half-width per z such that every nested ring/square up to it is reachable.

    z: (nz,), radii: (nr,) increasing -> (nz,) float, mm."""
    t = np.linspace(0, 2 * np.pi, n_angles, endpoint=False)
    if shape != "cylinder":
        # The square's corners are where a convex region cuts it first: always sample them
        # (60 even angles step 6 deg and miss 45 deg, which overstated the ETITC cube by 3 mm).
        t = np.union1d(t, np.pi / 4 * np.array([1.0, 3.0, 5.0, 7.0]))
    if shape == "cylinder":
        ux, uy = np.cos(t), np.sin(t)
    else:  # unit square perimeter, parametrised by angle
        m = np.maximum(np.abs(np.cos(t)), np.abs(np.sin(t)))
        ux, uy = np.cos(t) / m, np.sin(t) / m
    Zg, Rg, _ = np.meshgrid(z, radii, t, indexing="ij")
    pts = np.stack([Rg * ux[None, None], Rg * uy[None, None], Zg], axis=-1).reshape(-1, 3)
    ok = kin.reachable(pts).reshape(len(z), len(radii), len(t)).all(axis=2)
    # Count leading reachable rings: the first failure bounds the half-width.
    first_bad = np.where(ok.all(axis=1), len(radii), np.argmin(ok, axis=1))
    out = np.where(first_bad > 0, radii[np.maximum(first_bad - 1, 0)], 0.0)
    out[~ok[:, 0]] = 0.0
    return out


def _best_prism(z, half, shape, on_bed):
    """Best prism over slices z (increasing) with per-slice half-widths ``half``."""
    best = Prism(shape, 0.0, 0.0, 0.0)
    starts = [int(np.argmin(np.abs(z)))] if on_bed else range(len(z))
    for i in starts:
        running = np.minimum.accumulate(half[i:])
        heights = z[i:] - z[i]
        if shape == "cube":
            side = np.minimum(2 * running, heights)
            k = int(np.argmax(side))
            cand = Prism(shape, side[k] / 2, z[i], z[i] + side[k])
        else:
            vols = np.pi * running**2 * heights
            k = int(np.argmax(vols))
            cand = Prism(shape, running[k], z[i], z[i + k])
        if cand.volume > best.volume:
            best = cand
    return best


def analyse(kin, counts_per_unit, z_range, radius_max, nz=161, nr=121) -> WorkspaceReport:
    """Analyse a kinematics object.

    kin: :class:`~deltaslice.kinematics.base.Kinematics`; counts_per_unit: (J,)
    actuator counts per joint unit; z_range: (zmin, zmax) bed-frame heights to
    search, mm; radius_max: largest radius to search, mm.
    """
    z = np.linspace(z_range[0], z_range[1], nz)
    radii = np.linspace(0.0, radius_max, nr)
    dz = z[1] - z[0]
    disk = _nested_reach(kin, z, radii, "cylinder")
    square = _nested_reach(kin, z, radii, "cube")

    # Reachable volume from a coarse 3-D grid.
    step = max(radius_max / 40, dz)
    xs = np.arange(-radius_max, radius_max + step / 2, step)
    zs = np.arange(z_range[0], z_range[1] + step / 2, step)
    X, Y, Zz = np.meshgrid(xs, xs, zs, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel(), Zz.ravel()], axis=1)
    mask = kin.reachable(pts)
    volume = float(mask.sum() * step**3)

    cyl, cyl_bed = _best_prism(z, disk, "cylinder", False), _best_prism(z, disk, "cylinder", True)
    cube, cube_bed = _best_prism(z, square, "cube", False), _best_prism(z, square, "cube", True)

    # Condition and resolution inside the on-bed cylinder (or the best one if none stands on the bed).
    region = cyl_bed if cyl_bed.volume > 0 else cyl
    inside = pts[mask]
    if region.volume > 0:
        sel = (np.hypot(inside[:, 0], inside[:, 1]) <= region.half_width) & (inside[:, 2] >= region.z0) & (
            inside[:, 2] <= region.z1
        )
        inside = inside[sel] if sel.any() else inside
    cond = np.array([np.inf])
    res = np.array([np.nan])
    if len(inside):
        q = kin.inverse(inside)
        cond = kin.condition(q)
        res = resolution(kin, q, counts_per_unit)
    return WorkspaceReport(
        z=z,
        disk_radius=disk,
        square_half=square,
        reachable_volume=volume,
        cylinder=cyl,
        cylinder_on_bed=cyl_bed,
        cube=cube,
        cube_on_bed=cube_bed,
        condition_median=float(np.median(cond)),
        condition_max=float(np.max(cond)),
        resolution_min=float(np.nanmin(res)),
        resolution_median=float(np.nanmedian(res)),
        resolution_max=float(np.nanmax(res)),
    )


def resolution(kin, q, counts_per_unit) -> np.ndarray:
    """Worst Cartesian step of the tool for one actuator count of any one joint.

    q: (N,J) joint values -> (N,) float, mm per count (the largest Jacobian column
    norm divided by that joint's counts per unit)."""
    jac = kin.jacobian(np.atleast_2d(q))
    col = np.linalg.norm(jac, axis=1) / np.abs(np.asarray(counts_per_unit, dtype=float))[None]
    return col.max(axis=1)


def plot(kin, report: WorkspaceReport, counts_per_unit, path, title="") -> None:
    """Write a PNG: reachable half-width per height, and a resolution map at mid-height."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5.2))
    ax1.fill_betweenx(report.z, -report.disk_radius, report.disk_radius, color="#9ecae1", label="reachable disk")
    ax1.fill_betweenx(report.z, -report.square_half, report.square_half, color="#3182bd", alpha=0.6, label="reachable square")
    for prism, color, label in (
        (report.cylinder_on_bed, "#e6550d", "largest cylinder on bed"),
        (report.cube_on_bed, "#31a354", "largest cube on bed"),
    ):
        if prism.volume > 0:
            w = prism.half_width
            ax1.plot([-w, w, w, -w, -w], [prism.z0, prism.z0, prism.z1, prism.z1, prism.z0], color=color, lw=2, label=label)
    ax1.axhline(0, color="k", lw=0.8)
    ax1.set_xlabel("x (mm), section through the axis")
    ax1.set_ylabel("z above bed (mm)")
    ax1.set_title("Reachable region (joint limits, tilt, singularity)")
    ax1.legend(loc="best", fontsize=8)

    region = report.cylinder_on_bed if report.cylinder_on_bed.volume > 0 else report.cylinder
    zmid = (region.z0 + region.z1) / 2 if region.volume > 0 else float(report.z[len(report.z) // 2])
    lim = max(float(report.disk_radius.max()) * 1.3, 10.0)
    xs = np.linspace(-lim, lim, 161)
    X, Y = np.meshgrid(xs, xs)
    pts = np.stack([X.ravel(), Y.ravel(), np.full(X.size, zmid)], axis=1)
    ok = kin.reachable(pts)
    res = np.full(len(pts), np.nan)
    if ok.any():
        res[ok] = resolution(kin, kin.inverse(pts[ok]), counts_per_unit)
    im = ax2.pcolormesh(X, Y, res.reshape(X.shape), shading="auto", cmap="viridis")
    fig.colorbar(im, ax=ax2, label="mm per actuator count (worst joint)")
    ax2.set_aspect("equal")
    ax2.set_title(f"Resolution at z = {zmid:.1f} mm (blank: unreachable)")
    ax2.set_xlabel("x (mm)")
    ax2.set_ylabel("y (mm)")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
