"""Spectral over-segmentation of a mesh into connected patches (paper §3.2, after Liu & Zhang 2004).

The paper cuts the mesh into 24 patches by spectral clustering and lets a person merge them into
anatomical regions. Here each vertex is embedded by the low harmonics of the mesh,
``e(v) = (h_1(v)/√λ_1, …, h_k(v)/√λ_k)`` (the commute-time embedding: nearby and well-connected
vertices land close together), the embedded points are clustered by area-weighted k-means
(k-means++ start, a few restarts, all driven by one seeded generator, so a seed gives one answer),
and each cluster is made connected on the surface: a cluster's pieces other than its largest are
handed to the neighbouring patches that surround them. Patches are numbered by their lowest vertex
index, so the numbering does not depend on the order k-means found them in.

This module also owns the mesh's vertex graph helpers (:func:`vertex_graph`,
:func:`connected_parts`) which the labeller reuses.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sparse
from scipy.sparse.csgraph import connected_components

from allorules.errors import SegmentationError
from allorules.mesh.geometry import vertex_areas
from allorules.mesh.topology import vertex_graph
from allorules.spectral.eigen import few_smallest_eigenpairs
from allorules.spectral.laplacian import cotangent_laplacian

DEFAULT_PATCH_COUNT = 24
KMEANS_RESTARTS = 4
KMEANS_ITERATIONS = 100


def spectral_patches(vertices: np.ndarray, faces: np.ndarray, count: int = DEFAULT_PATCH_COUNT, *, seed: int = 0) -> np.ndarray:
    """Per-vertex patch ids 0 … count−1; every patch is one connected piece of surface.

    Deterministic for a given mesh, ``count`` and ``seed``.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    n = len(vertices)
    count = int(count)
    if count < 1:
        raise SegmentationError(f"--patches must be at least 1, got {count}")
    if count > n // 10:
        raise SegmentationError(f"{count} patches is too many for a mesh of {n} vertices; ask for at most {max(1, n // 10)}")
    graph = vertex_graph(vertices, faces)
    part_count, _ = connected_components(graph, directed=False)
    if part_count > 1:
        raise SegmentationError(
            f"the mesh has {part_count} separate parts; prepare it first (allorules.mesh.repair keeps the largest part)"
        )
    mass = vertex_areas(vertices, faces)
    if count == 1:
        return np.zeros(n, dtype=np.int64)
    eigenvalues, vectors = few_smallest_eigenpairs(cotangent_laplacian(vertices, faces), mass, min(count + 1, n - 1))
    eigenvalues, vectors = eigenvalues[1:], vectors[:, 1:]
    # Commute-time embedding: h_i / sqrt(λ_i), i ≥ 1 (the constant h_0 carries no position).
    embedding = vectors / np.sqrt(np.maximum(eigenvalues, 1e-12 * eigenvalues.max()))
    rng = np.random.default_rng(seed)
    clusters = _weighted_kmeans(embedding, mass, count, rng)
    patches = _make_connected(clusters, graph, mass)
    while len(np.unique(patches)) < count:  # an empty cluster: split the largest patch in two
        areas = np.bincount(patches, weights=mass)
        largest = int(np.argmax(areas))
        members = np.flatnonzero(patches == largest)
        halves = _weighted_kmeans(embedding[members], mass[members], 2, rng)
        if len(np.unique(halves)) < 2:
            break
        patches[members[halves == 1]] = patches.max() + 1
        patches = _make_connected(patches, graph, mass)
    return _renumber(patches)


def _weighted_kmeans(points: np.ndarray, weights: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """Area-weighted k-means (Lloyd) from k-means++ starts; the best of a few restarts."""
    best, best_inertia = None, np.inf
    for _ in range(KMEANS_RESTARTS):
        centres = _kmeans_plus_plus(points, weights, count, rng)
        assignment = np.zeros(len(points), dtype=np.int64)
        for iteration in range(KMEANS_ITERATIONS):
            distances = ((points[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
            new_assignment = np.argmin(distances, axis=1)
            if iteration > 0 and np.array_equal(new_assignment, assignment):
                break
            assignment = new_assignment
            for k in range(count):
                members = assignment == k
                if members.any():
                    centres[k] = np.average(points[members], axis=0, weights=weights[members])
        inertia = float(np.sum(weights * distances[np.arange(len(points)), assignment]))
        if inertia < best_inertia:
            best, best_inertia = assignment.copy(), inertia
    return best


def _kmeans_plus_plus(points: np.ndarray, weights: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    probability = weights / weights.sum()
    centres = [points[rng.choice(len(points), p=probability)]]
    nearest = ((points - centres[0]) ** 2).sum(axis=1)
    for _ in range(1, count):
        score = weights * nearest
        total = score.sum()
        index = rng.choice(len(points), p=score / total) if total > 0 else rng.integers(len(points))
        centres.append(points[index])
        nearest = np.minimum(nearest, ((points - points[index]) ** 2).sum(axis=1))
    return np.array(centres, dtype=float)


def _make_connected(labels: np.ndarray, graph: sparse.csr_matrix, mass: np.ndarray) -> np.ndarray:
    """Keep each label's largest connected piece; grow the neighbours into the other pieces."""
    labels = labels.copy()
    rows, cols = graph.nonzero()
    same = labels[rows] == labels[cols]
    inside = sparse.coo_matrix((np.ones(int(same.sum())), (rows[same], cols[same])), shape=graph.shape).tocsr()
    _, pieces = connected_components(inside, directed=False)
    piece_area = np.bincount(pieces, weights=mass)
    keep = np.zeros(len(piece_area), dtype=bool)
    for label in np.unique(labels):
        label_pieces = np.unique(pieces[labels == label])
        keep[label_pieces[np.argmax(piece_area[label_pieces])]] = True
    labels[~keep[pieces]] = -1
    # Grow: an unassigned vertex takes the most common label among its assigned neighbours.
    adjacency = sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=graph.shape)
    while (labels < 0).any():
        pending = np.flatnonzero(labels < 0)
        sub = adjacency[pending]
        neighbour_labels = labels[sub.indices]
        owner = np.repeat(np.arange(len(pending)), np.diff(sub.indptr))
        ok = neighbour_labels >= 0
        if not ok.any():
            raise SegmentationError("patches could not be made connected: the mesh has separate parts")
        votes = sparse.coo_matrix((np.ones(int(ok.sum())), (owner[ok], neighbour_labels[ok])),
                                  shape=(len(pending), labels.max() + 1)).toarray()
        has_vote = votes.sum(axis=1) > 0
        labels[pending[has_vote]] = np.argmax(votes[has_vote], axis=1)
    return labels


def _renumber(labels: np.ndarray) -> np.ndarray:
    """Number patches 0 … k−1 in order of their lowest vertex index."""
    unique, first = np.unique(labels, return_index=True)
    lookup = np.zeros(unique.max() + 1, dtype=np.int64)
    lookup[unique[np.argsort(first)]] = np.arange(len(unique))
    return lookup[labels]
