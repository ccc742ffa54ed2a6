"""The body being scaled: one triangle mesh with optional per-vertex region labels.

:class:`Body` is the state that travels between preparation, segmentation, measurement,
constraints and the solver. It is immutable in spirit: a deformation makes a new ``Body``
through :meth:`Body.with_vertices`, which keeps faces and labels and drops derived caches.
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


@dataclass
class Body:
    """A closed-or-open triangle mesh plus what is known about its anatomy.

    ``labels[i]`` is the index into ``region_names`` of vertex ``i``'s region, or
    ``UNLABELLED``. ``cache`` holds derived quantities (skeletons, capped meshes, ...) keyed by
    whoever computes them; it is valid only for these exact vertices.
    """

    vertices: np.ndarray
    faces: np.ndarray
    labels: np.ndarray | None = None
    region_names: tuple[str, ...] = ()
    frame: Frame | None = None
    cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

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
        """The same body (faces, labels, frame) deformed to new vertex positions."""
        return Body(vertices, self.faces, self.labels, self.region_names, self.frame)
