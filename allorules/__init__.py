"""allorules: scale creature meshes the way biology scales animals.

The public Python API is :mod:`allorules.api`. The package reads as the pipeline a mesh goes
through (docs/architecture.md): ``mesh`` (in), ``spectral`` (the harmonic basis), ``segment``
(regions), ``measure``, ``plugins`` and ``rules`` (the rules engine), ``solve``, ``output``,
``runs`` (the run pipeline every front end calls) and ``cli``.
"""
__version__ = "0.1.0"
