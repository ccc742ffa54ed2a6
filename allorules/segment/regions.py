"""Region names, and where a region nobody asked for goes.

The six regions of a quadruped that the paper's rules talk about are :data:`QUADRUPED_REGIONS`
(head, neck, chest = upper torso, abdomen = lower torso, forelimbs, hindlimbs). A segmenter may
find more (tail, ears, horns, trunk, ...). A run keeps every region its ruleset names; any other
region joins the neighbour it grows from (:data:`NEIGHBOUR_REGION`, :func:`fold_regions`): a
**tail** the **abdomen** (it grows from the rump, which is lower torso); ears, horns, antlers and
a trunk the **head**; a mane the **neck**.
"""
from __future__ import annotations

import numpy as np

from allorules.body import UNLABELLED, Body

QUADRUPED_REGIONS = ("head", "neck", "chest", "abdomen", "forelimbs", "hindlimbs")

# Where regions outside the ones a run keeps go: the neighbour that carries them.
NEIGHBOUR_REGION = {"tail": "abdomen", "ears": "head", "ear": "head", "horns": "head", "horn": "head",
                    "trunk": "head", "antlers": "head", "mane": "neck"}


def fold_regions(body: Body, keep: tuple[str, ...] = QUADRUPED_REGIONS) -> Body:
    """The body with every region not in ``keep`` joined to its neighbour (:data:`NEIGHBOUR_REGION`)
    when that neighbour is kept; other regions stay as they are. Kept regions come first, in
    ``keep``'s order; the labelling is kept."""
    if body.labels is None:
        raise ValueError("the body has no labels; segment it first")
    target = {}
    for name in body.region_names:
        neighbour = NEIGHBOUR_REGION.get(name)
        target[name] = neighbour if name not in keep and neighbour in keep and neighbour in body.region_names else name
    names = tuple(name for name in keep if name in target.values()) + tuple(
        dict.fromkeys(name for name in target.values() if name not in keep))
    lookup = np.full(len(body.region_names) + 1, UNLABELLED, dtype=np.int64)   # last slot: unlabelled
    for index, name in enumerate(body.region_names):
        lookup[index] = names.index(target[name])
    labels = lookup[np.where(body.labels >= 0, body.labels, len(body.region_names))]
    return body.with_labels(labels, names)


def patch_body(body: Body, patches: np.ndarray) -> Body:
    """The body with its patches as regions named ``patch0`` … (for labels files and pictures)."""
    patches = np.asarray(patches, dtype=np.int64)
    names = tuple(f"patch{i}" for i in range(int(patches.max()) + 1))
    return body.with_labels(patches, names)
