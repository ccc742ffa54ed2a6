"""Mesh in: reading files, repairing them into a body, and the geometry and topology every later
stage uses (one home per operation), plus the generated example quadruped.

``load`` (files → trimesh), ``repair`` (``prepare_mesh``: the body and its map back to the
input), ``geometry`` (areas, normals, volume, flipped faces), ``topology`` (edges, adjacency,
connected parts, boundaries, hole caps), ``decimate``, ``quadruped`` (the generated animal that
knows its truth).
"""
