"""Pictures for people: shaded PNG renders of meshes, comparisons, close-ups, galleries and the spectrum plot.

Everything runs headless on matplotlib's Agg backend. A mesh is drawn as a ``PolyCollection`` of
its orthographically projected triangles sorted back to front (painter's algorithm) with Lambert
shading computed in numpy; this is much faster than ``mplot3d`` and looks the same for the smooth
closed-ish bodies we draw (a 10k-face mesh renders in well under a second, see docs/outputs.md).

Orientation. Renders follow the body's :class:`~allorules.body.Frame` (``up``: feet to back,
``forward``: tail to head). Without a frame we assume **+Y up** and take the longer of the X and Z
extents as **forward** (positive direction): the convention of most modelling tools, but the head
may then face left. Views:

* ``"side"`` — looking along the body's left-right axis, head to the right, back up;
* ``"three-quarter"`` — from 45° in front of the side and 20° above;
* ``"front"`` — looking at the face, from head towards tail;
* ``"top"`` — from above, head to the right.

Size. ``normalise_size=True`` draws every mesh at the same head-to-tail length, as the paper's
Figures 17–18 do ("the overall scale of each mesh has been normalized"); ``False`` keeps the
true relative scale. Region colours come from a fixed colour-blind-safe palette (Okabe & Ito).
"""
from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import matplotlib
import numpy as np

matplotlib.use("Agg")  # no display, ever
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from allorules.body import UNLABELLED, Body, Frame
from allorules.errors import SegmentationError
from allorules.files import atomic_write
from allorules.mesh.geometry import enclosed_volume, face_areas, face_normals

VIEWS = ("side", "three-quarter", "front", "top")
DEFAULT_SIZE = (900, 600)          # pixels (width, height) of a whole picture
DPI = 100
BASE_COLOR = (0.74, 0.75, 0.78, 1.0)   # clay grey for unlabelled/uncoloured surfaces
BACKGROUND = "white"

# Okabe & Ito (2008) colour-blind-safe palette, one fixed colour per anatomical region.
REGION_PALETTE: dict[str, str] = {
    "head": "#D55E00",        # vermillion
    "neck": "#E69F00",        # orange
    "chest": "#0072B2",       # blue
    "abdomen": "#56B4E9",     # sky blue
    "forelimbs": "#009E73",   # bluish green
    "hindlimbs": "#CC79A7",   # reddish purple
    "tail": "#F0E442",        # yellow
    "body": "#999999",        # grey
}
UNLABELLED_COLOR = "#D9D9D9"
# Regions the table above does not know (plugin regions, numbered patches) get these, chosen by
# a stable hash of the name so a name keeps its colour across pictures (Paul Tol's "muted").
EXTRA_PALETTE = (
    "#332288", "#88CCEE", "#44AA99", "#117733", "#999933",
    "#DDCC77", "#CC6677", "#882255", "#AA4499", "#DDDDDD",
)

_KEY_LIGHT = np.array([-0.45, 0.65, 0.62])   # in camera coordinates: from upper left, front
_FILL_LIGHT = np.array([0.60, -0.15, 0.80])
_KEY_LIGHT /= np.linalg.norm(_KEY_LIGHT)
_FILL_LIGHT /= np.linalg.norm(_FILL_LIGHT)


# --------------------------------------------------------------------------------------------
# Colours


def region_color(name: str) -> tuple[float, float, float, float]:
    """The fixed RGBA colour of a region name (see ``REGION_PALETTE``; other names: stable hash)."""
    from matplotlib.colors import to_rgba

    if name in REGION_PALETTE:
        return to_rgba(REGION_PALETTE[name])
    digest = int(hashlib.sha1(name.encode("utf-8")).hexdigest(), 16)
    return to_rgba(EXTRA_PALETTE[digest % len(EXTRA_PALETTE)])


def region_colors(labels: np.ndarray, region_names: Sequence[str]) -> np.ndarray:
    """Per-vertex RGBA (n, 4) for region labels; ``UNLABELLED`` vertices are light grey."""
    from matplotlib.colors import to_rgba

    labels = np.asarray(labels, dtype=np.int64)
    table = np.array([region_color(name) for name in region_names] + [to_rgba(UNLABELLED_COLOR)])
    index = np.where((labels >= 0) & (labels < len(region_names)), labels, len(region_names))
    return table[index]


def region_legend(labels: np.ndarray | None, region_names: Sequence[str]) -> dict[str, tuple]:
    """Legend entries {name: RGBA} for the regions that occur in ``labels`` (all if None)."""
    from matplotlib.colors import to_rgba

    present = set(range(len(region_names))) if labels is None else set(np.unique(labels).tolist())
    legend = {name: region_color(name) for index, name in enumerate(region_names) if index in present}
    if labels is not None and UNLABELLED in present:
        legend["unlabelled"] = to_rgba(UNLABELLED_COLOR)
    return legend


def _as_rgba(colors: Any, count: int, what: str) -> np.ndarray:
    colors = np.asarray(colors, dtype=float)
    if colors.ndim != 2 or colors.shape[0] != count or colors.shape[1] not in (3, 4):
        raise ValueError(f"{what} must have shape ({count}, 3) or ({count}, 4), got {colors.shape}")
    if colors.max(initial=0.0) > 1.0:  # 0..255
        colors = colors / 255.0
    if colors.shape[1] == 3:
        colors = np.hstack([colors, np.ones((count, 1))])
    return np.clip(np.nan_to_num(colors, nan=0.5), 0.0, 1.0)


# --------------------------------------------------------------------------------------------
# Frame and cameras


def resolve_frame(vertices: np.ndarray, frame: Frame | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthonormal (up, forward, lateral) for a mesh; ``lateral = forward × up`` (body's right).

    Without ``frame``: +Y up and the longer of the X/Z extents forward (positive direction).
    """
    vertices = np.asarray(vertices, dtype=float)
    if frame is None:
        up = np.array([0.0, 1.0, 0.0])
        extent = np.ptp(vertices, axis=0) if len(vertices) else np.ones(3)
        forward = np.array([1.0, 0.0, 0.0]) if extent[0] >= extent[2] else np.array([0.0, 0.0, 1.0])
    else:
        up = np.asarray(frame.up, dtype=float)
        forward = np.asarray(frame.forward, dtype=float)
    up = up / np.linalg.norm(up)
    forward = forward - up * (forward @ up)  # Gram-Schmidt: forward exactly horizontal
    if np.linalg.norm(forward) < 1e-9:
        raise ValueError("frame.forward is parallel to frame.up")
    forward /= np.linalg.norm(forward)
    lateral = np.cross(forward, up)
    return up, forward, lateral


@dataclass(frozen=True)
class Camera:
    """Orthographic camera: screen axes and the unit vector pointing towards the viewer."""

    right: np.ndarray
    up: np.ndarray
    toward_viewer: np.ndarray


def camera_for(view: str, up: np.ndarray, forward: np.ndarray, lateral: np.ndarray) -> Camera:
    """The camera of a named view in a body frame."""
    if view == "side":
        toward = lateral
        screen_up = up
    elif view == "three-quarter":
        azimuth, elevation = np.radians(45.0), np.radians(20.0)
        toward = np.cos(elevation) * (np.cos(azimuth) * lateral + np.sin(azimuth) * forward) + np.sin(elevation) * up
        screen_up = up
    elif view == "front":
        toward = forward
        screen_up = up
    elif view == "top":
        toward = up
        screen_up = -lateral
    else:
        raise ValueError(f"unknown view {view!r}; choose from {', '.join(VIEWS)}")
    toward = toward / np.linalg.norm(toward)
    right = np.cross(screen_up, toward)   # screen x = screen_up × toward_viewer
    right /= np.linalg.norm(right)
    screen_up = np.cross(toward, right)
    return Camera(right, screen_up, toward)


# --------------------------------------------------------------------------------------------
# Shading and projection


@dataclass
class Shot:
    """One mesh seen by one camera: sorted 2-D triangles and their shaded colours."""

    triangles: np.ndarray   # (m, 3, 2) screen coordinates, back to front
    colors: np.ndarray      # (m, 4) RGBA, shaded
    xy: np.ndarray          # (n, 2) every vertex's screen position
    depth: np.ndarray       # (n,) towards the viewer
    faces: np.ndarray       # (m, 3) in drawing order

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the used vertices."""
        used = self.triangles.reshape(-1, 2)
        return float(used[:, 0].min()), float(used[:, 0].max()), float(used[:, 1].min()), float(used[:, 1].max())

    def transformed(self, scale: float, offset: tuple[float, float]) -> "Shot":
        shift = np.asarray(offset, dtype=float)
        return Shot(self.triangles * scale + shift, self.colors, self.xy * scale + shift, self.depth * scale, self.faces)


def shade(face_normals_camera: np.ndarray, base_rgba: np.ndarray) -> np.ndarray:
    """Two-sided Lambert shading with a key and a fill light plus a soft highlight.

    intensity = 0.28 + 0.62·max(0, n·L_key) + 0.18·max(0, n·L_fill); colour = base·intensity +
    0.10·max(0, n·H)^24 (Blinn highlight, H = half vector of key light and view direction).
    Normals facing away from the viewer are flipped (we see the inside of open meshes).
    """
    normals = face_normals_camera.copy()
    length = np.linalg.norm(normals, axis=1)
    good = length > 0
    normals[good] /= length[good, None]
    normals[normals[:, 2] < 0] *= -1.0
    key = np.clip(normals @ _KEY_LIGHT, 0.0, None)
    fill = np.clip(normals @ _FILL_LIGHT, 0.0, None)
    half = _KEY_LIGHT + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half)
    highlight = 0.10 * np.clip(normals @ half, 0.0, None) ** 24
    intensity = np.where(good, 0.28 + 0.62 * key + 0.18 * fill, 0.5)
    colors = base_rgba.copy()
    colors[:, :3] = np.clip(base_rgba[:, :3] * intensity[:, None] + highlight[:, None], 0.0, 1.0)
    return colors


def _checked(vertices: Any, faces: Any) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must be an (n, 3) array, got shape {vertices.shape}")
    if not np.isfinite(vertices).all():
        raise ValueError("cannot render vertices that are NaN or infinite")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(f"nothing to draw: faces must be a non-empty (m, 3) array, got shape {faces.shape}")
    faces = faces.astype(np.int64)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError("faces refer to vertices that do not exist")
    return vertices, faces


CREASE_ANGLE_DEGREES = 50.0   # faces meeting at a sharper angle than this keep a hard edge


def shading_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-face shading normals with "auto smooth": each corner's normal is the area-weighted
    sum of the face normals around its vertex that lie within ``CREASE_ANGLE_DEGREES`` of the
    corner's own face; the face is shaded with the mean of its three corner normals. Organic
    surfaces look smooth, boxes and creases stay crisp, inconsistently oriented patches fall
    back to their flat normal. Very high-valence vertices (over 5 million corner pairs in all)
    fall back to flat shading to bound the cost."""
    vertices, faces = _checked(vertices, faces)
    flat = face_normals(vertices, faces)   # 2·area·n
    flat_length = np.linalg.norm(flat, axis=1)
    flat_unit = flat / np.maximum(flat_length, 1e-300)[:, None]
    face_count = len(faces)
    corner_vertex = faces.reshape(-1)
    corner_face = np.repeat(np.arange(face_count), 3)
    order = np.argsort(corner_vertex, kind="stable")
    sorted_vertex = corner_vertex[order]
    starts = np.flatnonzero(np.r_[True, sorted_vertex[1:] != sorted_vertex[:-1]])
    degree = np.diff(np.r_[starts, len(sorted_vertex)])
    group_of_sorted = np.repeat(np.arange(len(starts)), degree)
    pairs_per_corner = degree[group_of_sorted]
    if pairs_per_corner.sum() > 5_000_000:
        return flat_unit
    # every (corner i, corner j) pair at the same vertex, in sorted-corner numbering
    first = np.repeat(np.arange(len(sorted_vertex)), pairs_per_corner)
    block_start = np.repeat(np.cumsum(pairs_per_corner) - pairs_per_corner, pairs_per_corner)
    second = starts[group_of_sorted][first] + (np.arange(len(first)) - block_start)
    face_i = corner_face[order][first]
    face_j = corner_face[order][second]
    keep = (flat_unit[face_i] * flat_unit[face_j]).sum(axis=1) > np.cos(np.radians(CREASE_ANGLE_DEGREES))
    target = order[first[keep]]
    source = flat[face_j[keep]]
    corner_normals = np.column_stack(
        [np.bincount(target, weights=source[:, axis], minlength=len(corner_vertex)) for axis in range(3)]
    )
    smooth = corner_normals.reshape(face_count, 3, 3).sum(axis=1)
    smooth_length = np.linalg.norm(smooth, axis=1)
    smooth_unit = smooth / np.maximum(smooth_length, 1e-300)[:, None]
    agree = (smooth_length > 0) & ((smooth_unit * flat_unit).sum(axis=1) > 0.5)
    return np.where(agree[:, None], smooth_unit, flat_unit)


def outward_orientation(vertices: np.ndarray, faces: np.ndarray) -> int:
    """+1 if the faces are consistently oriented with normals outward, -1 if consistently inward,
    0 if the orientation is inconsistent or the enclosed volume is (near) zero.

    Consistent: no directed edge is used twice. Outward: signed volume
    V = Σ_f v0 · (v1 × v2) / 6 > 0 (divergence theorem; holes only perturb it slightly).
    """
    faces = np.asarray(faces, dtype=np.int64)
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    if len(np.unique(directed, axis=0)) != len(directed):
        return 0
    vertices = np.asarray(vertices, dtype=float)
    volume = enclosed_volume(vertices, faces)
    area = float(face_areas(vertices, faces).sum())
    if abs(volume) < 1e-6 * max(area, 1e-300) ** 1.5:
        return 0
    return 1 if volume > 0 else -1


def make_shot(
    vertices: np.ndarray,
    faces: np.ndarray,
    camera: Camera,
    *,
    vertex_colors: Any = None,
    face_colors: Any = None,
    normals: np.ndarray | None = None,
    orientation: int | None = None,
) -> Shot:
    """Project, shade and sort (back to front) a mesh for one camera.

    ``normals``: per-face shading normals in mesh coordinates (default :func:`shading_normals`;
    pass them when drawing one mesh from several cameras); ``orientation``: see
    :func:`outward_orientation` (computed when None). On a consistently oriented mesh the faces
    turned away from the viewer are drawn first, then the faces towards it, each group back to
    front: on a closed mesh this is exact whatever the triangle sizes (plain depth sorting of
    large triangles can be wrong); open meshes still show their inside through holes."""
    vertices, faces = _checked(vertices, faces)
    basis = np.stack([camera.right, camera.up, camera.toward_viewer], axis=1)  # world -> camera
    camera_vertices = vertices @ basis
    corners = camera_vertices[faces]
    if normals is None:
        normals = shading_normals(vertices, faces)
    normals = np.asarray(normals, dtype=float) @ basis
    if face_colors is not None:
        base = _as_rgba(face_colors, len(faces), "face_colors")
    elif vertex_colors is not None:
        base = _as_rgba(vertex_colors, len(vertices), "vertex_colors")[faces].mean(axis=1)
    else:
        base = np.tile(BASE_COLOR, (len(faces), 1))
    colors = shade(normals, base)
    if orientation is None:
        orientation = outward_orientation(vertices, faces)
    depth = corners[:, :, 2].mean(axis=1)
    if orientation:
        flat = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])[:, 2] * orientation
        order = np.lexsort((depth, flat > 0))   # turned away first, then far first
    else:
        order = np.argsort(depth, kind="stable")  # far first
    return Shot(
        triangles=corners[order][:, :, :2],
        colors=colors[order],
        xy=camera_vertices[:, :2],
        depth=camera_vertices[:, 2],
        faces=faces[order],
    )


def _draw_shot(axes: Any, shot: Shot) -> None:
    collection = PolyCollection(
        shot.triangles,
        facecolors=shot.colors,
        edgecolors=shot.colors,   # same-colour hairline edges hide antialiasing seams
        linewidths=0.25,
        antialiaseds=True,
        zorder=2,
    )
    axes.add_collection(collection, autolim=False)


def _visible(shot: Shot, point_xy: np.ndarray, point_depth: float, tolerance: float) -> bool:
    """Whether a 3-D point is not hidden by a triangle in front of it (exact depth test)."""
    a, b, c = shot.triangles[:, 0], shot.triangles[:, 1], shot.triangles[:, 2]
    v0, v1, v2 = b - a, c - a, point_xy - a
    d00 = (v0 * v0).sum(1)
    d01 = (v0 * v1).sum(1)
    d11 = (v1 * v1).sum(1)
    d20 = (v2 * v0).sum(1)
    d21 = (v2 * v1).sum(1)
    denominator = d00 * d11 - d01 * d01
    ok = np.abs(denominator) > 1e-30
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(ok, (d11 * d20 - d01 * d21) / denominator, -1.0)
        w = np.where(ok, (d00 * d21 - d01 * d20) / denominator, -1.0)
    u = 1.0 - v - w
    inside = (u >= 0) & (v >= 0) & (w >= 0)
    if not inside.any():
        return True
    depths = shot.depth[shot.faces[inside]]
    barycentric = np.stack([u[inside], v[inside], w[inside]], axis=1)
    face_depth = (depths * barycentric).sum(axis=1)
    return bool(face_depth.max() <= point_depth + tolerance)


def _draw_annotations(axes: Any, shot: Shot, camera: Camera, annotations: Sequence[tuple[Any, str]], scale: float, offset) -> None:
    if not annotations:
        return
    extent = float(np.ptp(shot.depth)) if len(shot.depth) else 1.0
    tolerance = 0.02 * max(extent, 1e-12)
    for point, text in annotations:
        point = np.asarray(point, dtype=float)
        screen = np.array([point @ camera.right, point @ camera.up]) * scale + np.asarray(offset)
        depth = float(point @ camera.toward_viewer) * scale
        if _visible(shot, screen, depth, tolerance):
            axes.text(
                screen[0], screen[1], str(text), ha="center", va="center", fontsize=8, fontweight="bold",
                color="black", zorder=5,
                bbox=dict(boxstyle="round,pad=0.15", facecolor="white", edgecolor="0.3", linewidth=0.5, alpha=0.85),
            )
        else:  # behind the body: still listed, but quiet
            axes.text(
                screen[0], screen[1], str(text), ha="center", va="center", fontsize=7, fontstyle="italic",
                color="0.35", alpha=0.7, zorder=4,
            )


# --------------------------------------------------------------------------------------------
# Figures


def _figure(size: tuple[int, int]) -> Figure:
    width, height = size
    if width < 50 or height < 50:
        raise ValueError(f"picture size {size} is too small (at least 50×50 pixels)")
    figure = Figure(figsize=(width / DPI, height / DPI), dpi=DPI, facecolor=BACKGROUND)
    FigureCanvasAgg(figure)
    return figure


def _save_png(figure: Figure, path: str | Path) -> Path:
    path = Path(path)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=DPI, facecolor=figure.get_facecolor())
    atomic_write(path, buffer.getvalue())
    return path


def _fit_limits(axes: Any, bounds: tuple[float, float, float, float], margin: float = 0.06) -> None:
    """Centre ``bounds`` in the axes with equal aspect and a margin, filling the panel."""
    xmin, xmax, ymin, ymax = bounds
    width, height = max(xmax - xmin, 1e-12), max(ymax - ymin, 1e-12)
    box = axes.get_position()
    figure_width, figure_height = axes.figure.get_size_inches()
    panel_aspect = (box.height * figure_height) / (box.width * figure_width)  # height / width
    width *= 1 + 2 * margin
    height *= 1 + 2 * margin
    if height / width > panel_aspect:
        width = height / panel_aspect
    else:
        height = width * panel_aspect
    cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
    axes.set_xlim(cx - width / 2, cx + width / 2)
    axes.set_ylim(cy - height / 2, cy + height / 2)


def _bare_axes(figure: Figure, rect: Sequence[float]) -> Any:
    axes = figure.add_axes(rect)
    axes.set_axis_off()
    return axes


def _layout(title: str | None, legend: Mapping | None, size: tuple[int, int]) -> tuple[float, float]:
    """Fractions of the figure height reserved at the top (title) and bottom (legend)."""
    height = size[1]
    top = min(0.15, 34 / height) if title else 0.0
    bottom = min(0.15, 30 / height) if legend else 0.0
    return top, bottom


def _draw_title_and_legend(figure: Figure, title: str | None, legend: Mapping | None, top: float, bottom: float) -> None:
    if title:
        figure.text(0.5, 1 - top / 2, title, ha="center", va="center", fontsize=12, color="0.15")
    if legend:
        handles = [Patch(facecolor=color, edgecolor="0.4", linewidth=0.5, label=name) for name, color in legend.items()]
        figure.legend(
            handles=handles, loc="center", bbox_to_anchor=(0.5, bottom / 2), ncol=min(len(handles), 8),
            fontsize=8, frameon=False, handlelength=1.2, columnspacing=1.2,
        )


def _ground_y(shot: Shot) -> float:
    return shot.bounds[2]


def render_views(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    path: str | Path,
    views: Sequence[str] = ("side",),
    frame: Frame | None = None,
    vertex_colors: Any = None,
    face_colors: Any = None,
    annotations: Sequence[tuple[Any, str]] | None = None,
    title: str | None = None,
    legend: Mapping[str, Any] | None = None,
    size: tuple[int, int] | None = None,
) -> Path:
    """Render one mesh from the named ``views`` side by side into a PNG (written atomically).

    ``vertex_colors`` (n, 3|4) or ``face_colors`` (m, 3|4), RGB(A) in 0..1 or 0..255, tint the
    surface (e.g. :func:`region_colors`); ``legend`` ({name: colour}, e.g. :func:`region_legend`)
    is drawn under the picture. ``annotations`` are (3-D point, text) pairs printed on top;
    labels of points hidden behind the body are drawn small and grey. ``size`` is the whole
    picture in pixels (default 900×600 per view row, widened for several views).
    """
    views = tuple(views)
    if not views:
        raise ValueError("give at least one view")
    for view in views:
        if view not in VIEWS:
            raise ValueError(f"unknown view {view!r}; choose from {', '.join(VIEWS)}")
    if size is None:
        size = (DEFAULT_SIZE[0] if len(views) == 1 else 600 * len(views), DEFAULT_SIZE[1])
    figure = _figure(size)
    top, bottom = _layout(title, legend, size)
    up, forward, lateral = resolve_frame(vertices, frame)
    panel_width = 1.0 / len(views)
    normals = shading_normals(vertices, faces)
    orientation = outward_orientation(vertices, faces)
    for number, view in enumerate(views):
        camera = camera_for(view, up, forward, lateral)
        shot = make_shot(vertices, faces, camera, vertex_colors=vertex_colors, face_colors=face_colors,
                         normals=normals, orientation=orientation)
        axes = _bare_axes(figure, [number * panel_width, bottom, panel_width, 1 - top - bottom])
        _draw_shot(axes, shot)
        _fit_limits(axes, shot.bounds)
        if view in ("side", "front"):
            ground = _ground_y(shot)
            axes.axhline(ground, color="0.55", linewidth=0.8, zorder=1)
        _draw_annotations(axes, shot, camera, annotations or (), 1.0, (0.0, 0.0))
        if len(views) > 1:
            axes.text(0.02, 0.02, view, transform=axes.transAxes, fontsize=8, color="0.45", ha="left", va="bottom")
    _draw_title_and_legend(figure, title, legend, top, bottom)
    return _save_png(figure, path)


def _body_length(vertices: np.ndarray, forward: np.ndarray) -> float:
    along = np.asarray(vertices, dtype=float) @ forward
    return float(along.max() - along.min())


def render_comparison(
    meshes: Sequence[tuple],
    *,
    path: str | Path,
    normalise_size: bool,
    frame: Frame | None = None,
    view: str = "side",
    title: str | None = None,
    legend: Mapping[str, Any] | None = None,
    size: tuple[int, int] | None = None,
    shared_ground: bool = False,
) -> Path:
    """Meshes side by side on a common ground line (before/after pictures).

    ``meshes``: (vertices, faces, label) or (vertices, faces, label, vertex_colors) tuples, drawn
    left to right in one frame (the given one, else the first mesh's). ``normalise_size=True``
    draws each at the first mesh's head-to-tail length; ``False`` keeps true relative scale.
    Each mesh stands on the ground line by its own lowest point, unless ``shared_ground`` (true
    scale only): then every mesh keeps its height above the first mesh's lowest point, as in one
    scene, so an output that floats or sinks is drawn floating or sunk.
    """
    if shared_ground and normalise_size:
        raise ValueError("shared_ground draws the meshes as in one scene: use it with normalise_size=False")
    if not meshes:
        raise ValueError("give at least one mesh to compare")
    if size is None:
        size = (min(2400, 520 * len(meshes)), 520)
    figure = _figure(size)
    top, bottom = _layout(title, legend, size)
    label_space = min(0.12, 26 / size[1])
    up, forward, lateral = resolve_frame(meshes[0][0], frame)
    camera = camera_for(view, up, forward, lateral)
    reference_length = _body_length(meshes[0][0], forward)
    shots = []
    for item in meshes:
        vertices, faces = item[0], item[1]
        colors = item[3] if len(item) > 3 else None
        shot = make_shot(vertices, faces, camera, vertex_colors=colors)
        scale = reference_length / max(_body_length(vertices, forward), 1e-300) if normalise_size else 1.0
        shots.append((shot, scale))
    gap = 0.12 * max((shot.bounds[1] - shot.bounds[0]) * scale for shot, scale in shots)
    axes = _bare_axes(figure, [0.0, bottom + label_space, 1.0, 1 - top - bottom - label_space])
    cursor = 0.0
    placed = []
    scene_ground = shots[0][0].bounds[2]
    for (shot, scale), item in zip(shots, meshes):
        xmin, xmax, ymin, _ = shot.bounds
        ground = scene_ground if shared_ground else ymin
        moved = shot.transformed(scale, (cursor - xmin * scale, -ground * scale))  # ground at y = 0
        _draw_shot(axes, moved)
        placed.append((moved, str(item[2])))
        cursor += (xmax - xmin) * scale + gap
    xmin = min(shot.bounds[0] for shot, _ in placed)
    xmax = max(shot.bounds[1] for shot, _ in placed)
    ymin = min(0.0, min(shot.bounds[2] for shot, _ in placed))
    ymax = max(shot.bounds[3] for shot, _ in placed)
    _fit_limits(axes, (xmin, xmax, ymin, ymax), margin=0.04)
    if view in ("side", "front"):
        axes.axhline(0.0, color="0.55", linewidth=0.8, zorder=1)
    for shot, label in placed:
        centre = (shot.bounds[0] + shot.bounds[1]) / 2
        axes.annotate(
            label, xy=(centre, min(0.0, shot.bounds[2])), xytext=(0, -6), textcoords="offset points",
            ha="center", va="top", fontsize=10, color="0.15", annotation_clip=False,
        )
    _draw_title_and_legend(figure, title, legend, top, bottom)
    return _save_png(figure, path)


def render_closeups(
    meshes: Sequence[tuple],
    focus: Any,
    *,
    path: str | Path,
    frame: Frame | None = None,
    views: Sequence[str] = ("side", "three-quarter"),
    title: str | None = None,
    cell_size: tuple[int, int] = (320, 240),
) -> Path:
    """Close-ups of one part (a head, a tail) of meshes that share their vertices (an input and its
    outputs): one column per mesh, one row per view.

    ``meshes``: (vertices, faces, label) tuples as in :func:`render_comparison`; ``focus``: a
    boolean mask over the vertices, the part to look at. The whole mesh is drawn (no cut edges),
    framed on the part, and every panel frames its own part, so each part fills its panel at the
    same size: what changed is its shape, not its size (which the true-scale comparison shows).
    """
    if not meshes:
        raise ValueError("give at least one mesh")
    views = tuple(views)
    for view in views:
        if view not in VIEWS:
            raise ValueError(f"unknown view {view!r}; choose from {', '.join(VIEWS)}")
    focus = np.asarray(focus, dtype=bool)
    if not focus.any():
        raise ValueError("the close-up's part has no vertex")
    for item in meshes:
        if len(item[0]) != len(focus):
            raise ValueError(f"mesh {item[2]!r} has {len(item[0])} vertices, the part's mask {len(focus)}: "
                             "close-ups compare meshes with the same vertices")
    label_height, title_height = 24, 30 if title else 0
    width = cell_size[0] * len(meshes)
    height = title_height + label_height + cell_size[1] * len(views)
    figure = _figure((width, height))
    up, forward, lateral = resolve_frame(meshes[0][0], frame)
    grid_top = 1 - (title_height + label_height) / height
    cell_width, cell_height = 1 / len(meshes), cell_size[1] / height
    for column, item in enumerate(meshes):
        vertices, faces = item[0], item[1]
        colors = item[3] if len(item) > 3 else None
        normals, orientation = shading_normals(vertices, faces), outward_orientation(vertices, faces)
        figure.text((column + 0.5) * cell_width, grid_top + label_height / 2 / height, str(item[2]),
                    ha="center", va="center", fontsize=10, color="0.15")
        for row, view in enumerate(views):
            camera = camera_for(view, up, forward, lateral)
            shot = make_shot(vertices, faces, camera, vertex_colors=colors, normals=normals, orientation=orientation)
            part = shot.xy[focus]
            axes = _bare_axes(figure, [column * cell_width, grid_top - (row + 1) * cell_height, cell_width, cell_height])
            _draw_shot(axes, shot)
            _fit_limits(axes, (part[:, 0].min(), part[:, 0].max(), part[:, 1].min(), part[:, 1].max()), margin=0.12)
            if column == 0 and len(views) > 1:
                axes.text(0.02, 0.02, view, transform=axes.transAxes, fontsize=8, color="0.45", ha="left", va="bottom")
    if title:
        figure.text(0.5, 1 - title_height / 2 / height, title, ha="center", va="center", fontsize=12, color="0.15")
    return _save_png(figure, path)


def render_gallery(
    grid: Mapping[str, Mapping[str, tuple]],
    *,
    path: str | Path,
    rows: Sequence[str] = ("minified", "original", "magnified"),
    normalise_size: bool = True,
    frames: Mapping[str, Frame] | None = None,
    view: str = "side",
    title: str | None = None,
    cell_size: tuple[int, int] = (340, 240),
) -> Path:
    """A gallery in the style of the paper's Figures 17–19: one column per animal, one row per
    ``rows`` entry (e.g. minified / original / magnified).

    ``grid[animal][row] = (vertices, faces)`` or ``(vertices, faces, vertex_colors)``; a missing
    cell is left blank. Each column uses its ``frames[animal]`` or the frame guessed from its
    ``"original"`` (else first) mesh. ``normalise_size=True`` draws every mesh at the same
    head-to-tail length (all cells on one scale); ``False`` keeps each column's true relative
    scale, so a magnified animal is drawn bigger than its original.
    """
    animals = list(grid)
    rows = list(rows)
    if not animals or not rows:
        raise ValueError("the gallery needs at least one animal and one row")
    label_width, header_height = 90, 28 + (30 if title else 0)
    width = label_width + cell_size[0] * len(animals)
    height = header_height + cell_size[1] * len(rows)
    figure = _figure((width, height))
    frames = dict(frames or {})

    # Shots, scaled (normalised: to length 1) and grounded at y = 0 with x centred.
    cells: dict[tuple[int, int], Shot] = {}
    for column, animal in enumerate(animals):
        entries = grid[animal]
        if not entries:
            continue
        anchor = entries.get("original") or next(iter(entries.values()))
        up, forward, lateral = resolve_frame(anchor[0], frames.get(animal))
        camera = camera_for(view, up, forward, lateral)
        for row_index, row in enumerate(rows):
            if row not in entries:
                continue
            item = entries[row]
            shot = make_shot(item[0], item[1], camera, vertex_colors=item[2] if len(item) > 2 else None)
            scale = 1.0 / max(_body_length(item[0], forward), 1e-300) if normalise_size else 1.0
            xmin, xmax, ymin, _ = shot.bounds
            cells[(row_index, column)] = shot.transformed(scale, (-(xmin + xmax) / 2 * scale, -ymin * scale))

    # Common limits: the whole grid when normalised, else each column.
    def limits(keys: list[tuple[int, int]]) -> tuple[float, float, float, float]:
        bounds = np.array([cells[key].bounds for key in keys])
        half = float(np.max(np.abs(bounds[:, :2])))
        return -half, half, 0.0, float(bounds[:, 3].max())

    cell_width = cell_size[0] / width
    cell_height = cell_size[1] / height
    left = label_width / width
    grid_top = 1 - header_height / height
    every = list(cells)
    for column, animal in enumerate(animals):
        keys = [key for key in every if key[1] == column]
        column_limits = limits(every if normalise_size else keys) if keys else None
        figure.text(left + (column + 0.5) * cell_width, grid_top + 14 / height, animal,
                    ha="center", va="center", fontsize=11, color="0.15")
        for row_index in range(len(rows)):
            rect = [left + column * cell_width, grid_top - (row_index + 1) * cell_height, cell_width, cell_height]
            axes = _bare_axes(figure, rect)
            if (row_index, column) not in cells:
                axes.text(0.5, 0.5, "—", transform=axes.transAxes, ha="center", va="center", color="0.6")
                continue
            _draw_shot(axes, cells[(row_index, column)])
            _fit_limits(axes, column_limits, margin=0.08)
            if view in ("side", "front"):
                axes.axhline(0.0, color="0.7", linewidth=0.6, zorder=1)
    for row_index, row in enumerate(rows):
        figure.text(left / 2, grid_top - (row_index + 0.5) * cell_height, row,
                    ha="center", va="center", fontsize=10, color="0.25", rotation=90)
    if title:
        figure.text(0.5, 1 - 15 / height, title, ha="center", va="center", fontsize=12, color="0.15")
    return _save_png(figure, path)


# --------------------------------------------------------------------------------------------
# Plots


def plot_spectrum(
    eigenvalues: np.ndarray,
    coefficients: np.ndarray,
    slope: float,
    intercept: float,
    r: float,
    *,
    path: str | Path,
    title: str | None = None,
    size: tuple[int, int] = (800, 760),
) -> Path:
    """The paper's Figure 4: |r̃_i| against λ_i, semilog (top) and log-log (bottom), with the
    fitted power law r̃ = exp(intercept) · λ^slope (natural-log fit, as ``allorules.spectral.spectrum``).

    ``coefficients`` is the radial spectrum (m,) or the coefficients (m, 3) (their row norms are
    used). Modes with λ ≤ 0 (the constant mode) or r̃ = 0 cannot be drawn on log axes and are left
    out of the picture (not of the fit, which the caller made).
    """
    eigenvalues = np.asarray(eigenvalues, dtype=float)
    coefficients = np.asarray(coefficients, dtype=float)
    radial = np.linalg.norm(coefficients, axis=1) if coefficients.ndim == 2 else np.abs(coefficients)
    if radial.shape != eigenvalues.shape:
        raise ValueError(f"{len(radial)} coefficients for {len(eigenvalues)} eigenvalues")
    drawable = (eigenvalues > 0) & (radial > 0) & np.isfinite(eigenvalues) & np.isfinite(radial)
    if drawable.sum() < 2:
        raise ValueError("fewer than two modes with λ > 0 and r̃ > 0; nothing to plot")
    lam, rad = eigenvalues[drawable], radial[drawable]
    line_lambda = np.geomspace(lam.min(), lam.max(), 200)
    line = np.exp(intercept + slope * np.log(line_lambda))   # log r̃ = slope·log λ + intercept

    figure = _figure(size)
    upper = figure.add_axes([0.11, 0.57, 0.85, 0.35])
    lower = figure.add_axes([0.11, 0.08, 0.85, 0.38])
    for axes, log_x in ((upper, False), (lower, True)):
        axes.plot(lam, rad, linestyle="none", marker="x", markersize=3.5, markeredgewidth=0.8,
                  color="#D62728", label="r̃ (radial spectrum)")
        axes.plot(line_lambda, line, color="0.1", linewidth=1.2,
                  label=f"fit: r̃ ∝ λ^{slope:.3f}")
        axes.set_yscale("log")
        if log_x:
            axes.set_xscale("log")
        axes.set_xlabel("eigenvalue λ" + (" (log)" if log_x else ""))
        axes.set_ylabel("|r̃|")
        axes.grid(True, which="major", color="0.9", linewidth=0.6)
        axes.legend(fontsize=8, loc="upper right", frameon=False)
    upper.set_title("semilog", fontsize=9, color="0.4", loc="left")
    lower.set_title("log-log", fontsize=9, color="0.4", loc="left")
    heading = f"slope α = {slope:.3f}   R = {r:.3f}   ({len(lam)} modes)"
    figure.text(0.5, 0.965, f"{title} — {heading}" if title else heading, ha="center", va="center", fontsize=11)
    return _save_png(figure, path)


def render_regions(body: Body, path, *, numbered: bool = False, title: str | None = None, views=None):
    """A PNG of the body with one colour per region, from several views.

    ``numbered`` prints each region's index on it (for patches: the ids a merge file uses), at
    the region's vertex nearest to its area centroid.
    """
    from allorules.mesh.geometry import vertex_areas

    if body.labels is None:
        raise SegmentationError("the body has no labels to draw; segment it first")
    views = tuple(views) if views else VIEWS
    colors = region_colors(body.labels, body.region_names)
    annotations = []
    if numbered:
        mass = vertex_areas(body.vertices, body.faces)
        for index in range(len(body.region_names)):
            members = np.flatnonzero(body.labels == index)
            if len(members) == 0:
                continue
            centre = np.average(body.vertices[members], axis=0, weights=mass[members] + 1e-300)
            nearest = members[np.argmin(np.linalg.norm(body.vertices[members] - centre, axis=1))]
            annotations.append((body.vertices[nearest], str(index)))
    legend = None if numbered else region_legend(body.labels, body.region_names)
    return render_views(body.vertices, body.faces, path=path, views=views, frame=body.frame,
                        vertex_colors=colors, annotations=annotations or None, title=title, legend=legend)
