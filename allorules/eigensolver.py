"""Solvers for the smallest eigenpairs of the generalised problem L h = λ D h (METHOD §2).

``smallest_eigenpairs`` is the one entry point: given the cotangent stiffness ``L`` (sparse,
symmetric PSD) and the lumped mass ``D`` (its diagonal), it returns the ``count`` smallest
eigenvalues in ascending order and D-orthonormal eigenvectors (Hᵀ D H = I).

Methods:

- ``"dense"``: LAPACK on the full matrices, for small meshes.
- ``"bands"`` (spectrum slicing, Vallet & Lévy 2008): bands from the bottom of the spectrum
  up. Each band factorises ``L − σD`` once (SuperLU, symmetric ordering, diagonal pivots only);
  the pivots' signs give the inertia of ``L − σD`` (Sylvester's law: the number of negative
  pivots is the number of eigenvalues below σ), so the window between two shifts holds a known
  number of pairs, and a window is accepted only when exactly that many are found: none missed,
  none duplicated, also in clusters of repeated eigenvalues cut by a shift. Inside a band, a
  block Lanczos run on the shift-invert operator ``(L − σD)⁻¹ D`` (small blocks, full
  reorthogonalisation by block Gram–Schmidt, thick restart) finds the pairs nearest σ, D-
  orthogonal to the pairs already found nearby; pairs above σ that converge on the way fill
  the bottom of the next window. Any failed check falls back to ``"eigsh"`` (logged), never to
  a partial basis. Warm start (``initial``): the previous basis's vectors for each window,
  mixed into the band's starting block.
- ``"eigsh"``: scipy's shift-invert Lanczos over the whole range, the reference.

``terminal_progress`` makes a tqdm bar callback when stderr is a terminal (``None`` otherwise).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg
import scipy.sparse as sparse
import scipy.sparse.linalg

log = logging.getLogger(__name__)

DENSE_LIMIT = 2500
BAND_SIZE = 100                   # pairs per band (docs/benchmarks.md)

Progress = Callable[[int, int], None]


def _normalise_signs(vectors: np.ndarray) -> np.ndarray:
    """Deterministic signs: the entry of largest magnitude of each eigenvector is positive."""
    index = np.argmax(np.abs(vectors), axis=0)
    signs = np.sign(vectors[index, np.arange(vectors.shape[1])])
    signs[signs == 0] = 1.0
    return vectors * signs


def terminal_progress(description: str) -> Progress | None:
    """A ``progress(done, total)`` callback drawing a bar of modes found on a terminal, or ``None``
    when nobody would see it (see :func:`allorules.progress.count_bar`)."""
    from .progress import count_bar

    return count_bar(description, unit="modes")


def smallest_eigenpairs(
    stiffness: sparse.spmatrix,
    mass: np.ndarray,
    count: int,
    *,
    initial: np.ndarray | None = None,
    progress: Progress | None = None,
    method: str = "auto",
    band_size: int = BAND_SIZE,
) -> tuple[np.ndarray, np.ndarray]:
    """The ``count`` smallest eigenpairs of ``stiffness h = λ diag(mass) h``.

    ``initial`` (an earlier basis of a nearby mesh with the same connectivity, (n, m)) speeds
    up the solve; ``progress(done, total)`` is called as eigenpairs are accepted. ``method`` is
    ``"auto"`` (dense for small meshes, one Lanczos run for at most 32 pairs, else bands),
    ``"dense"``, ``"bands"`` or ``"eigsh"``.
    Returns ``(eigenvalues, eigenvectors)`` with eigenvalues ascending and
    ``vectors.T @ diag(mass) @ vectors = I``; each eigenvector's largest-magnitude entry is
    positive.
    """
    n = stiffness.shape[0]
    if not 1 <= count <= n:
        raise ValueError(f"count must be between 1 and {n}, got {count}")
    mass = np.asarray(mass, dtype=np.float64)
    if method == "auto":
        # A handful of pairs (a Fiedler vector) is one Lanczos run; many pairs go by bands.
        method = "dense" if n <= DENSE_LIMIT or count >= n // 3 else "eigsh" if count <= 32 else "bands"
    if method == "dense" or count >= n - 1:
        eigenvalues, vectors = scipy.linalg.eigh(
            stiffness.toarray(), np.diag(mass), subset_by_index=[0, count - 1]
        )
    elif method == "eigsh":
        eigenvalues, vectors = _eigsh(stiffness, mass, count)
    elif method == "bands":
        if initial is not None and (initial.ndim != 2 or initial.shape[0] != n):
            initial = None
        try:
            eigenvalues, vectors = _spectrum_slicing(
                stiffness, mass, count, initial=initial, progress=progress, band_size=band_size
            )
        except np.linalg.LinAlgError as error:
            # Never return an incomplete basis: fall back to one Lanczos run over everything.
            log.warning("spectrum slicing failed (%s); using the reference solver", error)
            eigenvalues, vectors = _eigsh(stiffness, mass, count)
    else:
        raise ValueError(f"unknown method {method!r}: use auto, dense, bands or eigsh")
    if progress is not None:
        progress(count, count)
    # Re-normalise in the D-inner product (the solvers already do; this guards round-off).
    norms = np.sqrt(np.einsum("ij,i,ij->j", vectors, mass, vectors))
    vectors /= norms
    return eigenvalues, _normalise_signs(vectors)


def _eigsh(stiffness: sparse.spmatrix, mass: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference: one shift-invert Lanczos run for all ``count`` pairs (scipy/ARPACK)."""
    # Shift slightly below zero so that the factorisation of L − σD is non-singular.
    sigma = -1e-8 * float(stiffness.diagonal().max() / mass.max())
    eigenvalues, vectors = scipy.sparse.linalg.eigsh(
        stiffness.tocsc(), k=count, M=sparse.diags(mass).tocsc(), sigma=sigma, which="LM"
    )
    order = np.argsort(eigenvalues)
    return eigenvalues[order], vectors[:, order]


# --------------------------------------------------------------------------------------------
# Spectrum slicing: bands verified by inertia, a blocked shift-invert Davidson method inside


RESIDUAL_TOLERANCE = 1e-9   # accept a pair when ‖L x − θ D x‖_{D⁻¹} ≤ tol · max(|θ|, λ_floor)
BLOCK_SIZE = 4              # Krylov block: small keeps the polynomial degree high (docs/benchmarks.md)
MAX_ITERATIONS = 2000       # block steps per band; a band that needs more falls back to the reference
MAX_RESTARTS = 3            # thick restarts per band before falling back to the reference
CHECK_EVERY = 24            # columns added between Rayleigh–Ritz checks


@dataclass
class _ShiftedFactor:
    """A factorisation of L − σD: its shift, a solver, and how many eigenvalues lie below σ."""

    shift: float
    solve: Callable[[np.ndarray], np.ndarray]
    below: int


def _factorise(stiffness: sparse.csc_matrix, mass_matrix: sparse.csc_matrix, shift: float,
               nudge: float | None = None) -> _ShiftedFactor:
    """Sparse LU of L − σD with a symmetric ordering and diagonal pivots only, so that
    L − σD = Pᵀ (L̂ diag(d) L̂ᵀ) P and, by Sylvester's law of inertia, the number of negative
    pivots d is the number of eigenvalues of L h = λ D h below σ."""
    scale = abs(shift) + float(stiffness.diagonal().max() / mass_matrix.diagonal().max())
    nudge = 1e-9 * scale if nudge is None else nudge
    for attempt in range(8):
        try:
            factor = scipy.sparse.linalg.splu(
                (stiffness - shift * mass_matrix).tocsc(),
                permc_spec="MMD_AT_PLUS_A",
                diag_pivot_thresh=0.0,
                options={"SymmetricMode": True},
            )
        except RuntimeError:  # exactly singular: σ hit an eigenvalue; nudge it
            shift += nudge * (attempt + 1)
            continue
        if np.array_equal(factor.perm_r, factor.perm_c):
            pivots = np.abs(factor.U.diagonal())
            # No pivoting: a tiny pivot (σ very near an eigenvalue) means element growth and
            # solves too inexact for 1e-9 residuals (measured); move σ a little instead.
            if np.all(np.isfinite(pivots)) and pivots.min() > 1e-9 * pivots.max():
                return _ShiftedFactor(shift, factor.solve, int(np.count_nonzero(factor.U.diagonal() < 0)))
        shift += nudge * (attempt + 1)
    raise np.linalg.LinAlgError(f"could not factorise L - sigma D near sigma={shift:g}")


def _orthonormalise(block: np.ndarray, against: list[np.ndarray], mass: np.ndarray,
                    drop: float = 1e-8) -> np.ndarray:
    """D-orthonormal columns spanning the part of ``block`` D-orthogonal to every (D-orthonormal)
    basis in ``against``: two passes of block classical Gram–Schmidt, each followed by SVQB
    (eigen-decomposition of the block's Gram matrix). Directions that (nearly) vanish — shorter
    than ``drop`` of their length after the projection — are dropped. Level-3 BLAS throughout."""
    lengths = np.sqrt(np.einsum("ij,i,ij->j", block, mass, block))
    block = block[:, lengths > 0] / lengths[lengths > 0]
    for _ in range(2):
        for basis in against:
            if basis.shape[1] and block.shape[1]:
                block = block - basis @ (basis.T @ (mass[:, None] * block))
        if not block.shape[1]:
            return block
        gram = block.T @ (mass[:, None] * block)
        gram = 0.5 * (gram + gram.T)
        values, rotation = np.linalg.eigh(gram)
        keep = values > drop ** 2
        if not np.any(keep):
            return block[:, :0]
        block = block @ (rotation[:, keep] / np.sqrt(values[keep]))
    return block


class _SliceSolver:
    """State shared by the bands of one spectrum-slicing solve."""

    def __init__(self, stiffness, mass, band_size, block_size, tolerance, initial):
        self.stiffness = stiffness.tocsr()
        self.stiffness_csc = stiffness.tocsc()
        self.mass = mass
        self.inverse_mass = 1.0 / mass
        self.mass_matrix = sparse.diags(mass).tocsc()
        self.n = len(mass)
        self.band_size = band_size
        self.block_size = block_size
        self.max_dimension = 3 * band_size + 2 * block_size
        self.tolerance = tolerance
        self.rng = np.random.default_rng(20080617)
        # Weyl's law for a surface: N(λ) ≈ area · λ / 4π, the first guess of eigenvalue density.
        self.density = mass.sum() / (4.0 * math.pi)
        self.value_floor = 1.0 / self.density        # ~ the spacing of the first eigenvalues
        self.solves = 0
        self.iterations = 0
        self.initial = None
        if initial is not None:
            vectors = np.asarray(initial, dtype=np.float64)
            norms = np.sqrt(np.einsum("ij,i,ij->j", vectors, mass, vectors))
            self.initial = vectors / np.where(norms > 0, norms, 1.0)

    def factorise(self, shift: float) -> _ShiftedFactor:
        # A nudge of ~1 % of the eigenvalue spacing keeps σ off an eigenvalue.
        return _factorise(self.stiffness_csc, self.mass_matrix, shift, nudge=0.013 / self.density)

    def shifted_solve(self, factor: _ShiftedFactor, block: np.ndarray) -> np.ndarray:
        """(L − σD)⁻¹ block, one column at a time (SuperLU's multi-column solve is slower per
        column than single solves, measured: docs/benchmarks.md)."""
        block = np.asfortranarray(block)
        out = np.empty_like(block, order="F")
        for column in range(block.shape[1]):
            out[:, column] = factor.solve(block[:, column])
        self.solves += block.shape[1]
        return out

    def random_block(self, width: int) -> np.ndarray:
        return self.rng.standard_normal((self.n, width))

    def band(self, factor: _ShiftedFactor, lower: float, needed: int, deflate: list[np.ndarray],
             start: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ``needed`` eigenpairs in [lower, σ) that are D-orthogonal to ``deflate``.

        Block Davidson with the shift-invert correction t = (L − σD)⁻¹ r for the residual
        r = L x − θ D x of each unconverged Ritz pair (θ, x) nearest σ, Rayleigh–Ritz on
        (L, D) over the search space V (Vᵀ D V = I, D-orthogonal to ``deflate``), hard locking
        of converged pairs. Pairs above σ that converge on the way are returned too (they start
        the next band's window); so are the unconverged Ritz vectors above σ (its start).
        """
        shift, mass, block_size = factor.shift, self.mass, self.block_size
        V = _orthonormalise(start, deflate, mass) if start.shape[1] else start
        if V.shape[1] < block_size:
            V = np.hstack([V, _orthonormalise(self.random_block(block_size - V.shape[1]), deflate + [V], mass)])
        LV = self.stiffness @ V
        T = V.T @ LV
        carry = V[:, :0]
        stalled = 0
        for iteration in range(MAX_ITERATIONS):
            self.iterations += 1
            theta, Z = np.linalg.eigh(0.5 * (T + T.T))
            valid = np.flatnonzero(theta >= lower)
            order = valid[np.argsort(np.abs(theta[valid] - shift), kind="stable")]
            check = order[: 2 * block_size]
            X = V @ Z[:, check]
            R = LV @ Z[:, check] - mass[:, None] * X * theta[check]
            residuals = np.sqrt(np.einsum("ij,i,ij->j", R, self.inverse_mass, R))
            converged = residuals <= self.tolerance * np.maximum(np.abs(theta[check]), self.value_floor)
            if np.any(converged):
                locked_values.append(theta[check][converged])
                locked_vectors.append(X[:, converged])
                found_below += int(np.count_nonzero(theta[check][converged] < shift))
                stalled = 0
            else:
                stalled += 1
            if found_below > needed:
                raise np.linalg.LinAlgError(
                    f"{found_below} eigenpairs found in a window of {needed} below sigma={shift:g}")
            # Search space for the next iteration: the unlocked Ritz vectors nearest σ.
            locked = np.zeros(len(theta), dtype=bool)
            locked[check[converged]] = True
            keep = order[~locked[order]]
            if found_below == needed:
                above = keep[theta[keep] > shift][: self.max_dimension // 2]
                carry = V @ Z[:, above]
                break
            keep = keep[: self.max_dimension - block_size]
            pending = np.flatnonzero(~converged)[:block_size]
            corrections = self.shifted_solve(factor, R[:, pending])
            del X, R
            V = V @ Z[:, keep]
            LV = LV @ Z[:, keep]
            theta_keep = theta[keep]
            if stalled >= 8:    # a direction missing from the search space: add fresh ones
                corrections = np.hstack([corrections, self.random_block(4)])
                stalled = 0
            E = _orthonormalise(corrections, deflate + locked_vectors + [V], mass)
            if E.shape[1] == 0:
                E = _orthonormalise(self.random_block(block_size), deflate + locked_vectors + [V], mass)
            LE = self.stiffness @ E
            cross = V.T @ LE
            T = np.block([[np.diag(theta_keep), cross], [cross.T, E.T @ LE]])
            V = np.hstack([V, E])
            LV = np.hstack([LV, LE])
        else:
            raise np.linalg.LinAlgError(f"band at sigma={shift:g} did not converge")
        values = np.concatenate(locked_values) if locked_values else np.empty(0)
        vectors = np.hstack(locked_vectors) if locked_vectors else np.empty((self.n, 0))
        return values, vectors, carry

    def krylov_band(self, factor: _ShiftedFactor, lower: float, needed: int, deflate: list[np.ndarray],
                    start: np.ndarray, above: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ``needed`` eigenpairs in [lower, σ) that are D-orthogonal to ``deflate`` (and at
        least ``above`` converged pairs above σ).

        Block Lanczos on S = (L − σD)⁻¹ D in the D-inner product with full reorthogonalisation
        (block classical Gram–Schmidt twice, level-3 BLAS): V spans the block Krylov space,
        H = Vᵀ D S V is its projection. Ritz pairs (τ, V y) of H give eigenvalues λ = σ + 1/τ;
        the Krylov relation S V = V H + V₊ H₊ bounds ‖S x − τ x‖_D by ‖H₊ y‖ at no cost, and
        a pair counts only after its true residual ‖L x − θ D x‖_{D⁻¹} (θ its Rayleigh quotient)
        passes. Pairs above σ that converge on the way are returned too (they fill the bottom of
        the next band's window), and so are a block of unconverged Ritz vectors above σ (its
        start). When V is full, the run restarts thickly (Krylov–Schur) from the Ritz vectors
        nearest σ.
        """
        shift, mass, block_size = factor.shift, self.mass, self.block_size
        capacity = self.max_dimension
        estimate_tolerance = self.tolerance
        basis = np.empty((self.n, capacity))
        projected = np.zeros((capacity, capacity))
        against = [basis for basis in deflate if basis.shape[1]]

        def begin(block: np.ndarray) -> int:
            block = _orthonormalise(block, against, mass)
            if block.shape[1] < block_size:
                block = np.hstack([block, _orthonormalise(self.random_block(block_size - block.shape[1]),
                                                          against + [block], mass)])
            block = block[:, :capacity // 3]
            basis[:, :block.shape[1]] = block
            projected[:] = 0.0
            return block.shape[1]

        width = begin(start)
        applied = checked = restarts = 0
        for iteration in range(MAX_ITERATIONS):
            self.iterations += 1
            V = basis[:, :width]
            W = self.shifted_solve(factor, mass[:, None] * basis[:, applied:width])
            if not np.all(np.isfinite(W)):
                raise np.linalg.LinAlgError(f"shifted solve at sigma={shift:g} overflowed")
            coefficients = np.zeros((width, width - applied))
            size_before = float(np.sqrt(np.einsum("ij,i,ij->j", W, mass, W)).max())
            for _ in range(2):
                step = V.T @ (mass[:, None] * W)
                W -= V @ step
                coefficients += step
                for other in against:
                    W -= other @ (other.T @ (mass[:, None] * W))
            projected[:width, applied:width] = coefficients
            # The new block: W = Q C by SVQB in the D-inner product; C continues the projection.
            gram = W.T @ (mass[:, None] * W)
            values, rotation = np.linalg.eigh(0.5 * (gram + gram.T))
            # Directions that shrank below 1e-10 of the solves' size are round-off: dropped.
            keep = values > (1e-10 * size_before) ** 2
            new = W @ (rotation[:, keep] / np.sqrt(values[keep]))
            continuation = (rotation[:, keep] * np.sqrt(values[keep])).T
            del W
            columns_before, applied = width, width
            basis[:, width:width + new.shape[1]] = new
            projected[width:width + new.shape[1], applied - coefficients.shape[1]:applied] = continuation
            width += new.shape[1]
            # Full when the next block (no wider than this one) would not fit: the Krylov
            # relation must never be cut.
            full = width + new.shape[1] > capacity or new.shape[1] == 0
            if not full and width - checked < CHECK_EVERY:
                continue
            checked = width
            # Rayleigh–Ritz on the part of the space S has been applied to.
            H = projected[:applied, :applied]
            tau, Y = np.linalg.eigh(0.5 * (H + H.T))
            with np.errstate(divide="ignore"):
                estimates = shift + 1.0 / tau
            bound = np.linalg.norm(projected[applied:width, :applied] @ Y, axis=0) / np.maximum(np.abs(tau), 1e-300)
            candidate = (np.abs(tau) > 0) & (estimates >= lower)
            settled = candidate & (bound <= estimate_tolerance)
            window_settled = int(np.count_nonzero(settled & (estimates < shift)))
            if (window_settled < needed or np.count_nonzero(settled) - window_settled < above) and not full:
                continue
            # Verify the settled pairs by their true residuals.
            chosen = np.flatnonzero(settled)
            X = basis[:, :applied] @ Y[:, chosen]
            LX = self.stiffness @ X
            # Rayleigh–Ritz on (L, D) inside the settled span: S's Ritz vectors of pairs close
            # together near σ can mix at the level of the solves' round-off (measured).
            small = X.T @ LX
            quotients, rotation = np.linalg.eigh(0.5 * (small + small.T))
            X, LX = X @ rotation, LX @ rotation
            residual = LX - mass[:, None] * X * quotients
            residuals = np.sqrt(np.einsum("ij,i,ij->j", residual, self.inverse_mass, residual))
            del LX, residual
            good = (residuals <= self.tolerance * np.maximum(np.abs(quotients), self.value_floor)) & (quotients >= lower)
            log.debug("verify: %d settled, %d good, window good %d, worst window residual %.1e", len(chosen), np.count_nonzero(good), np.count_nonzero(good & (quotients < shift)), np.max((residuals / np.maximum(np.abs(quotients), self.value_floor))[quotients < shift], initial=0))
            window_good = int(np.count_nonzero(good & (quotients < shift)))
            if window_good > needed:
                raise np.linalg.LinAlgError(
                    f"{window_good} eigenpairs found in a window of {needed} below sigma={shift:g}")
            if window_good == needed and np.count_nonzero(good) - window_good >= above:
                values, vectors = quotients[good], X[:, good]
                rest = np.flatnonzero(candidate & ~settled & (estimates > shift))
                rest = rest[np.argsort(estimates[rest])][:block_size]
                carry = basis[:, :applied] @ Y[:, rest]
                break
            if full:
                restarts += 1
                if restarts > MAX_RESTARTS:
                    raise np.linalg.LinAlgError(f"band at sigma={shift:g} did not converge in {MAX_RESTARTS} restarts")
                # Thick restart (Krylov–Schur): keep the Ritz vectors nearest σ and the block not
                # yet multiplied by S; S X = X diag(τ) + V₊ H₊ Y keeps the projection exact.
                keep = np.flatnonzero(candidate)
                keep = keep[np.argsort(np.abs(estimates[keep] - shift), kind="stable")]
                keep = keep[: max(capacity - 2 * (width - applied), 0)]
                pending = basis[:, applied:width].copy()
                tail = projected[applied:width, :applied] @ Y[:, keep]
                if not pending.shape[1]:   # the space was invariant: continue with fresh directions
                    pending = _orthonormalise(self.random_block(block_size), against + [basis[:, :applied]], mass)
                    tail = np.zeros((pending.shape[1], len(keep)))
                kept = len(keep)
                basis[:, :kept] = basis[:, :applied] @ Y[:, keep]
                basis[:, kept:kept + pending.shape[1]] = pending
                projected[:] = 0.0
                projected[:kept, :kept] = np.diag(tau[keep])
                projected[kept:kept + pending.shape[1], :kept] = tail
                applied, width = kept, kept + pending.shape[1]
                checked = applied
                del pending
                log.debug("band at sigma=%g restarted keeping %d Ritz vectors", shift, kept)
                continue
            estimate_tolerance = max(0.1 * estimate_tolerance, 1e-14)
        else:
            raise np.linalg.LinAlgError(f"band at sigma={shift:g} did not converge")
        return values, vectors, carry

    def next_shift(self, lower: float, lower_below: int, pool: np.ndarray, remaining: int) -> float:
        """Where to put the next band's shift. The pairs already converged above ``lower``
        (``pool``, ascending) fill the bottom of its window; the shift goes about half a band
        above them (Weyl's law, with the density observed so far), or, when the pool holds all
        that remain, in the first gap above the last one needed."""
        half = max(self.band_size // 2, 1)
        if not np.isfinite(lower):
            return -0.5 * self.value_floor
        if lower_below > 0 and lower > 0:
            self.density = lower_below / lower     # N(λ) ∝ λ on a surface
        if len(pool) >= remaining:
            for index in range(remaining - 1, len(pool) - 1):
                if pool[index + 1] - pool[index] > 1e-6 * abs(pool[index + 1]):
                    return 0.5 * (pool[index] + pool[index + 1])
            return pool[-1] + 0.5 / self.density
        top = pool[-1] if len(pool) else max(lower, 0.0)
        extra = min(half, remaining - len(pool)) + 2
        return top + extra / self.density


def _spectrum_slicing(
    stiffness: sparse.spmatrix,
    mass: np.ndarray,
    count: int,
    *,
    initial: np.ndarray | None,
    progress: Progress | None,
    band_size: int,
    block_size: int = BLOCK_SIZE,
    tolerance: float = RESIDUAL_TOLERANCE,
) -> tuple[np.ndarray, np.ndarray]:
    """Bands from the bottom of the spectrum up until ``count`` pairs are certified.

    Band j factorises L − σ_j D; its pivots say exactly how many eigenvalues lie below σ_j
    (Sylvester), so the window [σ_{j−1}, σ_j) holds a known number of pairs. Those already
    converged above σ_{j−1} in band j−1 count; the rest are found by a block Davidson run with
    that factorisation, D-orthogonal to every pair found near the window. A window is accepted
    only when its count matches the inertia exactly: no pair missed, none duplicated, also in
    clusters of (nearly) repeated eigenvalues cut by a shift.
    """
    solver = _SliceSolver(stiffness, mass, band_size, block_size, tolerance, initial)
    n = len(mass)
    values_out = np.empty(count)
    vectors_out = np.empty((n, count))
    certified = 0
    lower, lower_below = -np.inf, 0
    pool_values = np.empty(0)
    pool_vectors = np.empty((n, 0))
    carry = np.empty((n, 0))
    while certified < count:
        remaining = count - certified
        shift = solver.next_shift(lower, lower_below, pool_values, remaining)
        factor = solver.factorise(shift)
        shift = factor.shift
        in_window = pool_values < shift
        needed = factor.below - lower_below - int(np.count_nonzero(in_window))
        if needed < 0:
            raise np.linalg.LinAlgError(f"{factor.below} eigenvalues below sigma={shift:g}, more found")
        # Deflate against every pair found within one window's width below: far ones are damped
        # by the shift-invert and, being below the window, never accepted again.
        reach = lower - (shift - lower) if np.isfinite(lower) else -np.inf
        first = int(np.searchsorted(values_out[:certified], reach))
        deflate = [vectors_out[:, first:certified], pool_vectors]
        start = carry
        if solver.initial is not None:
            # Warm start: the previous basis's vectors for this window, mixed into one small
            # block (a wide start block would cost a solve per column per Krylov step).
            warm = solver.initial[:, lower_below + len(pool_values): factor.below + band_size // 2]
            if warm.shape[1]:
                start = np.hstack([warm @ solver.rng.standard_normal((warm.shape[1], block_size)), carry])
        if certified == 0 and not len(pool_values):
            # First band: σ < 0 has nothing below; the run converges the bottom of the spectrum
            # one-sidedly (fastest), and the next band's inertia certifies it.
            values, vectors, carry = solver.krylov_band(factor, lower, 0, deflate, start,
                                                        above=min(count, max(band_size // 2, 1)))
        elif needed:
            values, vectors, carry = solver.krylov_band(factor, lower, needed, deflate, start)
        else:
            values, vectors = np.empty(0), np.empty((n, 0))
        all_values = np.concatenate([pool_values, values])
        all_vectors = np.hstack([pool_vectors, vectors])
        window = np.flatnonzero(all_values < shift)
        window = window[np.argsort(all_values[window], kind="stable")]
        take = min(len(window), count - certified)
        values_out[certified:certified + take] = all_values[window[:take]]
        vectors_out[:, certified:certified + take] = all_vectors[:, window[:take]]
        certified += take
        rest = np.flatnonzero(all_values >= shift)
        rest = rest[np.argsort(all_values[rest], kind="stable")]
        pool_values, pool_vectors = all_values[rest], all_vectors[:, rest]
        del all_vectors
        log.debug("band sigma=%.6g below=%d certified=%d pool=%d solves=%d iterations=%d", shift,
                  factor.below, certified, len(pool_values), solver.solves, solver.iterations)
        lower, lower_below = shift, factor.below
        if progress is not None:
            progress(certified, count)
    return values_out, vectors_out
