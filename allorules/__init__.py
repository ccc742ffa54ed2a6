"""allorules: scale creature meshes the way biology scales animals.

The public API is gathered in :mod:`allorules.api`; the modules, one per concept, are:
``preparation`` (mesh in), ``laplacian``/``eigensolver``/``basis`` (the harmonic basis),
``spectrum`` (Table 1 statistics), ``quadruped`` (the generated example animal),
``measures``, ``segmentation``, ``rules`` and ``plugins`` (the rules engine), ``scaling``
(the spectral power laws), ``solver`` (the nlopt energy), and ``cli``.
"""
__version__ = "0.1.0"
