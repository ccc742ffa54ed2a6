"""Hand marks on real meshes and the check "labelled right" the labeller is judged by.

A hand mark file (``tests/data/hand_marks.json``) names, per mesh file, the vertex count of the
file as read and vertex indices *into the file* of the nose tip, the two fore feet, the two hind
feet and (where there is one) the tail tip, chosen by a person looking at renders. The meshes
themselves are never copied; the vertex count guards against a different file of the same name.

A body is **labelled right** when the nose lies in the head (or in an appendage of the head:
ears, horns, trunk), every fore foot in ``forelimbs``, every hind foot in ``hindlimbs``, and the
tail tip (if marked) is not in the head, its appendages or the neck. **Head and tail swapped** is
the worst error: the nose in the tail, abdomen or hind limbs, or the tail tip in the head or neck.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from allorules.body import Body

HEAD_PARTS = ("head", "ears", "horns", "trunk")


@dataclass(frozen=True)
class HandMarks:
    """Marks on one mesh, as vertex indices into the file."""

    file_vertices: int
    nose: int
    fore: tuple[int, int]
    hind: tuple[int, int]
    tail: int | None

    def on_body(self, source_vertex_index: np.ndarray) -> "HandMarks":
        """The same marks as indices into the prepared body (``PreparedMesh.source_vertex_index``)."""
        index = np.asarray(source_vertex_index)
        if len(index) != self.file_vertices:
            raise ValueError(f"the marks are for a file of {self.file_vertices} vertices, this one has {len(index)}")

        def body(vertex):
            mapped = int(index[vertex])
            if mapped < 0:
                raise ValueError(f"marked vertex {vertex} is not on the body")
            return mapped

        return HandMarks(self.file_vertices, body(self.nose), tuple(body(v) for v in self.fore),
                         tuple(body(v) for v in self.hind), None if self.tail is None else body(self.tail))


def read_hand_marks(path: str | Path) -> dict[str, HandMarks]:
    """File name → marks, from a hand mark file."""
    document = json.loads(Path(path).read_text(encoding="utf-8"))
    return {name: HandMarks(int(m["vertices"]), int(m["nose"]), tuple(int(v) for v in m["fore"]),
                            tuple(int(v) for v in m["hind"]), None if m.get("tail") is None else int(m["tail"]))
            for name, m in document["marks"].items()}


@dataclass(frozen=True)
class Verdict:
    right: bool
    swapped: bool
    problems: tuple[str, ...]


def check_labels(body: Body, marks: HandMarks) -> Verdict:
    """Whether ``body``'s regions agree with the marks (``marks`` as body vertex indices)."""
    names = body.region_names

    def region(vertex):
        label = int(body.labels[vertex])
        return names[label] if label >= 0 else "unlabelled"

    problems = []
    nose = region(marks.nose)
    if nose not in HEAD_PARTS:
        problems.append(f"nose in {nose}")
    for kind, feet in (("forelimbs", marks.fore), ("hindlimbs", marks.hind)):
        for foot in feet:
            if region(foot) != kind:
                problems.append(f"a {kind[:-5]} foot in {region(foot)}")
    tail = region(marks.tail) if marks.tail is not None else None
    if tail in HEAD_PARTS + ("neck",):
        problems.append(f"tail tip in {tail}")
    swapped = nose in ("tail", "abdomen", "hindlimbs") or tail in HEAD_PARTS + ("neck",)
    return Verdict(not problems, swapped, tuple(problems))
