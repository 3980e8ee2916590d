"""A small software renderer: a flat-shaded triangle mesh to an RGB image (numpy + Pillow).

It exists for pictures of a progressive mesh refining (``pmw verify --frames``,
``pmw demo``), so its one promise is that **frames line up**: fit a
:class:`Camera` once (to the finest mesh) and render every level with it::

    cam = Camera.fit(final.positions, width=240, height=200)
    images = [render(m.positions, m.faces, cam) for m in levels]   # (h, w, 3) uint8 each

Method: orthographic projection; per-face Lambert shading (two-sided, so open or
inconsistently oriented meshes still read); a z-buffer filled by vectorised
rasterisation — triangles are grouped by the size of their pixel bounding box and
every candidate pixel of a group is tested at once with edge functions; the
nearest face per pixel wins.  Rendering happens at ``supersample`` times the size
and is reduced with a box filter for anti-aliased edges.  No per-triangle Python
loop: a 65k-face mesh renders in well under a second.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from PIL import Image

#: Default surface colour (RGB) and background.
SURFACE = (150, 176, 208)
BACKGROUND = (255, 255, 255)
#: Largest image side, and largest frame buffer (the side's pixels times ``supersample`` squared, 24 bytes each:
#: 1.5 GB), in pixels; the pictures pmw draws are 256-1024 wide (a side of 10**6 ended in numpy's MemoryError).
MAX_SIDE = 8192
MAX_PIXELS = 1 << 26
#: Direction towards the light, in view space (x right, y up, z towards the viewer).
LIGHT = np.array([-0.35, 0.55, 1.0]) / np.linalg.norm([-0.35, 0.55, 1.0])
#: Candidate pixels tested per vectorised step (bounds peak memory).
_STEP_CANDIDATES = 1 << 21


def _rotation(axis: int, degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


@dataclass(frozen=True)
class Camera:
    """Orthographic camera: ``view = (p - center) @ rotation.T``; pixels = ``view * scale``.

    ``rotation`` (3, 3) maps world to view space (x right, y up, z towards the viewer);
    ``width`` x ``height`` is the output image size in pixels.
    """

    rotation: np.ndarray
    center: np.ndarray
    scale: float
    width: int
    height: int

    def __post_init__(self) -> None:
        """OptionError naming a field that cannot draw: a rotation not (3, 3), a center not (3,), either not
        finite, a scale not a finite number > 0, a size not an integer 1 .. :data:`MAX_SIDE`."""
        import numbers

        from .errors import OptionError

        for name, shape in (("rotation", (3, 3)), ("center", (3,))):
            try:
                value = np.asarray(getattr(self, name), np.float64)
            except (TypeError, ValueError):
                value = None
            if value is None or value.shape != shape or not np.isfinite(value).all():
                got = "values that are not all finite" if value is not None and value.shape == shape else \
                    f"shape {np.shape(value) if value is not None else type(getattr(self, name)).__name__}"
                raise OptionError(f"Camera: {name} must be a finite {shape} array, got {got}")
        if isinstance(self.scale, bool) or not isinstance(self.scale, numbers.Real) or not 0 < self.scale < math.inf:
            raise OptionError(f"Camera: scale must be a finite number > 0, got {self.scale!r}")
        for name in ("width", "height"):
            _check_side(f"Camera: {name}", getattr(self, name))

    @classmethod
    def fit(cls, positions, width: int = 256, height: int = 256, *, azimuth: float = -28.0,
            elevation: float = 24.0, margin: float = 0.05) -> "Camera":
        """A camera framing ``positions`` (n, 3): its bounding box, as the camera sees it.

        The view looks along the axis in which the box is thinnest (so the widest
        silhouette faces the camera), with the longest remaining axis horizontal,
        then turns by ``azimuth`` about the vertical and tilts by ``elevation``.
        """
        from .errors import MeshError

        p = np.asarray(positions, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or not len(p) or not np.isfinite(p).all():
            raise MeshError(f"Camera.fit: positions must be (n, 3) finite, n >= 1, got shape {p.shape}")
        lo, hi = p.min(0), p.max(0)
        extent = hi - lo
        order = np.argsort(extent, kind="stable")  # thinnest first
        depth_axis, vertical, horizontal = order[0], order[1], order[2]
        base = np.zeros((3, 3))
        base[0, horizontal] = 1.0
        base[1, vertical] = 1.0
        base[2] = np.cross(base[0], base[1])
        if base[2, depth_axis] < 0:  # keep a right-handed frame looking along -depth
            base[2] *= -1
            base[0] *= -1
        rot = _rotation(0, -elevation) @ _rotation(1, azimuth) @ base
        center = 0.5 * (lo + hi)
        v = (p - center) @ rot.T
        span = np.maximum(v.max(0) - v.min(0), 1e-12)
        scale = min(width * (1 - 2 * margin) / span[0], height * (1 - 2 * margin) / span[1])
        # centre the projected box, not the world box
        mid = 0.5 * (v.max(0) + v.min(0))
        center = center + mid @ rot
        return cls(rot, center, float(scale), int(width), int(height))

    def project(self, positions, factor: int = 1) -> np.ndarray:
        """(n, 3) pixel x, pixel y (down), depth (larger is nearer) at ``factor`` times the size."""
        v = (np.asarray(positions, dtype=np.float64) - self.center) @ self.rotation.T
        s = self.scale * factor
        out = np.empty_like(v)
        out[:, 0] = self.width * factor / 2 + v[:, 0] * s
        out[:, 1] = self.height * factor / 2 - v[:, 1] * s
        out[:, 2] = v[:, 2]
        return out


def face_shading(positions, faces, camera: Camera) -> np.ndarray:
    """(m,) float in [0, 1]: two-sided Lambert term of every face, ambient included."""
    v = (np.asarray(positions, np.float64) - camera.center) @ camera.rotation.T
    tri = v[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1)
    length[length == 0] = 1.0
    lambert = np.abs(n @ LIGHT) / length
    return 0.22 + 0.78 * lambert


def rasterize(screen: np.ndarray, faces: np.ndarray, width: int, height: int) -> np.ndarray:
    """Z-buffer: (height, width) int64 index of the nearest face per pixel, -1 for background.

    ``screen`` (n, 3) pixel x, pixel y, depth (larger is nearer); pixel centres at +0.5.
    """
    faces = np.asarray(faces, dtype=np.int64)
    tri = screen[faces]  # (m, 3, 3)
    xs, ys = tri[:, :, 0], tri[:, :, 1]
    x0 = np.clip(np.floor(xs.min(1) - 0.5), 0, width - 1).astype(np.int64)
    x1 = np.clip(np.ceil(xs.max(1) - 0.5), 0, width - 1).astype(np.int64)
    y0 = np.clip(np.floor(ys.min(1) - 0.5), 0, height - 1).astype(np.int64)
    y1 = np.clip(np.ceil(ys.max(1) - 0.5), 0, height - 1).astype(np.int64)
    area = (xs[:, 1] - xs[:, 0]) * (ys[:, 2] - ys[:, 0]) - (xs[:, 2] - xs[:, 0]) * (ys[:, 1] - ys[:, 0])
    visible = (np.abs(area) > 1e-12) & (xs.max(1) >= 0) & (xs.min(1) < width) & (ys.max(1) >= 0) & (ys.min(1) < height)
    zbuf = np.full(width * height, -np.inf)
    fbuf = np.full(width * height, -1, dtype=np.int64)
    box = np.maximum(x1 - x0, y1 - y0) + 1
    sizes = 1 << np.ceil(np.log2(np.maximum(box, 1))).astype(np.int64)
    for s in np.unique(sizes[visible]):
        ids = np.flatnonzero(visible & (sizes == s))
        oy, ox = np.divmod(np.arange(s * s), s)
        per_step = max(1, _STEP_CANDIDATES // (s * s))
        for start in range(0, len(ids), per_step):
            f = ids[start:start + per_step]
            px = x0[f, None] + ox[None, :]
            py = y0[f, None] + oy[None, :]
            ok = (px <= x1[f, None]) & (py <= y1[f, None])
            cx, cy = px + 0.5, py + 0.5
            t = tri[f]
            a = area[f, None]
            # barycentric weights from edge functions, normalised by the signed area
            w0 = ((t[:, 1, 0, None] - cx) * (t[:, 2, 1, None] - cy) - (t[:, 2, 0, None] - cx) * (t[:, 1, 1, None] - cy)) / a
            w1 = ((t[:, 2, 0, None] - cx) * (t[:, 0, 1, None] - cy) - (t[:, 0, 0, None] - cx) * (t[:, 2, 1, None] - cy)) / a
            w2 = 1.0 - w0 - w1
            ok &= (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9)
            if not ok.any():
                continue
            depth = w0 * t[:, 0, 2, None] + w1 * t[:, 1, 2, None] + w2 * t[:, 2, 2, None]
            pix = (py * width + px)[ok]
            dep = depth[ok]
            fid = np.broadcast_to(f[:, None], ok.shape)[ok]
            order = np.lexsort((-dep, pix))  # by pixel, nearest first
            pix, dep, fid = pix[order], dep[order], fid[order]
            first = np.ones(len(pix), dtype=bool)
            first[1:] = pix[1:] != pix[:-1]
            pix, dep, fid = pix[first], dep[first], fid[first]
            nearer = dep > zbuf[pix]
            zbuf[pix[nearer]] = dep[nearer]
            fbuf[pix[nearer]] = fid[nearer]
    return fbuf.reshape(height, width)


def _check_side(what: str, size) -> None:
    """OptionError unless ``size`` is an integer 1 .. :data:`MAX_SIDE` (pixels)."""
    import numbers

    from .errors import OptionError

    if isinstance(size, bool) or not isinstance(size, numbers.Integral) or not 1 <= size <= MAX_SIDE:
        raise OptionError(f"{what} must be an integer 1..{MAX_SIDE} (pixels), got {size!r}")


def _checked_arguments(positions, faces, camera, width, height, color, background, supersample) -> tuple:
    """``(positions (n, 3) float64, faces (m, 3) int64)`` of :func:`render` once its arguments are known to draw:
    a mesh (:func:`~pmwm_codec.mesh.mesh_arrays`: MeshError for NaN, an index out of range ...; no faces: the
    background alone), a :class:`Camera` or None with ``width`` and ``height`` ints 1 .. :data:`MAX_SIDE`, RGB
    triples 0..255, ``supersample`` an int 1..8;
    OptionError naming what is wrong otherwise."""
    import numbers

    from .errors import MeshError, OptionError
    from .mesh import mesh_arrays

    if np.size(faces):
        positions, faces = mesh_arrays(positions, faces, "render")
    else:
        positions, faces = np.asarray(positions, np.float64), np.zeros((0, 3), np.int64)
        if positions.ndim != 2 or positions.shape[1] != 3 or (camera is None and not len(positions)):
            raise MeshError(f"render: positions must be (n, 3), n >= 1 without a camera, got shape {positions.shape}")
    if camera is not None and not isinstance(camera, Camera):
        raise OptionError(f"render: camera must be a Camera or None, got {type(camera).__name__}")
    if camera is None:
        for name, size in (("width", width), ("height", height)):
            _check_side(f"render: {name}", size)
    if isinstance(supersample, bool) or not isinstance(supersample, numbers.Integral) or not 1 <= supersample <= 8:
        raise OptionError(f"render: supersample must be an integer 1..8, got {supersample!r}")
    for name, rgb in (("color", color), ("background", background)):
        try:
            triple = np.asarray(rgb, np.float64)
        except (TypeError, ValueError):
            triple = None
        if triple is None or triple.shape != (3,) or not (np.isfinite(triple).all() and 0 <= triple.min()
                                                          and triple.max() <= 255):
            raise OptionError(f"render: {name} must be an RGB triple of numbers 0..255, got {rgb!r}")
    return positions, faces


def render(positions, faces, camera: Camera | None = None, *, width: int = 256, height: int = 256,
           color=SURFACE, background=BACKGROUND, supersample: int = 2) -> np.ndarray:
    """Render a mesh: (height, width, 3) uint8 RGB.

    Parameters
    ----------
    positions : (n, 3) float; faces : (m, 3) int
    camera : Camera, optional
        Fitted to ``positions`` when omitted (pass one camera to make frames line up;
        it then decides the image size).
    color, background : RGB triples 0..255
    supersample : render at this factor and box-filter down (1 = aliased).
    """
    positions, faces = _checked_arguments(positions, faces, camera, width, height, color, background, supersample)
    if camera is None:
        camera = Camera.fit(positions, width, height)
    k = int(supersample)
    w, h = camera.width * k, camera.height * k
    if w * h > MAX_PIXELS:
        from .errors import OptionError

        raise OptionError(f"render: a {camera.width}x{camera.height} image at supersample {k} needs a {w}x{h} frame "
                          f"buffer, more than {MAX_PIXELS:,} pixels; draw it smaller or with a lower supersample")
    img = np.empty((h, w, 3), dtype=np.float64)
    img[:] = background
    if len(faces):
        fbuf = rasterize(camera.project(positions, k), faces, w, h)
        shade = face_shading(positions, faces, camera)
        hit = fbuf >= 0
        img[hit] = shade[fbuf[hit], None] * np.asarray(color, np.float64)
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if k > 1:
        out = np.asarray(Image.fromarray(out, "RGB").resize((camera.width, camera.height), Image.BOX))
    return out
