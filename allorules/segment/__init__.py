"""Segmentation (paper §3.2, METHOD §7): which region each vertex belongs to.

``labeller`` (the automatic quadruped labeller), ``patches`` (spectral over-segmentation into
numbered patches), ``labels_io`` (labels JSON, Princeton ``.seg``, merge files), ``regions``
(the region names and where an unlisted region goes).
"""
