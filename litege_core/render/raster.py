"""A small offscreen software rasterizer (pure numpy): orthographic camera, z-buffer,
per-pixel barycentrics, Lambert shading of per-vertex colours, point splats, and polyline and
marker overlays with a depth test. No OpenGL, no display.

The pipeline is deferred: :func:`rasterize_mesh` / :func:`rasterize_points` produce
:class:`Fragments` (for every pixel the nearest triangle or point and its barycentric
weights), from which any per-vertex attribute is interpolated (:meth:`Fragments.interpolate`),
so a scalar field is mapped to colours and isolines per pixel, not per triangle.

Triangles are rasterized in batches grouped by the size of their screen bounding box (a
power of two), so the Python loop runs over a handful of groups, not over triangles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

VIEWS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    # name: (direction from the shape towards the viewer, up), for y-up shapes
    "three_quarter": ((0.75, 0.35, 0.56), (0.0, 1.0, 0.0)),
    "side": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "front": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "back": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
    "top": ((0.0, 1.0, 0.0), (0.0, 0.0, -1.0)),
}
"""Named view directions, written for y-up shapes (as the procedural families are); for a
shape whose up axis is x or z they are turned with it (see :func:`view_axes`)."""

UP_ROTATIONS: dict[int, NDArray] = {
    0: np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),  # y → x, x → -y
    1: np.eye(3),
    2: np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),  # y → z, z → -y
}
"""Proper rotations taking the y-up frame of :data:`VIEWS` to an x-up or z-up one."""

_CANDIDATES_PER_BATCH = 1 << 21
_EMPTY = -1


@dataclass(frozen=True)
class Camera:
    """An orthographic camera: ``screen = ((p - center)·right, (p - center)·up) × scale``
    around the image centre, depth ``-(p - center)·towards`` (smaller is nearer)."""

    right: NDArray
    up: NDArray
    towards: NDArray
    center: NDArray
    scale: float
    width: int
    height: int

    def project(self, points: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
        """Pixel coordinates ``x`` (right), ``y`` (down) and depth of ``(N, 3)`` points."""
        p = np.asarray(points, dtype=np.float64) - self.center
        x = p @ self.right * self.scale + self.width / 2.0
        y = self.height / 2.0 - p @ self.up * self.scale
        depth = -(p @ self.towards)
        return x, y, depth

    def scaled(self, factor: int) -> Camera:
        """The same view at ``factor`` times the resolution (supersampling)."""
        return Camera(
            self.right,
            self.up,
            self.towards,
            self.center,
            self.scale * factor,
            self.width * factor,
            self.height * factor,
        )


FOOT_SLAB = 0.01
"""Depth of the "sole" slab of :func:`detect_up_axis`, as a fraction of the axis' extent."""

FOOT_MARGIN = 0.05
"""Difference of sole spreads (fractions of the largest side) that decides the up axis."""


def detect_up_axis(points: ArrayLike) -> int:
    """The up axis, 1 (y) or 2 (z), of a standing figure stored in either convention (TOSCA
    animals are z-up; FAUST humans, glTF files and the procedural families y-up).

    1. **Soles.** A figure stands on its feet: the points within :data:`FOOT_SLAB` of the
       bottom along the true up axis are feet, spread far apart (front and hind feet, left
       and right); along the wrong axis they are one end (a nose, a tail, a back). When the
       spreads of the y and z soles (largest side of the slab, relative to the shape's largest
       side) differ by more than :data:`FOOT_MARGIN`, the wider sole is the bottom.
    2. **Bounding box** otherwise, y preferred: z only when y is the longest side and z the
       middle one (an animal's body length along y, its height along z, as in TOSCA).

    Measured on the evaluation meshes and the procedural shapes: right for 30 of 35 TOSCA
    poses, 18 of 20 FAUST poses, 26 of 27 procedural shapes (y-up) and 23 of 27 of them
    turned z-up; the bounding-box rule alone was right for 24, 15, 26 and 12.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if p.shape[0] == 0:
        raise ValueError("cannot detect the up axis of no points")
    extent = np.ptp(p, axis=0)
    largest = float(extent.max())
    if not largest > 0:
        return 1
    spread = {}
    for axis in (1, 2):
        sole = p[p[:, axis] <= p[:, axis].min() + FOOT_SLAB * extent[axis]]
        spread[axis] = float(np.delete(np.ptp(sole, axis=0), axis).max()) / largest
    if abs(spread[1] - spread[2]) > FOOT_MARGIN:
        return 1 if spread[1] > spread[2] else 2
    longest, middle, _ = (int(i) for i in np.argsort(-extent, kind="stable"))
    return 2 if (longest, middle) == (1, 2) else 1


def view_axes(view: str | ArrayLike = "three_quarter", up_axis: int = 1) -> tuple[NDArray, NDArray]:
    """``(towards, up)`` unit vectors of a named view or of a direction towards the viewer.

    Args:
        view: a name of :data:`VIEWS` (turned by :data:`UP_ROTATIONS` when ``up_axis`` is not
            y) or a direction towards the viewer in the shape's own frame.
        up_axis: the shape's up axis (0 = x, 1 = y, 2 = z).
    """
    if up_axis not in UP_ROTATIONS:
        raise ValueError(f"up_axis must be 0, 1 or 2, got {up_axis!r}")
    rotation = UP_ROTATIONS[up_axis]
    if isinstance(view, str):
        if view not in VIEWS:
            raise ValueError(f"unknown view {view!r}; expected one of {sorted(VIEWS)}")
        towards, up = (rotation @ np.asarray(v, dtype=np.float64) for v in VIEWS[view])
    else:
        towards = np.asarray(view, dtype=np.float64).reshape(3)
        up = rotation @ np.array([0.0, 1.0, 0.0])
    norm = np.linalg.norm(towards)
    if not norm > 0:
        raise ValueError("the view direction must be non-zero")
    towards = towards / norm
    up = up - (up @ towards) * towards
    if np.linalg.norm(up) < 1e-6:  # looking straight along the up axis: "top"'s up
        fallback = rotation @ np.array([0.0, 0.0, -1.0])
        up = fallback - (fallback @ towards) * towards
    return towards, up / np.linalg.norm(up)


def fit_camera(
    points: ArrayLike,
    size: tuple[int, int] = (640, 480),
    view: str | ArrayLike = "three_quarter",
    *,
    margin: float = 0.06,
    up_axis: int | None = None,
) -> Camera:
    """A camera looking at ``points`` from ``view`` that fits them in ``size = (W, H)``;
    ``up_axis`` (0 = x, 1 = y, 2 = z) is the shape's up, by default
    :func:`detect_up_axis` of the points."""
    width, height = (int(s) for s in size)
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {size}")
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if p.shape[0] == 0:
        raise ValueError("cannot fit a camera to no points")
    towards, up = view_axes(view, detect_up_axis(p) if up_axis is None else up_axis)
    right = np.cross(up, towards)
    u, v, w = p @ right, p @ up, p @ towards
    lo = np.array([u.min(), v.min(), w.min()])
    hi = np.array([u.max(), v.max(), w.max()])
    mid = 0.5 * (lo + hi)
    center = mid[0] * right + mid[1] * up + mid[2] * towards
    extent = np.maximum(hi - lo, 1e-12)
    usable = 1.0 - 2.0 * margin
    scale = usable * min(width / extent[0], height / extent[1])
    return Camera(right, up, towards, center, float(scale), width, height)


@dataclass(frozen=True)
class Fragments:
    """What is visible in each pixel of an ``(H, W)`` image.

    Attributes:
        element: ``(H, W)`` int64 index of the nearest triangle (or point), -1 where empty.
        weights: ``(H, W, 3)`` barycentric weights of the pixel centre in that triangle.
        depth: ``(H, W)`` float64 depth, +inf where empty.
        corners: ``(E, 3)`` vertex indices of each element (points: the point thrice).
        normals: optional ``(H, W, 3)`` per-pixel normals (point splats: sphere impostors).
    """

    element: NDArray
    weights: NDArray
    depth: NDArray
    corners: NDArray
    normals: NDArray | None = None

    @property
    def mask(self) -> NDArray:
        """``(H, W)`` bool: pixels covered by the shape."""
        return self.element >= 0

    def interpolate(self, attribute: ArrayLike, fill: float = np.nan) -> NDArray:
        """Per-vertex ``attribute`` (``(N,)`` or ``(N, C)``) interpolated at every pixel;
        ``fill`` where the image is empty."""
        values = np.asarray(attribute, dtype=np.float64)
        flat = values.reshape(values.shape[0], -1)
        height, width = self.element.shape
        out = np.full((height * width, flat.shape[1]), fill, dtype=np.float64)
        covered = self.element.reshape(-1) >= 0
        corners = self.corners[self.element.reshape(-1)[covered]]
        weights = self.weights.reshape(-1, 3)[covered]
        out[covered] = np.einsum("pk,pkc->pc", weights, flat[corners])
        return out.reshape((height, width, *values.shape[1:]))


def _resolve(
    zbuf: NDArray,
    elem: NDArray,
    wbuf: NDArray,
    pix: NDArray,
    z: NDArray,
    ids: NDArray,
    weights: NDArray,
) -> None:
    """Z-test candidate fragments against the buffers (in place)."""
    if pix.size == 0:
        return
    order = np.lexsort((z, pix))
    pix, z = pix[order], z[order]
    first = np.ones(pix.size, dtype=bool)
    first[1:] = pix[1:] != pix[:-1]
    pix, z, picked = pix[first], z[first], order[first]
    nearer = z < zbuf[pix]
    pix, picked = pix[nearer], picked[nearer]
    zbuf[pix] = z[nearer]
    elem[pix] = ids[picked]
    wbuf[pix] = weights[picked]


def rasterize_mesh(camera: Camera, vertices: ArrayLike, faces: ArrayLike) -> Fragments:
    """Z-buffered rasterization of a triangle mesh (pixel centres, orthographic)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    width, height = camera.width, camera.height
    x, y, d = camera.project(vertices)
    fx, fy, fz = x[faces], y[faces], d[faces]
    x0 = np.floor(fx.min(axis=1) - 0.5).astype(np.int64)
    x1 = np.ceil(fx.max(axis=1) - 0.5).astype(np.int64)
    y0 = np.floor(fy.min(axis=1) - 0.5).astype(np.int64)
    y1 = np.ceil(fy.max(axis=1) - 0.5).astype(np.int64)
    x0, y0 = np.maximum(x0, 0), np.maximum(y0, 0)
    x1, y1 = np.minimum(x1, width - 1), np.minimum(y1, height - 1)
    area = (fx[:, 1] - fx[:, 0]) * (fy[:, 2] - fy[:, 0]) - (fx[:, 2] - fx[:, 0]) * (
        fy[:, 1] - fy[:, 0]
    )
    live = (x1 >= x0) & (y1 >= y0) & (np.abs(area) > 1e-12) & np.isfinite(area)
    extent = np.maximum(x1 - x0 + 1, y1 - y0 + 1)
    bucket = np.zeros(len(faces), dtype=np.int64)
    bucket[live] = np.ceil(np.log2(np.maximum(extent[live], 1))).astype(np.int64)

    zbuf = np.full(height * width, np.inf)
    elem = np.full(height * width, _EMPTY, dtype=np.int64)
    wbuf = np.zeros((height * width, 3))
    for b in np.unique(bucket[live]):
        side = 1 << int(b)
        members = np.flatnonzero(live & (bucket == b))
        per_batch = max(1, _CANDIDATES_PER_BATCH // (side * side))
        offsets = np.arange(side)
        for start in range(0, members.size, per_batch):
            f = members[start : start + per_batch]
            gx = x0[f, None, None] + offsets[None, None, :]  # (n, 1, side)
            gy = y0[f, None, None] + offsets[None, :, None]  # (n, side, 1)
            in_box = (gx <= x1[f, None, None]) & (gy <= y1[f, None, None])
            px, py = gx + 0.5, gy + 0.5
            ax, bx, cx = (fx[f, k, None, None] for k in range(3))
            ay, by, cy = (fy[f, k, None, None] for k in range(3))
            inv = 1.0 / area[f, None, None]
            w1 = ((px - ax) * (cy - ay) - (cx - ax) * (py - ay)) * inv
            w2 = ((bx - ax) * (py - ay) - (px - ax) * (by - ay)) * inv
            w0 = 1.0 - w1 - w2
            eps = -1e-7
            inside = in_box & (w0 >= eps) & (w1 >= eps) & (w2 >= eps)
            n_idx, r_idx, c_idx = np.nonzero(inside)
            if n_idx.size == 0:
                continue
            w = np.stack([w0[n_idx, r_idx, c_idx], w1[n_idx, r_idx, c_idx]], axis=1)
            w = np.column_stack([w, w2[n_idx, r_idx, c_idx]])
            faces_hit = f[n_idx]
            z = np.einsum("pk,pk->p", w, fz[faces_hit])
            pix = (y0[faces_hit] + r_idx) * width + (x0[faces_hit] + c_idx)
            _resolve(zbuf, elem, wbuf, pix, z, faces_hit, w)
    return Fragments(
        element=elem.reshape(height, width),
        weights=wbuf.reshape(height, width, 3),
        depth=zbuf.reshape(height, width),
        corners=faces,
    )


def rasterize_points(camera: Camera, points: ArrayLike, radius_px: float) -> Fragments:
    """Z-buffered point splats: each point a disk of ``radius_px`` shaded as a small sphere
    (its normals are in :attr:`Fragments.normals`, in world coordinates)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    width, height = camera.width, camera.height
    x, y, d = camera.project(points)
    r = max(float(radius_px), 0.5)
    reach = int(np.ceil(r))
    oy, ox = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    keep = (ox**2 + oy**2) <= r * r + 1e-9
    ox, oy = ox[keep], oy[keep]
    cx, cy = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    zbuf = np.full(height * width, np.inf)
    elem = np.full(height * width, _EMPTY, dtype=np.int64)
    buf = np.zeros((height * width, 6))  # barycentric weights, then the normal
    per_batch = max(1, _CANDIDATES_PER_BATCH // ox.size)
    radius_world = r / camera.scale
    for start in range(0, points.shape[0], per_batch):
        ids = np.arange(start, min(start + per_batch, points.shape[0]))
        gx = cx[ids, None] + ox[None, :]
        gy = cy[ids, None] + oy[None, :]
        dx = (gx + 0.5 - x[ids, None]) / r
        dy = (gy + 0.5 - y[ids, None]) / r
        rr = dx**2 + dy**2
        ok = (gx >= 0) & (gx < width) & (gy >= 0) & (gy < height) & (rr <= 1.0)
        n_idx, k_idx = np.nonzero(ok)
        if n_idx.size == 0:
            continue
        bulge = np.sqrt(np.clip(1.0 - rr[n_idx, k_idx], 0.0, 1.0))
        z = d[ids[n_idx]] - bulge * radius_world
        pix = gy[n_idx, k_idx] * width + gx[n_idx, k_idx]
        normal = (
            dx[n_idx, k_idx, None] * camera.right
            - dy[n_idx, k_idx, None] * camera.up
            + bulge[:, None] * camera.towards
        )
        payload = np.concatenate([np.ones((n_idx.size, 1)), np.zeros((n_idx.size, 2)), normal], 1)
        _resolve(zbuf, elem, buf, pix, z, ids[n_idx], payload)
    corners = np.repeat(np.arange(points.shape[0], dtype=np.int64)[:, None], 3, axis=1)
    return Fragments(
        element=elem.reshape(height, width),
        weights=buf[:, :3].reshape(height, width, 3),
        depth=zbuf.reshape(height, width),
        corners=corners,
        normals=buf[:, 3:].reshape(height, width, 3),
    )


def lambert(
    normals: NDArray, camera: Camera, *, ambient: float = 0.32, two_sided: bool = True
) -> NDArray:
    """Lambert shading factor in [ambient, 1] of ``(..., 3)`` normals under a key light
    above-left of the viewer and a weaker headlight."""
    n = np.asarray(normals, dtype=np.float64)
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    facing = n @ camera.towards
    if two_sided:
        n = np.where((facing < 0)[..., None], -n, n)
    key = 0.55 * camera.towards + 0.45 * camera.up - 0.35 * camera.right
    key /= np.linalg.norm(key)
    diffuse = 0.7 * np.clip(n @ key, 0.0, 1.0) + 0.3 * np.clip(n @ camera.towards, 0.0, 1.0)
    return ambient + (1.0 - ambient) * diffuse


def _stamp(mask: NDArray, x: NDArray, y: NDArray, radius: float) -> None:
    """Set the disks of ``radius`` around pixel positions ``(x, y)`` in ``mask``."""
    height, width = mask.shape
    reach = int(np.ceil(radius))
    oy, ox = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    disk = (ox**2 + oy**2) <= radius * radius + 0.25
    ox, oy = ox[disk], oy[disk]
    px = np.floor(x).astype(np.int64)[:, None] + ox[None, :]
    py = np.floor(y).astype(np.int64)[:, None] + oy[None, :]
    ok = (px >= 0) & (px < width) & (py >= 0) & (py < height)
    mask[py[ok], px[ok]] = True


def polyline_masks(
    camera: Camera,
    fragments: Fragments,
    points: ArrayLike,
    width_px: float,
    *,
    depth_tolerance: float,
) -> tuple[NDArray, NDArray]:
    """``(visible, hidden)`` pixel masks of a 3D polyline drawn ``width_px`` wide: samples in
    front of (or within ``depth_tolerance`` behind) the surface are visible."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    visible = np.zeros((camera.height, camera.width), dtype=bool)
    hidden = np.zeros_like(visible)
    if p.shape[0] == 0:
        return visible, hidden
    x, y, d = camera.project(p)
    if p.shape[0] == 1:
        sx, sy, sd = x, y, d
    else:
        seg = np.hypot(np.diff(x), np.diff(y))
        steps = np.maximum(np.ceil(seg / 0.5).astype(np.int64), 1)
        t = np.concatenate([np.arange(s) / s for s in steps] + [np.array([0.0])])
        start = np.concatenate([np.repeat(np.arange(len(steps)), steps), [len(steps) - 1]])
        t[-1] = 1.0
        sx = x[start] + t * (x[start + 1] - x[start])
        sy = y[start] + t * (y[start + 1] - y[start])
        sd = d[start] + t * (d[start + 1] - d[start])
    inside = (sx >= 0) & (sx < camera.width) & (sy >= 0) & (sy < camera.height)
    sx, sy, sd = sx[inside], sy[inside], sd[inside]
    surface = fragments.depth[sy.astype(np.int64), sx.astype(np.int64)]
    seen = sd <= surface + depth_tolerance
    radius = max(width_px / 2.0, 0.5)
    _stamp(visible, sx[seen], sy[seen], radius)
    _stamp(hidden, sx[~seen], sy[~seen], radius)
    return visible, hidden & ~visible


def disk_mask(camera: Camera, point: ArrayLike, radius_px: float) -> NDArray:
    """Pixel mask of a disk of ``radius_px`` around the projection of one 3D point."""
    mask = np.zeros((camera.height, camera.width), dtype=bool)
    x, y, _ = camera.project(np.asarray(point, dtype=np.float64).reshape(1, 3))
    _stamp(mask, x, y, radius_px)
    return mask


def dilate(mask: NDArray, radius: int) -> NDArray:
    """Binary dilation of a mask by a square of ``2 radius + 1`` pixels."""
    out = np.asarray(mask, dtype=bool).copy()
    for _ in range(max(int(radius), 0)):
        grown = out.copy()
        grown[1:, :] |= out[:-1, :]
        grown[:-1, :] |= out[1:, :]
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        out = grown
    return out


__all__ = [
    "UP_ROTATIONS",
    "VIEWS",
    "Camera",
    "Fragments",
    "detect_up_axis",
    "dilate",
    "disk_mask",
    "fit_camera",
    "lambert",
    "polyline_masks",
    "rasterize_mesh",
    "rasterize_points",
    "view_axes",
]
