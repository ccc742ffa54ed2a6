"""Files that carry a segmentation: per-vertex label JSON, Princeton ``.seg``, and merge files.

* **Labels file** (``*.json``), one region index per vertex::

      {"format": "allorules-labels", "version": 1,
       "regions": ["head", "neck", ...], "labels": [0, 0, 3, ..., -1]}

  ``labels[i]`` indexes ``regions``; ``-1`` means unlabelled. The generator's CLI writes the same.
  Optional: ``labelling`` (who labelled it, how sure), ``frame`` (``{"up": [x, y, z],
  "forward": [x, y, z]}``, the animal's axes as the labeller found them, read back with the labels),
  ``faces_sha256`` (the mesh's faces, so that a file is known to be this mesh's: a run's output
  keeps its input's faces, so its input's labels fit it too) and ``heart_girth_tape`` (``{"levels":
  [area quantiles of the chest], "piece": "part"|"torso"|"body", "margin": m}``: where a run put
  heart girth's tape on its input, so that its output is measured there too) and ``working_mesh``
  (``{"target_vertices": t, "faces": [...], "triangles": [...], "weights": [...], "labels": [...]}``:
  the working mesh its run measured on, as points of this mesh, each vertex a triangle of the
  mesh and three barycentric weights, with its regions: :class:`~allorules.mesh.working.WorkingRecord`,
  read back by :func:`read_labels_file`).
  ``NAME.labels.json`` beside ``NAME.EXT`` (:func:`labels_file_beside`) is the mesh's own: ``allorules
  scale`` writes its output's there, and ``scale`` and ``measure`` read it when it fits the mesh.
* **Princeton segmentation benchmark ``.seg``**: one integer per line, one line per FACE, in face
  order; the integer is the face's segment. Faces get the majority label of their three vertices
  (:func:`face_labels_from_vertices`); vertices get the area-weighted majority of their faces
  (:func:`vertex_labels_from_faces`).
* **Merge file** (YAML): which patches of ``allorules segment`` make up each region::

      head: [3, 17]
      neck: [9]
      ...

  Validated with errors naming the file and line: unknown patch ids, a patch in two regions,
  a required region missing, patches left in no region.

All writers are atomic (temporary file + ``os.replace``).
"""
from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import scipy.sparse as sparse
import yaml

from allorules.body import UNLABELLED, Body, Frame, HeartGirthTape, Labelling
from allorules.errors import RulesetError, SegmentationError, SourceLocation
from allorules.files import atomic_write, text_size_problem
from allorules.mesh.geometry import face_areas
from allorules.mesh.working import MAX_WORKING_VERTICES, WorkingRecord
from allorules.segment.regions import QUADRUPED_REGIONS

log = logging.getLogger("allorules")

LABELS_FORMAT = "allorules-labels"
TAPE_PIECES = ("part", "torso", "body")   # what heart girth's tape goes round (measure/girth.chest_girth)
LABELS_VERSION = 1


class UnsaidMeshError(SegmentationError):
    """A labels file that does not say which mesh it was made for (no ``faces_sha256``: written by
    an older allorules or by hand), where the mesh's own was asked for."""


class MergeFileError(SegmentationError, RulesetError):
    """A merge file is invalid; the message starts with ``file:line``."""


# ---------------------------------------------------------------- labels JSON

def labels_file_beside(mesh: str | Path) -> Path:
    """``NAME.labels.json`` beside ``NAME.EXT``: the mesh's own labels file."""
    mesh = Path(mesh)
    return mesh.with_name(mesh.stem + ".labels.json")


def faces_fingerprint(faces: np.ndarray) -> str:
    """SHA-256 of the faces (vertex indices, in order): the same for a mesh and every output of a
    run on it, which keep its faces and move only its vertices."""
    return hashlib.sha256(np.ascontiguousarray(faces, dtype="<i8").tobytes()).hexdigest()


@dataclass(frozen=True)
class LabelsFile:
    """What a labels file gives a body: the body labelled and, where the file recorded one (a run's
    output's), the working mesh its run measured on as points of the body."""

    body: Body
    working: WorkingRecord | None = None


def write_labels(path: str | Path, body: Body, working: WorkingRecord | None = None) -> None:
    """Write the body's per-vertex labels as an allorules labels file (JSON), with the ``working``
    mesh its run measured on where given (the weights to 1e-9: a point moves by 1e-9 of an edge)."""
    if body.labels is None:
        raise SegmentationError("the body has no labels to write; segment it first")
    document = {
        "format": LABELS_FORMAT,
        "version": LABELS_VERSION,
        "regions": list(body.region_names),
        "labels": [int(label) for label in body.labels],
        "faces_sha256": faces_fingerprint(body.faces),
    }
    if body.labelling is not None:   # who labelled it and how sure it was (optional when read)
        document["labelling"] = body.labelling.as_dict()
    if body.frame is not None:       # the animal's up and forward the labeller found (optional when read)
        document["frame"] = {"up": [float(value) for value in body.frame.up],
                             "forward": [float(value) for value in body.frame.forward]}
    if body.tape is not None:        # where heart girth's tape went on the run's input (optional when read)
        document["heart_girth_tape"] = {"levels": [float(level) for level in body.tape.levels],
                                        "piece": body.tape.piece, "margin": float(body.tape.margin)}
    if working is not None:
        document["working_mesh"] = {
            "target_vertices": int(working.target_vertices),
            "faces": np.asarray(working.faces, dtype=np.int64).ravel().tolist(),
            "triangles": np.asarray(working.triangle, dtype=np.int64).tolist(),
            "weights": np.round(np.asarray(working.weights, dtype=float), 9).ravel().tolist(),
            "labels": None if working.labels is None else np.asarray(working.labels, dtype=np.int64).tolist()}
    atomic_write(path, json.dumps(document, separators=(",", ":")) + "\n")


def labels_file_limit(vertex_count: int) -> int:
    """The largest labels file read for a mesh of ``vertex_count`` vertices, in bytes: room for a
    padded label per vertex, a recorded working mesh (at most ~100 bytes a vertex, and no more
    vertices than the mesh or the largest working size), the frame, the tape and the notes (1 MB)."""
    return 16 * vertex_count + 100 * min(vertex_count, 2 * MAX_WORKING_VERTICES) + 1_000_000


def read_labels(path: str | Path, body: Body, *, same_faces: bool = False) -> Body:
    """The body with the labels of an allorules labels file (:func:`read_labels_file`)."""
    return read_labels_file(path, body, same_faces=same_faces).body


def read_labels_file(path: str | Path, body: Body, *, same_faces: bool = False) -> LabelsFile:
    """The body with the labels of an allorules labels file, and the working mesh it recorded; checked
    against the body's vertex count and, where the file has them, its faces (another mesh's faces:
    refused with ``same_faces``, else used with a warning; ``same_faces`` also refuses a file without
    them). A recorded working mesh is read only for the faces it was made on."""
    path = Path(path)
    try:
        size, largest = path.stat().st_size, labels_file_limit(body.vertex_count)
        if size > largest:    # a label is a few bytes: this is some other file, not to be read whole
            raise SegmentationError(f"{path}: {size / 1e6:.1f} MB is too large for the labels of a mesh of "
                                    f"{body.vertex_count} vertices (at most {largest / 1e6:.1f} MB); is it the right file?")
        document = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SegmentationError(f"{path}: labels file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise SegmentationError(f"{path}: not a readable labels file ({error})") from None
    except RecursionError:   # '[[[[…' nested deeper than any labels file
        raise SegmentationError(f"{path}: not an allorules labels file (its JSON nests thousands of levels deep)") from None
    if not isinstance(document, dict) or document.get("format") != LABELS_FORMAT:
        raise SegmentationError(f'{path}: not an allorules labels file (expected "format": "{LABELS_FORMAT}")')
    if document.get("version") != LABELS_VERSION:
        raise SegmentationError(f"{path}: labels file version {document.get('version')!r} is not supported (expected {LABELS_VERSION})")
    regions, labels = document.get("regions"), document.get("labels")
    if not isinstance(regions, list) or not all(isinstance(name, str) for name in regions) or len(set(regions)) != len(regions):
        raise SegmentationError(f'{path}: "regions" must be a list of distinct region names')
    if not isinstance(labels, list) or not all(isinstance(label, int) and not isinstance(label, bool) for label in labels):
        raise SegmentationError(f'{path}: "labels" must be a list of integers, one per vertex')
    if len(labels) != body.vertex_count:
        raise SegmentationError(
            f"{path}: has {len(labels)} labels but the mesh has {body.vertex_count} vertices; "
            "labels must come from this exact mesh (after the same preparation)"
        )
    fingerprint = document.get("faces_sha256")
    same = fingerprint == faces_fingerprint(body.faces)
    if not same:
        if same_faces and fingerprint is None:
            raise UnsaidMeshError(f"{path}: does not say which mesh it was made for (an older labels file)")
        if same_faces:
            raise SegmentationError(f"{path}: made for another mesh (its faces differ)")
        if fingerprint is not None:
            log.warning("%s: made for a mesh with other faces (same vertex count); its labels are used as given", path)
    labels = np.asarray(labels, dtype=np.int64)
    bad = (labels < UNLABELLED) | (labels >= len(regions))
    if bad.any():
        raise SegmentationError(
            f"{path}: label {int(labels[bad][0])} at vertex {int(np.flatnonzero(bad)[0])} is not a region index "
            f"(0 … {len(regions) - 1}, or -1 for unlabelled)"
        )
    labelled = body.with_labels(labels, tuple(regions), _read_labelling(document.get("labelling")),
                                _read_frame(document.get("frame")))
    labelled = replace(labelled, tape=_read_tape(document.get("heart_girth_tape")))
    working = _read_working(document.get("working_mesh"), body, len(regions), path) if same else None
    return LabelsFile(labelled, working)


def _read_working(value, body: Body, region_count: int, path: Path) -> WorkingRecord | None:
    """The optional ``working_mesh`` of a labels file (a malformed one is ignored, saying so: the mesh
    is then remeshed afresh and its labels carried over)."""
    if value is None:
        return None
    try:
        if not isinstance(value, dict):
            raise ValueError("not an object")
        faces, triangle = _integers(value.get("faces")).reshape(-1, 3), _integers(value.get("triangles"))
        weights = np.asarray(value.get("weights"), dtype=float).reshape(-1, 3)
        target = value.get("target_vertices")
        labels = None if value.get("labels") is None else _integers(value.get("labels"))
        count = len(triangle)
        if not 4 <= count <= 2 * MAX_WORKING_VERTICES or len(weights) != count or not len(faces):
            raise ValueError(f"{count} vertices, {len(weights)} weights")
        if triangle.min() < 0 or triangle.max() >= len(body.faces) or faces.min() < 0 or faces.max() >= count:
            raise ValueError("an index out of range")
        if not np.all(np.isfinite(weights)) or weights.min() < -1e-6 or weights.max() > 1 + 1e-6:
            raise ValueError("a weight outside [0, 1]")
        if isinstance(target, bool) or not isinstance(target, int) or not 1 <= target <= MAX_WORKING_VERTICES:
            raise ValueError("target_vertices")
        if labels is not None and (len(labels) != count or labels.min() < UNLABELLED or labels.max() >= region_count):
            raise ValueError("labels")
    except (TypeError, ValueError) as error:
        log.warning("%s: its working_mesh is malformed (%s); ignored, the mesh is remeshed", path, error)
        return None
    return WorkingRecord(faces, triangle, weights, target, labels)


def _integers(value) -> np.ndarray:
    array = np.asarray(value)
    if array.ndim != 1 or array.dtype.kind not in "iu" or not len(array):
        raise ValueError("expected a list of integers")
    return array.astype(np.int64)


def _read_labelling(value) -> Labelling | None:
    """The optional ``labelling`` of a labels file (older files have none; a malformed one is ignored)."""
    if not isinstance(value, dict) or not isinstance(value.get("source"), str):
        return None
    confidence = value.get("confidence") if isinstance(value.get("confidence"), dict) else {}
    notes = value.get("notes") if isinstance(value.get("notes"), list) else []
    return Labelling(value["source"], {str(key): float(number) for key, number in confidence.items()
                                       if isinstance(number, (int, float)) and not isinstance(number, bool)},
                     tuple(str(note) for note in notes))


def _read_tape(value) -> HeartGirthTape | None:
    """The optional ``heart_girth_tape`` of a labels file (a malformed one is ignored: the tape is
    then placed afresh)."""
    if not isinstance(value, dict) or value.get("piece") not in TAPE_PIECES:
        return None
    levels, margin = value.get("levels"), value.get("margin")
    if not isinstance(levels, list) or not levels or not all(isinstance(level, (int, float)) and not isinstance(level, bool)
                                                             and 0.0 < level < 1.0 for level in levels):
        return None
    if not isinstance(margin, (int, float)) or isinstance(margin, bool) or not 0.0 <= margin < 1.0:
        return None
    return HeartGirthTape(tuple(float(level) for level in levels), value["piece"], float(margin))


def _read_frame(value) -> Frame | None:
    """The optional ``frame`` of a labels file: the body's up and forward as the labeller found them,
    so that a body labelled from the file is measured along the same axes as the labeller's (older
    files have none; a malformed one is ignored, and the axes come from the regions)."""
    if not isinstance(value, dict):
        return None
    try:
        up, forward = (np.asarray(value[key], dtype=float) for key in ("up", "forward"))
    except (KeyError, TypeError, ValueError):
        return None
    if up.shape != (3,) or forward.shape != (3,) or not (np.all(np.isfinite(up)) and np.all(np.isfinite(forward))):
        return None
    up_length, forward_length = np.linalg.norm(up), np.linalg.norm(forward)
    if min(up_length, forward_length) == 0 or np.linalg.norm(np.cross(up, forward)) < 1e-6 * up_length * forward_length:
        return None
    return Frame(up=up / up_length, forward=forward / forward_length)


# ---------------------------------------------------------------- face <-> vertex

def face_labels_from_vertices(faces: np.ndarray, vertex_labels: np.ndarray) -> np.ndarray:
    """Per-face labels: the label held by at least two of the face's vertices, else its first vertex's."""
    corner = vertex_labels[faces]
    return np.where(corner[:, 1] == corner[:, 2], corner[:, 1], corner[:, 0])


def vertex_labels_from_faces(vertices: np.ndarray, faces: np.ndarray, face_labels: np.ndarray) -> np.ndarray:
    """Per-vertex labels: the area-weighted majority label of the faces around each vertex."""
    face_labels = np.asarray(face_labels, dtype=np.int64)
    labelled = face_labels >= 0
    n = len(vertices)
    result = np.full(n, UNLABELLED, dtype=np.int64)
    if not labelled.any():
        return result
    areas = face_areas(vertices, faces)[labelled] + 1e-300  # a zero-area face still votes, weakly
    rows = faces[labelled].ravel()
    columns = np.repeat(face_labels[labelled], 3)
    votes = sparse.coo_matrix((np.repeat(areas, 3), (rows, columns)), shape=(n, int(face_labels.max()) + 1)).tocsr()
    has_vote = np.asarray(votes.sum(axis=1)).ravel() > 0
    result[has_vote] = np.asarray(votes[has_vote].argmax(axis=1)).ravel()
    return result


# ---------------------------------------------------------------- Princeton .seg

def write_seg(path: str | Path, body: Body) -> None:
    """Write per-face labels, one integer per line (Princeton benchmark ``.seg``); −1 for unlabelled faces."""
    if body.labels is None:
        raise SegmentationError("the body has no labels to write; segment it first")
    face_labels = face_labels_from_vertices(body.faces, body.labels)
    atomic_write(path, "".join(f"{int(label)}\n" for label in face_labels))


def read_seg(path: str | Path, body: Body, region_names: tuple[str, ...] | list[str] | None = None) -> Body:
    """The body labelled from a Princeton ``.seg`` file (one segment id per face).

    Segment ``i`` becomes region ``region_names[i]``; without names the regions are called
    ``segment0``, ``segment1``, … Vertices take the area-weighted majority of their faces.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").split()
    except FileNotFoundError:
        raise SegmentationError(f"{path}: .seg file not found") from None
    except (OSError, UnicodeDecodeError) as error:
        raise SegmentationError(f"{path}: not a readable .seg file ({error})") from None
    try:
        face_labels = np.array([int(token) for token in lines], dtype=np.int64)
    except ValueError as error:
        raise SegmentationError(f"{path}: a .seg file holds one integer per line ({error})") from None
    if len(face_labels) != len(body.faces):
        raise SegmentationError(
            f"{path}: has {len(face_labels)} face labels but the mesh has {len(body.faces)} faces; "
            "a .seg file must come from this exact mesh"
        )
    if (face_labels < UNLABELLED).any():
        raise SegmentationError(f"{path}: segment ids must be 0 or more (or -1 for unlabelled)")
    count = int(face_labels.max()) + 1 if len(face_labels) else 0
    if region_names is None:
        region_names = tuple(f"segment{i}" for i in range(count))
    region_names = tuple(region_names)
    if count > len(region_names):
        raise SegmentationError(f"{path}: segment id {count - 1} has no region name (names given: {', '.join(region_names)})")
    labels = vertex_labels_from_faces(body.vertices, body.faces, face_labels)
    return Body(body.vertices, body.faces, labels, region_names, body.frame)


# ---------------------------------------------------------------- merge files

def read_merge_file(path: str | Path, patch_count: int, required: tuple[str, ...] | None = None) -> dict[str, list[int]]:
    """Parse and validate a merge file: region name → list of patch ids.

    Errors (``MergeFileError``, message starting with ``file:line``): not YAML / not a mapping,
    a region whose value is not a list of integers, an id outside 0 … patch_count−1, a patch in
    two regions, a required region missing, and patches that belong to no region.
    """

    required = QUADRUPED_REGIONS if required is None else tuple(required)
    path = Path(path)
    try:
        too_large = text_size_problem(path.stat().st_size, "merge file") if path.is_file() else None
        if too_large:
            raise MergeFileError(too_large, SourceLocation(path))
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise MergeFileError("merge file not found", SourceLocation(path)) from None
    except (OSError, UnicodeDecodeError) as error:
        raise MergeFileError(f"cannot read merge file ({error})", SourceLocation(path)) from None
    try:
        root = yaml.compose(text)
    except RecursionError:
        raise MergeFileError("the YAML nests too deeply; a merge file maps each region to a list of patch ids, "
                             "e.g. 'head: [3, 17]'", SourceLocation(path)) from None
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(error, "problem", None) or str(error).splitlines()[0]
        raise MergeFileError(f"not valid YAML: {problem}", SourceLocation(path, line)) from None
    if root is None or not isinstance(root, yaml.MappingNode):
        raise MergeFileError(
            "a merge file maps each region to a list of patch ids, e.g. 'head: [3, 17]'",
            SourceLocation(path, root.start_mark.line + 1 if root is not None else 1),
        )
    regions: dict[str, list[int]] = {}
    owner: dict[int, tuple[str, int]] = {}
    for key_node, value_node in root.value:
        line = key_node.start_mark.line + 1
        name = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
        if not name or not isinstance(name, str):
            raise MergeFileError("region names must be plain words", SourceLocation(path, line))
        if name in regions:
            raise MergeFileError(f"region {name!r} is given twice", SourceLocation(path, line))
        items = value_node.value if isinstance(value_node, yaml.SequenceNode) else [value_node] if isinstance(value_node, yaml.ScalarNode) else None
        if items is None:
            raise MergeFileError(f"region {name!r} must list patch ids, e.g. '{name}: [3, 17]'", SourceLocation(path, line))
        ids = []
        for item in items:
            item_line = item.start_mark.line + 1
            if not isinstance(item, yaml.ScalarNode) or item.tag != "tag:yaml.org,2002:int":
                if isinstance(item, yaml.ScalarNode) and item.tag == "tag:yaml.org,2002:null":
                    continue  # 'ears:' with nothing after it
                raise MergeFileError(f"patch id {getattr(item, 'value', item)!r} of region {name!r} is not an integer", SourceLocation(path, item_line))
            try:
                patch = int(item.value)
            except ValueError:  # YAML also allows 0x1f, 0o17, 1_000
                patch = int(item.value.replace("_", ""), 0)
            if not 0 <= patch < patch_count:
                raise MergeFileError(
                    f"unknown patch id {patch} in region {name!r}: patches are numbered 0 … {patch_count - 1}",
                    SourceLocation(path, item_line),
                )
            if patch in owner:
                first, first_line = owner[patch]
                raise MergeFileError(
                    f"patch {patch} is in two regions: {first!r} (line {first_line}) and {name!r}",
                    SourceLocation(path, item_line),
                )
            owner[patch] = (name, item_line)
            ids.append(patch)
        regions[name] = ids
    missing = [name for name in required if not regions.get(name)]
    if missing:
        raise MergeFileError(
            f"required region{'s' if len(missing) > 1 else ''} {', '.join(missing)} missing or empty "
            f"(needed: {', '.join(required)})",
            SourceLocation(path, root.end_mark.line + 1 if root.end_mark.column else root.end_mark.line),
        )
    unassigned = sorted(set(range(patch_count)) - set(owner))
    if unassigned:
        raise MergeFileError(
            f"patch{'es' if len(unassigned) > 1 else ''} {', '.join(map(str, unassigned))} belong to no region; "
            "add each to the region it is part of",
            SourceLocation(path, root.end_mark.line + 1 if root.end_mark.column else root.end_mark.line),
        )
    return regions


def apply_merge_file(body: Body, patches: np.ndarray, path: str | Path, required: tuple[str, ...] | None = None) -> Body:
    """The body labelled by merging its patches into regions as a merge file says.

    Region order: the required regions (the six quadruped regions by default) first, then any
    extra regions in the order the file names them.
    """
    patches = np.asarray(patches, dtype=np.int64)
    if patches.shape != (body.vertex_count,):
        raise SegmentationError(f"patch ids must be one per vertex ({body.vertex_count}), got {patches.shape}")
    patch_count = int(patches.max()) + 1
    regions = read_merge_file(path, patch_count, required)

    required = QUADRUPED_REGIONS if required is None else tuple(required)
    names = tuple(required) + tuple(name for name in regions if name not in required)
    lookup = np.full(patch_count, UNLABELLED, dtype=np.int64)
    for index, name in enumerate(names):
        lookup[regions.get(name, [])] = index
    return Body(body.vertices, body.faces, lookup[patches], names, body.frame)
