"""The body being scaled: one triangle mesh with optional per-vertex region labels.

:class:`Body` is the state that travels between preparation, segmentation, measurement,
constraints and the solver, and what a segmenter plugin receives and returns. It is immutable in
spirit: a deformation makes a new ``Body`` through :meth:`Body.with_vertices`, which keeps faces,
labels, frame and labelling and drops what was measured on the old vertices.

Build one from arrays: ``Body(vertices, faces)`` (n × 3 floats, f × 3 vertex indices); a labelled
one with ``Body(vertices, faces, labels, region_names)`` where ``labels[i]`` indexes
``region_names`` (or is ``UNLABELLED``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

UNLABELLED = -1


@dataclass(frozen=True)
class Frame:
    """Anatomical directions of a body, as unit vectors in mesh coordinates."""

    up: np.ndarray        # from feet to back
    forward: np.ndarray   # from tail to head


@dataclass(frozen=True)
class HeartGirthTape:
    """Where heart girth's tape goes on an animal, as chosen on a reference body (a run's input):
    the chest's area quantiles its candidate sections are cut at, the piece they go round
    (``"part"``: the chest's own, ``"torso"``, ``"body"``) and the margin behind the forelimbs
    (:func:`allorules.measure.girth.chest_girth`). Travels with the regions (a labels file keeps
    it), so that a run's output is measured as its run measured it."""

    levels: tuple[float, ...]
    piece: str
    margin: float


@dataclass(frozen=True)
class Labelling:
    """Who labelled a body's regions, and how sure it was."""

    source: str                       # "segmenter auto-quadruped", "labels file horse.labels.json", ...
    confidence: dict[str, float] = field(default_factory=dict)   # named margins, 0 a guess … 1 certain
    notes: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        return {"source": self.source, "confidence": {key: float(value) for key, value in self.confidence.items()},
                "notes": list(self.notes)}


@dataclass
class Body:
    """A closed-or-open triangle mesh plus what is known about its anatomy.

    ``labels[i]`` is the index into ``region_names`` of vertex ``i``'s region, or
    ``UNLABELLED``. ``labelling`` says who labelled it; ``tape``, where heart girth is measured
    when a reference body chose it (a labels file's). ``measured`` holds what the measure stage
    derived from these exact vertices (:class:`allorules.measure.cache.Measured`: region parts,
    fields, skeletons, measured values); it is dropped by :meth:`with_vertices`.
    """

    vertices: np.ndarray
    faces: np.ndarray
    labels: np.ndarray | None = None
    region_names: tuple[str, ...] = ()
    frame: Frame | None = None
    labelling: Labelling | None = None
    measured: Any = field(default=None, repr=False, compare=False)
    tape: HeartGirthTape | None = None   # heart girth's tape as a reference body chose it (None: chosen here)

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64)
        if self.labels is not None:
            self.labels = np.asarray(self.labels, dtype=np.int64)
            if self.labels.shape != (len(self.vertices),):
                raise ValueError("labels must hold one region index per vertex")
        self.region_names = tuple(self.region_names)

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    def has_region(self, name: str) -> bool:
        return name in self.region_names

    def region_mask(self, name: str) -> np.ndarray:
        """Boolean mask of the vertices labelled ``name``."""
        if self.labels is None or name not in self.region_names:
            raise KeyError(f"body has no region {name!r} (regions: {', '.join(self.region_names) or 'none'})")
        return self.labels == self.region_names.index(name)

    def region_face_mask(self, name: str) -> np.ndarray:
        """Faces belonging to a region: those whose vertices are mostly (≥ 2 of 3) in it."""
        mask = self.region_mask(name)
        return mask[self.faces].sum(axis=1) >= 2

    def with_vertices(self, vertices: np.ndarray) -> "Body":
        """The same body (faces, labels, frame, labelling) deformed to new vertex positions."""
        return Body(vertices, self.faces, self.labels, self.region_names, self.frame, self.labelling, tape=self.tape)

    def with_labels(self, labels: np.ndarray, region_names: tuple[str, ...], labelling: Labelling | None = None,
                    frame: Frame | None = None) -> "Body":
        """The same surface with other regions (and, if given, who labelled them and the frame)."""
        return Body(self.vertices, self.faces, labels, region_names, frame if frame is not None else self.frame,
                    labelling if labelling is not None else self.labelling, tape=self.tape)
