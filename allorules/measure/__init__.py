"""Measurements (METHOD §3), all used as ratios: ``mass`` (body and region volumes), ``length``
(region skeletons), ``girth`` (heart girth and other cross-sections), ``limbs`` (limb sections and
posture), ``stress`` (peak limb stress σ = M/A and the section it is taken at), with ``sections``
(isocontour loops, skeleton graphs) and ``parts`` (regions as meshes) beneath them.
"""
