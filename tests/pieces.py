"""Toys modelled as game figures often are: closed pieces pushed into each other (a quadruped, and
an upright bear that is none)."""
from __future__ import annotations

import numpy as np
import trimesh


def _capsule(start, end, radius: float) -> trimesh.Trimesh:
    start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    length = float(np.linalg.norm(end - start))
    piece = trimesh.creation.capsule(height=length, radius=radius, count=[16, 16])
    piece.apply_transform(trimesh.geometry.align_vectors([0.0, 0.0, 1.0], (end - start) / length))
    piece.apply_translation((start + end) / 2)
    return piece


def pieces_quadruped() -> tuple[trimesh.Trimesh, dict[str, np.ndarray]]:
    """A toy animal as game models are built: a trunk, four legs, a neck, a head with a muzzle,
    a tail and two eyes, eleven closed pieces pushed into each other, never welded; Z up, the head
    at +X. Also which input vertices are its muzzle, each foot and the tail's tip."""
    pieces = [_capsule([-0.6, 0, 1.0], [0.6, 0, 1.0], 0.35)]
    pieces += [_capsule([x, y, 0.95], [x, y, 0.08], 0.09) for x in (-0.45, 0.45) for y in (-0.2, 0.2)]
    pieces.append(_capsule([0.6, 0, 1.1], [0.95, 0, 1.55], 0.14))
    pieces.append(trimesh.creation.icosphere(subdivisions=3, radius=0.25).apply_translation([1.05, 0, 1.65]))
    pieces.append(_capsule([1.2, 0, 1.6], [1.4, 0, 1.55], 0.1))
    pieces.append(_capsule([-0.85, 0, 1.05], [-1.1, 0, 0.7], 0.05))
    pieces += [trimesh.creation.icosphere(subdivisions=2, radius=0.04).apply_translation([1.25, y, 1.78]) for y in (-0.08, 0.08)]
    mesh = trimesh.util.concatenate(pieces)
    v = mesh.vertices
    marks = {"muzzle": np.flatnonzero(v[:, 0] > 1.45), "tail": np.flatnonzero((v[:, 0] < -1.1) & (v[:, 2] < 0.72))}
    for name, x in (("forelimbs", 0.45), ("hindlimbs", -0.45)):
        marks[name] = np.flatnonzero((v[:, 2] < 0.1) & (np.abs(v[:, 0] - x) < 0.1))
    return mesh, marks


def upright_toy_bear() -> trimesh.Trimesh:
    """A toy bear standing upright on its two legs, nine closed pieces: a trunk along Z, legs
    down, arms out and down, a head on top with two ears and a snout at +X. Not a quadruped."""
    pieces = [_capsule([0, 0, 0.7], [0, 0, 1.3], 0.35)]
    pieces += [_capsule([0, y, 0.6], [0.1, y, 0.05], 0.13) for y in (-0.18, 0.18)]
    pieces += [_capsule([0, side * 0.3, 1.35], [0, side * 0.75, 1.08], 0.1) for side in (-1, 1)]
    pieces.append(trimesh.creation.icosphere(subdivisions=3, radius=0.3).apply_translation([0, 0, 1.85]))
    pieces += [trimesh.creation.icosphere(subdivisions=2, radius=0.09).apply_translation([0, y, 2.12]) for y in (-0.2, 0.2)]
    pieces.append(trimesh.creation.icosphere(subdivisions=2, radius=0.1).apply_translation([0.28, 0, 1.8]))
    return trimesh.util.concatenate(pieces)
