"""The frequency domain (METHOD §2): the cotangent Laplacian, every generalised eigen-solve, the
manifold harmonic basis and its cache, the power laws of the paper's Eq. 4-9, the spectrum's
statistics (Table 1) and the 1-D experiments.
"""
