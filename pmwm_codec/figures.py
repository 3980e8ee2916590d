"""Pictures of a progressive, watermarked decode (numpy + Pillow, no plotting library).

Given the :class:`~pmwm_codec.stream.PartialResult` list of one decode (base mesh
first), :func:`write_figures` writes what ``pmw verify --frames`` and ``pmw demo``
promise::

    frame_000.png ...   the partial watermark at every chunk boundary where it changed (NNN = chunk;
                        grey "no coefficients yet" before the first coefficient)
    overview.png        the mesh at ~5 boundaries (spread in log vertex count) above the watermark at the same
                        boundaries, labelled with bytes received and PSNR (the
                        paper's Fig. 8)
    metrics.png         watermark PSNR and NC against bytes received
    tamper.png          (given a tamper map) the mesh with the flagged vertices in red, beside the
                        watermark read (:func:`tamper_figure`)

Each set is written whole or not at all (:func:`write_pictures`): a failure or a Ctrl-C part-way leaves
none of its pictures.  The pieces are public for other uses: :func:`pick_levels`, :func:`overview`,
:func:`metrics_plot`, :func:`tamper_figure`.
"""

from __future__ import annotations

import contextlib
import math
import numbers
import os
import re
import stat

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from .errors import OptionError
from .watermark.image import png_bytes
from .render import Camera, render

INK = (40, 40, 48)
GRID = (226, 226, 232)
PSNR_COLOR = (200, 70, 50)
NC_COLOR = (40, 100, 190)
CUT_COLOR = (150, 150, 150)



def font(size: int = 14):
    """Pillow's bundled scalable font at ``size`` px (the bitmap default if FreeType is missing)."""
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # Pillow < 10.1 or no FreeType
        return ImageFont.load_default()


def format_bytes(n: int) -> str:
    """``812 B``, ``71.2 kB``, ``3.41 MB``."""
    if n < 1000:
        return f"{n} B"
    if n < 1_000_000:
        return f"{n / 1000:.1f} kB"
    return f"{n / 1_000_000:.2f} MB"


def format_psnr(value) -> str:
    if value is None:
        return "PSNR -"
    if math.isinf(value):
        return "PSNR inf (exact)"
    return f"PSNR {value:.1f} dB"


def pick_levels(counts, k: int = 5) -> list[int]:
    """Indices of ~``k`` results spread evenly in ``log(counts)`` (vertex counts, say).

    A progressive mesh changes most at its start, so a log scale shows the
    refinement best; the first and last results are always picked.
    """
    c = np.log(np.maximum(np.asarray(counts, dtype=np.float64), 1.0))
    if len(c) <= k:
        return list(range(len(c)))
    targets = np.linspace(c[0], c[-1], k)
    picked = []
    for t in targets:
        i = int(np.argmin(np.abs(c - t)))
        if i not in picked:
            picked.append(i)
    for i in range(len(c)):  # top up when two targets hit the same result
        if len(picked) >= k:
            break
        if i not in picked:
            picked.append(i)
    return sorted(picked)


def _text_center(draw, xy_center, text, fnt, fill=INK):
    left, top, right, bottom = draw.textbbox((0, 0), text, font=fnt)
    draw.text((xy_center[0] - (right - left) / 2 - left, xy_center[1] - top), text, font=fnt, fill=fill)
    return bottom - top


#: Background of a watermark that has no coefficients yet.
EMPTY_MARK = (238, 238, 242)
#: Smallest side of a written frame (the watermark is scaled up by a whole factor to reach it).
FRAME_MIN_SIDE = 128
#: File names in a pictures directory: the tamper map, the overview, the metrics plot.
TAMPER_NAME, OVERVIEW_NAME, PLOT_NAME = "tamper.png", "overview.png", "metrics.png"


def watermark_tile(r, side: int) -> Image.Image:
    """RGB ``side`` x ``side`` picture of ``r.watermark`` (nearest-neighbour), or the grey
    "no coefficients yet" state when no coefficient has arrived (one look everywhere)."""
    if r.coefficients == 0:
        tile = Image.new("RGB", (side, side), EMPTY_MARK)
        draw = ImageDraw.Draw(tile)
        fnt = font(max(9, min(13, side // 10)))
        for i, word in enumerate(("no coefficients", "yet")):
            _text_center(draw, (side / 2, side / 2 - 14 + 16 * i), word, fnt, CUT_COLOR)
        return tile
    return Image.fromarray(np.asarray(r.watermark, np.uint8), "L").resize((side, side), Image.NEAREST).convert("RGB")


def _frames(results) -> dict:
    """``{frame_NNN.png: picture}`` (NNN = chunk boundary) where the watermark changed.

    A frame is the watermark scaled up by a whole factor to at least ``FRAME_MIN_SIDE`` px.
    Once every code has been read the picture stops changing (later carriers repeat the
    codes and only refine the mesh), so boundaries without a change get no frame.
    """
    frames = {}
    for r in _framed(results):
        size = np.shape(r.watermark)[0]
        side = size * max(1, -(-FRAME_MIN_SIDE // max(size, 1)))
        frames[_frame_name(r)] = watermark_tile(r, side)
    return frames


def _framed(results) -> list:
    """The results :func:`_frames` draws: those whose watermark differs from the previous one drawn."""
    out, previous = [], None
    for r in results:
        if r.watermark is None:
            continue
        state = (r.coefficients == 0, np.asarray(r.watermark, np.uint8).tobytes())
        if state != previous:
            out.append(r)
            previous = state
    return out


def _frame_name(r) -> str:
    return f"frame_{r.chunk:03d}.png"


def figure_paths(results, directory, *, tamper: bool = False) -> list:
    """Every file :func:`write_figures` (with ``tamper``: given a tamper map) would write into
    ``directory`` for ``results``, so a caller can check them all before any is written."""
    directory = os.fspath(directory)
    names = [_frame_name(r) for r in _framed(results)] + [OVERVIEW_NAME]
    if any(r.nc is not None for r in results):
        names.append(PLOT_NAME)
    return [os.path.join(directory, name) for name in names + ([TAMPER_NAME] if tamper else [])]


def overview(results, *, k: int = 5, tile=(220, 170), title: str | None = None, camera: Camera | None = None,
             total_bytes: int | None = None) -> Image.Image:
    """The mesh at ~``k`` chunk boundaries in a row, the watermark below each, labels under both.

    The boundaries are spread in log(vertex count) (:func:`pick_levels`).

    ``results``: PartialResult list, base mesh first.  One camera (fitted to the
    last result) renders every level, so the frames line up.
    """
    if not results:
        raise ValueError("no results to draw")
    idx = pick_levels([r.vertices for r in results], k)
    picked = [results[i] for i in idx]
    tw, th = tile
    if camera is None:
        camera = Camera.fit(picked[-1].mesh.positions, tw, th)
    has_mark = any(r.watermark is not None for r in picked)
    side = min(tw, th) - 10 if has_mark else 0
    big, small = font(17), font(13)
    pad, gap = 16, 10
    title_h = 30 if title else 0
    label_h = 4 * 17
    width = pad * 2 + len(picked) * tw + (len(picked) - 1) * gap
    height = pad + title_h + th + (gap + side if has_mark else 0) + gap + label_h + pad
    img = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    if title:
        draw.text((pad, pad), title, font=big, fill=INK)
    y_mesh = pad + title_h
    y_mark = y_mesh + th + gap
    y_label = (y_mark + side if has_mark else y_mesh + th) + gap
    for col, r in enumerate(picked):
        x = pad + col * (tw + gap)
        mesh = r.mesh
        img.paste(Image.fromarray(render(mesh.positions, mesh.faces, camera)), (x, y_mesh))
        draw.rectangle([x, y_mesh, x + tw - 1, y_mesh + th - 1], outline=GRID)
        if has_mark:
            mx = x + (tw - side) // 2
            if r.watermark is not None:
                img.paste(watermark_tile(r, side), (mx, y_mark))
            draw.rectangle([mx - 1, y_mark - 1, mx + side, y_mark + side], outline=(180, 180, 188))
        share = f" ({100 * r.bytes_read / total_bytes:.0f}%)" if total_bytes else ""
        lines = [
            (f"{format_bytes(r.bytes_read)}{share}", small),
            (format_psnr(r.psnr_db), small),
            ("base mesh" if r.chunk == 0 else f"chunk {r.chunk}/{r.chunks_total}", small),
            (f"{r.vertices:,} vertices", small),
        ]
        yy = y_label
        for text, fnt in lines:
            _text_center(draw, (x + tw / 2, yy), text, fnt)
            yy += 17
    return img


def _ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    span = hi - lo if hi > lo else 1.0
    raw = span / n
    mag = 10 ** math.floor(math.log10(raw))
    step = mag
    for m in (1, 2, 2.5, 5, 10):
        step = m * mag
        if step >= raw:
            break
    start = math.ceil(lo / step - 1e-9) * step
    return np.arange(start, hi + step * 1e-6, step)


def _tick_label(v: float) -> str:
    return f"{v:g}" if abs(v) < 1e5 else f"{v:.3g}"


class _Panel:
    """One plot area: data -> pixel mapping, axes, ticks, grid."""

    def __init__(self, draw, box, xlim, ylim):
        self.draw, self.box, self.xlim, self.ylim = draw, box, xlim, ylim

    def px(self, x, y):
        x0, y0, x1, y1 = self.box
        fx = (x - self.xlim[0]) / ((self.xlim[1] - self.xlim[0]) or 1)
        fy = (y - self.ylim[0]) / ((self.ylim[1] - self.ylim[0]) or 1)
        return x0 + fx * (x1 - x0), y1 - fy * (y1 - y0)

    def axes(self, xticks, yticks, ylabel, fnt, color, xlabels=True):
        d = self.draw
        x0, y0, x1, y1 = self.box
        for t in yticks:
            _, py = self.px(self.xlim[0], t)
            d.line([x0, py, x1, py], fill=GRID)
            d.line([x0 - 5, py, x0, py], fill=INK)
            text = _tick_label(t)
            w = d.textlength(text, font=fnt)
            d.text((x0 - 8 - w, py - 7), text, font=fnt, fill=INK)
        for t in xticks:
            px, _ = self.px(t, self.ylim[0])
            d.line([px, y0, px, y1], fill=GRID)
            d.line([px, y1, px, y1 + 5], fill=INK)
            if xlabels:
                _text_center(d, (px, y1 + 8), _tick_label(t), fnt)
        d.rectangle([x0, y0, x1, y1], outline=INK)
        w = d.textlength(ylabel, font=fnt)
        d.text((x1 - 8 - w, y1 - 22), ylabel, font=fnt, fill=color)

    def series(self, xs, ys, color):
        pts = [self.px(x, y) for x, y in zip(xs, ys)]
        if len(pts) > 1:
            self.draw.line(pts, fill=color, width=2, joint="curve")
        for x, y in pts:
            self.draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=color)


def metrics_plot(results, *, size=(760, 460), title: str | None = None, total_bytes: int | None = None,
                 bytes_received: int | None = None) -> Image.Image:
    """Watermark PSNR (top) and NC (bottom) against bytes received, one point per boundary.

    An exact watermark (PSNR infinite) is drawn at the top edge of the PSNR panel and
    labelled; ``total_bytes`` (the complete file's size) extends the x axis to the
    whole file; ``bytes_received`` below it marks where a cut stream stopped.
    """
    xs = np.array([r.bytes_read for r in results], dtype=np.float64) / 1000.0
    psnr = [r.psnr_db for r in results]
    ncs = [r.nc for r in results]
    fnt, big = font(13), font(16)
    img = Image.new("RGB", size, (255, 255, 255))
    d = ImageDraw.Draw(img)
    left, right, top = 70, size[0] - 20, 16 + (26 if title else 0)
    bottom = size[1] - 48
    mid_gap = 18
    panel_h = (bottom - top - mid_gap) / 2
    if title:
        d.text((left, 12), title, font=big, fill=INK)
    xmax = max(float(xs.max()), (total_bytes or 0) / 1000.0)
    xlim = (0.0, xmax * 1.02 if xmax > 0 else 1.0)
    xticks = _ticks(*xlim)

    finite = [p for p in psnr if p is not None and math.isfinite(p)]
    exact = any(p is not None and math.isinf(p) for p in psnr)
    p_hi = max(finite) if finite else 10.0
    p_top = (p_hi + 8) if exact else p_hi * 1.08 + 1
    p_lo = min(0.0, min(finite)) if finite else 0.0
    top_panel = _Panel(d, (left, top, right, top + panel_h), xlim, (p_lo, p_top))
    top_panel.axes(xticks, _ticks(p_lo, p_top), "watermark PSNR (dB)", fnt, PSNR_COLOR, xlabels=False)
    pts = [(x, (p_top if math.isinf(p) else p)) for x, p in zip(xs, psnr) if p is not None]
    if pts:
        top_panel.series(*zip(*pts), PSNR_COLOR)
    if exact:
        xi = next(x for x, p in zip(xs, psnr) if p is not None and math.isinf(p))
        px, py = top_panel.px(xi, p_top)
        text = "exact (inf)"
        w = d.textlength(text, font=fnt)
        d.text((min(px + 6, right - w - 4), py + 4), text, font=fnt, fill=PSNR_COLOR)

    n_vals = [v for v in ncs if v is not None]
    n_lo = min(0.0, min(n_vals)) if n_vals else 0.0
    bottom_panel = _Panel(d, (left, top + panel_h + mid_gap, right, bottom), xlim, (n_lo, 1.05))
    bottom_panel.axes(xticks, _ticks(n_lo, 1.0, 4), "watermark NC", fnt, NC_COLOR)
    pts = [(x, v) for x, v in zip(xs, ncs) if v is not None]
    if pts:
        bottom_panel.series(*zip(*pts), NC_COLOR)
    cut = bytes_received if bytes_received is not None else xs.max() * 1000
    if total_bytes and cut < total_bytes:
        for panel in (top_panel, bottom_panel):
            px, _ = panel.px(cut / 1000.0, 0)
            y0, y1 = panel.box[1], panel.box[3]
            for y in range(int(y0), int(y1), 8):
                d.line([px, y, px, min(y + 4, y1)], fill=CUT_COLOR, width=1)
        px, _ = top_panel.px(cut / 1000.0, 0)
        d.text((px + 5, top + 6), "stream cut here", font=fnt, fill=CUT_COLOR)
    _text_center(d, ((left + right) / 2, size[1] - 24), "bytes received (kB)", fnt)
    return img


TAMPER_COLOR = (214, 40, 40)


def tamper_figure(positions, faces, flagged, watermark=None, *, size: int = 360, title: str | None = None) -> Image.Image:
    """The mesh ``positions`` (n, 3) / ``faces`` (m, 3) with the vertices ``flagged`` (f,) int64 drawn as red
    dots (hidden ones too: the map is a list, not a view), beside ``watermark`` (s, s) uint8 if given."""
    camera = Camera.fit(positions, size, size)
    pad, top = 14, 30 if title else 0
    img = Image.new("RGB", (pad * 3 + 2 * size if watermark is not None else pad * 2 + size, pad * 2 + top + size + 20),
                    (255, 255, 255))
    img.paste(Image.fromarray(render(positions, faces, camera)), (pad, pad + top))
    draw = ImageDraw.Draw(img)
    if title:
        draw.text((pad, pad), title, font=font(17), fill=INK)
    xy = camera.project(np.asarray(positions, np.float64)[np.asarray(flagged, np.int64)])[:, :2] + (pad, pad + top)
    for x, y in xy:
        draw.ellipse([x - 2, y - 2, x + 2, y + 2], fill=TAMPER_COLOR)
    if watermark is not None:
        mark = Image.fromarray(np.asarray(watermark, np.uint8), "L").resize((size, size), Image.NEAREST)
        img.paste(mark.convert("RGB"), (2 * pad + size, pad + top))
    _text_center(draw, (pad + size / 2, pad + top + size + 10), f"{len(flagged):,} vertices flagged", font(13))
    return img


def write_pictures(directory, pictures: dict) -> list:
    """Write ``pictures`` (``{file name: Pillow image}``) into ``directory`` as PNG files, the set whole or
    not at all; returns their paths.

    Every picture is encoded, then staged beside its target (:func:`pmwm_codec.atomic.stage`), and only
    when all are staged are they published, one rename each, with SIGINT/SIGTERM held back
    (:func:`~pmwm_codec.atomic.signals_deferred`).  A failure or an interrupt before that leaves nothing:
    no picture, and no directory this call made (a rename failing part-way removes the pictures it had
    already published: :func:`~pmwm_codec.atomic.write_set`).  A directory that did not exist is created.
    OptionError naming ``directory`` when a picture cannot be written.
    """
    from .atomic import directory_made, write_set

    directory = os.fspath(directory)
    encoded = {os.path.join(directory, name): [png_bytes(image)] for name, image in pictures.items()}
    try:
        with directory_made(directory):
            write_set(encoded)
    except OSError as exc:
        raise OptionError(f"{directory}: cannot write pictures ({exc.strerror or exc})") from None
    return list(encoded)


def write_figures(results, directory, *, title: str | None = None, total_bytes: int | None = None,
                  bytes_received: int | None = None, k: int = 5, tamper=None, inputs=()) -> dict:
    """Write ``frame_NNN.png`` (see :func:`_frames`: where the watermark changed), ``overview.png``, ``metrics.png``
    and, given ``tamper`` (the flagged vertex ids (f,) of the last result's mesh), ``tamper.png``
    (:func:`tamper_figure`): the set whole or not at all (:func:`write_pictures`).

    ``total_bytes``: size of the complete file; ``bytes_received``: where the stream ended.
    Creates ``directory`` if needed.  Returns ``{"frames": [paths], "overview": path, "plot": path}``
    (``plot`` is None when no result carries a watermark score), and ``"tamper": path`` given ``tamper``.

    Pictures of this set that an earlier run left in ``directory`` and this one does not write (frames of
    other chunks, a ``metrics.png`` or ``tamper.png`` this file has none of) are removed once the new set is
    published (:func:`remove_stale`): the folder shows one file's pictures, not a mix of two.  ``inputs`` (the
    command's input paths) are never removed.
    """
    directory = os.fspath(directory)
    results = _checked_results(results, k, tamper)
    if title is not None and not isinstance(title, str):
        from .errors import OptionError

        raise OptionError(f"write_figures: title must be a str or None, got {type(title).__name__}")
    pictures = _frames(results)
    frames = [os.path.join(directory, name) for name in pictures]
    pictures[OVERVIEW_NAME] = overview(results, k=k, title=title, total_bytes=total_bytes)
    out = {"frames": frames, "overview": os.path.join(directory, OVERVIEW_NAME), "plot": None}
    if any(r.nc is not None for r in results):
        pictures[PLOT_NAME] = metrics_plot(results, title=title, total_bytes=total_bytes,
                                           bytes_received=bytes_received)
        out["plot"] = os.path.join(directory, PLOT_NAME)
    if tamper is not None:
        last = results[-1]
        pictures[TAMPER_NAME] = tamper_figure(last.mesh.positions, last.mesh.faces, tamper, last.watermark,
                                              title=title)
        out["tamper"] = os.path.join(directory, TAMPER_NAME)
    write_pictures(directory, pictures)
    remove_stale(directory, set(pictures), inputs)
    return out


def _checked_results(results, k, tamper) -> list:
    """``results`` of :func:`write_figures` as a list once its arguments are known to draw: one
    :class:`~pmwm_codec.stream.PartialResult` or more (:func:`pmwm_codec.iter_decode`'s), ``k`` an int >= 1 and
    ``tamper`` None or vertex indices of the last result's mesh; OptionError naming what is wrong otherwise."""
    from .stream.decoder import PartialResult

    try:
        results = list(results)
    except TypeError:
        results = []
    if not results:
        raise OptionError("results: nothing to draw; give the PartialResults of pmwm_codec.iter_decode, base first")
    wrong = next((r for r in results if not isinstance(r, PartialResult)), None)
    if wrong is not None:
        raise OptionError("results: each must be a PartialResult of pmwm_codec.iter_decode, "
                          f"got {type(wrong).__name__}")
    if any(not r.parts for r in results):
        raise OptionError("results: they hold no meshes to draw (verify_stream keeps them with keep_meshes=True)")
    if isinstance(k, bool) or not isinstance(k, numbers.Integral) or k < 1:
        raise OptionError(f"k (how many levels the overview shows) must be an integer >= 1, got {k!r}")
    if tamper is not None:
        flagged = np.asarray(tamper)
        n = results[-1].mesh.vertex_count
        if flagged.size and (flagged.dtype.kind not in "iu" or flagged.ndim != 1 or flagged.min() < 0
                             or flagged.max() >= n):
            raise OptionError(f"tamper: vertex indices (f,) of the last result's mesh ({n:,} vertices) expected")
    return results


#: The names :func:`write_figures` writes: a stale one of them is removed by the next write into the folder.
FIGURE_NAMES = re.compile(r"frame_\d{3,}\.png|" + "|".join(re.escape(n) for n in (OVERVIEW_NAME, PLOT_NAME, TAMPER_NAME)))


def remove_stale(directory: str, written: set, inputs=()) -> list:
    """Remove the regular files in ``directory`` whose names are :data:`FIGURE_NAMES` but not ``written``
    (links, folders, the ``inputs`` paths and key files under such a name are left: a key file is never
    rewritten, nor removed); returns the paths removed.  A file that cannot be removed stays (the pictures
    just written are what the command reports)."""
    from .watermark.key import is_key_file

    kept = set()
    for path in inputs:
        with contextlib.suppress(OSError, TypeError, ValueError):
            st = os.stat(path)
            kept.add((st.st_dev, st.st_ino))
    removed = []
    with os.scandir(directory) as entries:
        for entry in entries:
            if entry.name in written or not FIGURE_NAMES.fullmatch(entry.name):
                continue
            with contextlib.suppress(OSError):
                st = entry.stat(follow_symlinks=False)
                if stat.S_ISREG(st.st_mode) and (st.st_dev, st.st_ino) not in kept and not is_key_file(entry.path):
                    os.unlink(entry.path)
                    removed.append(entry.path)
    return removed
