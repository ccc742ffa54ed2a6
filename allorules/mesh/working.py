"""The working mesh: the one surface on which labelling, the basis, measuring and the solve run
(METHOD §9, issue 16).

Users bring 2k to 2M vertices; the answer must not depend on how finely the animal is
tessellated, and a 1,000-mode basis of a million vertices is out of reach. So every run works on
a mesh of a fixed, documented size and triangle quality made from the user's prepared body:

* at or below ``target`` vertices (default :data:`WORKING_VERTICES`): the body itself, untouched
  (``method == "as-is"``; every result is then bit for bit what it was before the working mesh
  existed);
* above it: isotropic remeshing (Botsch & Kobbelt 2004, gpytoolbox's ``remesh_botsch``: split,
  collapse, flip, tangential relaxation, projection back onto the input) to the edge length of
  an equilateral mesh of ``target`` vertices over the body's area; where the body has more than
  :data:`DECIMATE_FIRST` × ``target`` vertices it is first brought down to that many by quadric
  decimation (fast-simplification), because remeshing costs grow with the input (539k vertices:
  26 s, against 2.6 s after decimating to 32k; docs/benchmarks.md).
* The result is repaired like any input (:func:`allorules.preparation.prepare_mesh`: merged
  vertices, degenerate and non-manifold faces dropped, oriented outward, largest part kept).
* A body under :data:`SPLIT_BELOW` vertices whose run missed, used as it is, is made again on
  itself split at its edges' midpoints (:func:`split_working_mesh`, ``method == "split"``): the
  same surface in smaller triangles, its own vertices first, nothing to repair (the run pipeline
  decides when).

:class:`WorkingRecord` keeps a working mesh as points on the body it was made from (each vertex
a triangle of the body and its barycentric weights there), so that the same points can be taken
again on that body moved: a run's output is measured on the working mesh its run measured, not on
a second remesh of its own whose cuts fall elsewhere (``method == "recorded"``).

:func:`make_working_mesh` refuses (one :class:`MeshError` line that says why and what to do) a
body from which no working mesh can be made: a single open sheet, a surface too thin to
enclose a volume, or one the remesher cannot handle. :func:`check_working_vertices` refuses a
user-set size out of range before any work.

The result is carried back to the user's mesh by :mod:`allorules.mesh.transfer`; the run pipeline
(:mod:`allorules.runs.pipeline`) does both.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from allorules.errors import MeshError
from allorules.mesh.decimate import decimate

log = logging.getLogger(__name__)

# The working size, chosen by measurement (benchmarks/bench_resolution.py, docs/benchmarks.md).
WORKING_VERTICES = 8000
MIN_WORKING_VERTICES = 2000      # below this the labeller loses the neck (a 3k cow, issue 16)
MAX_WORKING_VERTICES = 100000    # the paper's own limit; a 1,000-mode basis stays in minutes
WORKING_METHOD = "remesh"        # or "decimate" (see make_working_mesh)
# A run that misses on a body under this many vertices, used as it is, is made again on the body
# split finer (split_working_mesh): its feet are a few triangles and its basis nearly its whole
# spectrum (docs/working-mesh.md, "A coarse body split finer").
SPLIT_BELOW = 1000
DECIMATE_FIRST = 4               # above this many times the target, decimate before remeshing
REMESH_ITERATIONS = 10
FLAT_ANGLE = 170.0               # degrees: a working triangle with a wider angle has its long edge flipped
FLIP_PASSES = 5
# A body is a single sheet when its holes' caps hold more than this share of its surface, and too
# thin when its enclosed volume over area^1.5 is below THIN (a sphere 0.094, a quadruped 0.02-0.04,
# a 100 x 100 x 1 plate 0.0035, x 0.2 0.0007).
SHEET_SHARE = 0.25
THIN = 1e-3


@dataclass(frozen=True)
class WorkingMesh:
    """The mesh a run works on, and how it was made from the user's body."""

    vertices: np.ndarray
    faces: np.ndarray
    method: str                       # "as-is", "split", "remeshed", "decimated+remeshed", "decimated", "recorded"
    source_vertices: int              # vertices of the user's body
    target_vertices: int              # the working size asked for
    seconds: float = 0.0
    quality: dict[str, float] = field(default_factory=dict)

    @property
    def is_source(self) -> bool:
        """The body itself (no transfer needed: results are the body's own)."""
        return self.method == "as-is"

    @property
    def is_coarse_source(self) -> bool:
        """The body itself, under :data:`SPLIT_BELOW` vertices (a missed run is made again split finer)."""
        return self.is_source and len(self.vertices) < SPLIT_BELOW

    def describe(self) -> str:
        if self.is_source:
            return f"working mesh: the body itself ({self.source_vertices} vertices, at or below {self.target_vertices})"
        if self.method == "split":
            return (f"working mesh: {len(self.vertices)} vertices, the body's {self.source_vertices} split at its edges' "
                    f"midpoints (the same surface)")
        if self.method == "recorded":
            return (f"working mesh: {len(self.vertices)} vertices at the points of the body its labels file recorded "
                    f"(the working mesh of the run that wrote it; target {self.target_vertices})")
        return (f"working mesh: {len(self.vertices)} vertices {self.method} from {self.source_vertices} "
                f"(target {self.target_vertices}; smallest angle median {self.quality.get('min_angle_median', 0):.1f}°) "
                f"in {self.seconds:.1f} s")


# A recorded working mesh taken again on a body moved so far that its smallest angles' median fell
# under this (a remesh has 45-55 degrees) is not used: the body is remeshed afresh instead.
RECORDED_MIN_ANGLE_MEDIAN = 25.0


@dataclass(frozen=True)
class WorkingRecord:
    """A working mesh as points on the body it was made from: vertex k is the point with barycentric
    ``weights[k]`` in the body's triangle ``triangle[k]``; ``faces`` are the working mesh's own.
    ``labels``: the working mesh's regions as its run had them (indices into its labels file's
    regions), or ``None``. The body must keep its faces (a run's output keeps its input's)."""

    faces: np.ndarray
    triangle: np.ndarray
    weights: np.ndarray
    target_vertices: int
    labels: np.ndarray | None = None

    @classmethod
    def of(cls, working: WorkingMesh, vertices: np.ndarray, faces: np.ndarray,
           labels: np.ndarray | None = None) -> WorkingRecord:
        """Where each vertex of ``working`` lies on the body (vertices, faces) it was made from (a
        remesh projects every vertex onto the body: the offsets are round-off)."""
        from allorules.mesh.transfer import bind

        on_body = bind(working.vertices, vertices, faces)
        return cls(np.asarray(working.faces, dtype=np.int64), on_body.triangle, on_body.weights,
                   working.target_vertices, None if labels is None else np.asarray(labels, dtype=np.int64))

    def on(self, vertices: np.ndarray, faces: np.ndarray) -> WorkingMesh | None:
        """The working mesh at the recorded points of the body (vertices, faces), or ``None`` where
        those points no longer make a working mesh (the body moved so far that its triangles'
        smallest angles' median fell under :data:`RECORDED_MIN_ANGLE_MEDIAN`, or one has no area)."""
        corners = np.asarray(faces, dtype=np.int64)[self.triangle]
        points = np.einsum("ij,ijk->ik", self.weights, np.asarray(vertices, dtype=np.float64)[corners])
        quality = triangle_quality(points, self.faces)
        if quality["min_angle_median"] < RECORDED_MIN_ANGLE_MEDIAN or quality["min_angle"] <= 0.0:
            log.info("the recorded working mesh no longer fits the body (smallest angles' median %.1f°); remeshing",
                     quality["min_angle_median"])
            return None
        return WorkingMesh(points, self.faces.copy(), "recorded", len(vertices), self.target_vertices, 0.0, quality)


def check_working_vertices(count: int | None) -> int:
    """The working size to use: ``count`` (a user's ``--working-vertices``) or the default.
    Raises :class:`MeshError` for a size out of [MIN_WORKING_VERTICES, MAX_WORKING_VERTICES]."""
    if count is None:
        return WORKING_VERTICES
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) and not float(count).is_integer():
        raise MeshError(f"--working-vertices must be a whole number, got {count!r}")
    count = int(count)
    if not MIN_WORKING_VERTICES <= count <= MAX_WORKING_VERTICES:
        raise MeshError(
            f"--working-vertices {count} is out of range: use {MIN_WORKING_VERTICES} to {MAX_WORKING_VERTICES} "
            f"(default {WORKING_VERTICES}); below, the regions cannot be found, above, the basis takes too long"
        )
    return count


def triangle_quality(vertices: np.ndarray, faces: np.ndarray) -> dict[str, float]:
    """Smallest angle of each triangle: its minimum, 1st percentile and median (degrees), and the
    share of triangles whose smallest angle is under 10° (60° everywhere is equilateral)."""
    from allorules.mesh.geometry import corner_angles

    smallest = corner_angles(vertices, faces).min(axis=1)
    if not len(smallest):
        return {"min_angle": 0.0, "min_angle_p1": 0.0, "min_angle_median": 0.0, "below_10": 1.0}
    return {"min_angle": float(smallest.min()), "min_angle_p1": float(np.percentile(smallest, 1)),
            "min_angle_median": float(np.median(smallest)), "below_10": float(np.mean(smallest < 10.0))}


def check_body_shape(vertices: np.ndarray, faces: np.ndarray, name: str = "mesh") -> None:
    """Refuse a body that no working mesh can represent: a single open sheet, or a surface too thin
    to enclose a volume (the method measures masses as enclosed volumes)."""
    from allorules.mesh.geometry import enclosed_volume, face_areas
    from allorules.mesh.topology import cap_holes

    area = float(face_areas(vertices, faces).sum())
    capped_vertices, capped_faces = cap_holes(vertices, faces)
    cap_area = float(face_areas(capped_vertices, capped_faces[len(faces):]).sum())
    if area <= 0 or not math.isfinite(area):
        raise MeshError(f"{name}: the surface has no area; export the animal as a triangle mesh")
    if cap_area > SHEET_SHARE * area:
        raise MeshError(
            f"{name}: the body is a single open sheet (its holes are {cap_area / area:.0%} of its surface), not an "
            "animal's skin; close it in your modelling tool (or export the whole body, not one side of it)")
    volume = abs(enclosed_volume(capped_vertices, capped_faces))
    if volume / area ** 1.5 < THIN:
        raise MeshError(
            f"{name}: the body encloses almost no volume (volume / area^1.5 = {volume / area ** 1.5:.1e}, under {THIN:g}): "
            "it is too thin or flat to weigh; give a closed animal body")


def make_working_mesh(vertices: np.ndarray, faces: np.ndarray, target: int | None = None, *,
                      name: str = "mesh", method: str | None = None) -> WorkingMesh:
    """The working mesh of a prepared body (vertices, faces): the body itself when it has at most
    ``target`` vertices (default :data:`WORKING_VERTICES`), else an isotropic remesh of about
    ``target`` vertices (within ~5 %), or with ``method="decimate"`` a quadric decimation to it
    (keeps the input's own density: more vertices where it is curved; default
    :data:`WORKING_METHOD`). Raises :class:`MeshError` when none can be made."""
    import time

    target = check_working_vertices(target)
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if len(vertices) <= target:
        return WorkingMesh(vertices, faces, "as-is", len(vertices), target)
    started = time.perf_counter()
    check_body_shape(vertices, faces, name)
    method = method or WORKING_METHOD
    if method not in ("remesh", "decimate"):
        raise ValueError(f"unknown working mesh method {method!r}: remesh or decimate")
    attempts = []
    if method == "decimate":
        attempts.append(("decimated", lambda: decimate(vertices, faces, target)))
    if len(vertices) > DECIMATE_FIRST * target:
        # quadric decimation can leave a few non-manifold edges: repaired before remeshing
        attempts.append(("decimated+remeshed", lambda: _repaired(*decimate(vertices, faces, DECIMATE_FIRST * target), name)))
    attempts.append(("remeshed", lambda: (vertices, faces)))
    failure = None
    for method, source in attempts:
        try:
            remeshed_vertices, remeshed_faces = source() if method == "decimated" else _remesh(*source(), target)
            break
        except Exception as error:   # the remesher raises ValueError/RuntimeError for broken input
            log.debug("%s: %s failed (%s)", name, method, error)
            failure = error
    else:
        raise MeshError(f"{name}: cannot make a working mesh from it ({failure}); repair the mesh in your modelling "
                        "tool (non-manifold or self-overlapping parts) or set --working-vertices "
                        f"{len(vertices)} to work on it as it is") from None
    working_vertices, working_faces = _repaired(remeshed_vertices, remeshed_faces, name)
    working_faces = flip_flat_triangles(working_vertices, working_faces)
    if len(working_vertices) < 0.5 * target:
        raise MeshError(f"{name}: the working mesh came out with {len(working_vertices)} vertices for {target}: the "
                        "surface is too broken to remesh; repair it in your modelling tool")
    quality = triangle_quality(working_vertices, working_faces)
    working = WorkingMesh(working_vertices, working_faces, method, len(vertices), target,
                          time.perf_counter() - started, quality)
    log.info("%s", working.describe())
    return working


def split_working_mesh(vertices: np.ndarray, faces: np.ndarray) -> WorkingMesh:
    """The body split at its edges' midpoints (``trimesh.remesh.subdivide``: each triangle into
    four) until it has :data:`SPLIT_BELOW` vertices or more: the same surface, facets and sharp
    edges included, the body's vertices first and unmoved (each binds to itself)."""
    import time

    import trimesh.remesh

    started = time.perf_counter()
    split_vertices, split_faces = vertices, faces
    while len(split_vertices) < SPLIT_BELOW:
        split_vertices, split_faces = trimesh.remesh.subdivide(split_vertices, split_faces)
    split_vertices = np.asarray(split_vertices, dtype=np.float64)
    split_faces = np.asarray(split_faces, dtype=np.int64)
    working = WorkingMesh(split_vertices, split_faces, "split", len(vertices), len(split_vertices),
                          time.perf_counter() - started, triangle_quality(split_vertices, split_faces))
    log.info("%s", working.describe())
    return working


def flip_flat_triangles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` with the long edge of each near-flat triangle flipped (a new array).

    remesh_botsch projects every vertex back onto the body, and a vertex beside a hole's rim can
    land on one of the rim's edges: a triangle with an angle of 180°, whose cotangent weight is
    unbounded. A held-out donkey split to 136k vertices had two on its working mesh (and two more
    above 170°), and every 1,000-mode basis of it took 37 s; flipped, 4.2 s (docs/working-mesh.md).
    The edge opposite an angle above :data:`FLAT_ANGLE` is flipped where it lies inside the surface,
    the edge it becomes is not one already, and the pair's smallest angle grows; a flat triangle at
    the rim itself stays. (gpytoolbox and libigl's bindings have no edge flip.)"""
    from allorules.mesh.geometry import corner_angles
    from allorules.mesh.topology import directed_edges

    faces = np.array(faces, dtype=np.int64)
    count = int(faces.max(initial=-1)) + 1
    for _ in range(FLIP_PASSES):
        angles = corner_angles(vertices, faces)
        flat = np.flatnonzero(angles.max(axis=1) > FLAT_ANGLE)
        if not len(flat):
            break
        # row k·F + i: face i's k-th edge as it walks it, one integer key per directed edge
        edges = directed_edges(faces)
        keys = edges[:, 0] * count + edges[:, 1]
        order = np.argsort(keys)

        def row_of(a: int, b: int) -> int | None:
            """The row of the directed edge (a, b), or None when no face walks it."""
            position = np.searchsorted(keys, a * count + b, sorter=order)
            return int(order[position]) if position < len(keys) and keys[order[position]] == a * count + b else None

        touched, created = set(), set()       # faces changed and edges made in this pass (not in keys)
        for i in flat:
            corner = int(np.argmax(angles[i]))
            apex, a, b = (int(faces[i, (corner + k) % 3]) for k in range(3))
            across = row_of(b, a)                                   # the face across (a, b) walks (b, a)
            if across is None:
                continue                                            # (a, b) is on a rim
            j, k = across % len(faces), across // len(faces)
            other = int(faces[j, (k + 2) % 3])
            diagonal = frozenset((apex, other))
            if (i in touched or j in touched or other == apex or diagonal in created
                    or row_of(apex, other) is not None or row_of(other, apex) is not None):
                continue
            pair = np.array([[apex, a, other], [apex, other, b]])
            if corner_angles(vertices, pair).min() <= angles[[i, j]].min():
                continue
            faces[i], faces[j] = pair
            touched |= {i, j}
            created.add(diagonal)
        if not created:
            break
    return faces


def _remesh(vertices: np.ndarray, faces: np.ndarray, target: int) -> tuple[np.ndarray, np.ndarray]:
    """Isotropic remeshing (gpytoolbox.remesh_botsch) to the edge length h of an equilateral mesh
    with ``target`` vertices on the same area: a closed mesh of n vertices has about 2n faces of
    area √3/4 h², so h = √(2 A / (√3 n)). One correction of h by the count it gave."""
    import gpytoolbox
    import igl

    from allorules.mesh.geometry import face_areas

    # remesh_botsch can die with a segmentation fault, not an error, on a vertex where two sheets
    # of the surface touch (a held-out cow's pinched vertex, split twice at its edges' midpoints and
    # decimated): it is given the surface with such vertices split apart (libigl), which it remeshes
    if not igl.is_vertex_manifold(faces).all():
        vertices, faces, _ = igl.split_nonmanifold(vertices, faces)
    area = float(face_areas(vertices, faces).sum())
    length = math.sqrt(2.0 * area / (math.sqrt(3.0) * target))
    faces32 = np.ascontiguousarray(faces, dtype=np.int32)
    result_vertices, result_faces = gpytoolbox.remesh_botsch(vertices, faces32, i=REMESH_ITERATIONS, h=length)
    if abs(len(result_vertices) / target - 1.0) > 0.05:
        length *= math.sqrt(len(result_vertices) / target)
        result_vertices, result_faces = gpytoolbox.remesh_botsch(vertices, faces32, i=REMESH_ITERATIONS, h=length)
    return np.asarray(result_vertices, dtype=np.float64), np.asarray(result_faces, dtype=np.int64)


def _repaired(vertices: np.ndarray, faces: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The remesh through the same repairs as any input (one home for them: prepare_mesh)."""
    import trimesh

    from allorules.mesh.repair import prepare_mesh

    prepared = prepare_mesh(trimesh.Trimesh(vertices, faces, process=False))
    for repair in prepared.repairs:
        log.debug("%s: working mesh: %s", name, repair)
    return prepared.vertices, prepared.faces
