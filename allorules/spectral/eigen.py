"""Solvers for the smallest eigenpairs of the generalised problem L h = λ D h (METHOD §2).

``smallest_eigenpairs`` is the one entry point: given the cotangent stiffness ``L`` (sparse,
symmetric PSD) and the lumped mass ``D`` (its diagonal), it returns the ``count`` smallest
eigenvalues in ascending order and D-orthonormal eigenvectors (Hᵀ D H = I).

Methods:

- ``"dense"``: LAPACK on the full matrices, for small meshes.
- ``"bands"`` (spectrum slicing, Vallet & Lévy 2008): the spectrum is cut into consecutive
  bands of ~``band_size`` eigenpairs. Each band factorises ``L − σD`` once (sparse LU, symmetric
  ordering, no off-diagonal pivoting) and runs Lanczos with the shift-invert operator
  ``(L − σD)⁻¹ D`` on it: full re-orthogonalisation, no restart, deflated against the previous
  band, stopped as soon as the band's pairs have converged, every accepted pair checked on
  ``L`` and ``D`` themselves (``_BandSolver.krylov``). The same factorisation gives the inertia of
  ``L − σD`` (Sylvester's law: the number of negative pivots is the number of eigenvalues below
  σ), so every band *knows* how many eigenpairs lie below its shift: a pair Lanczos missed (one
  copy of an exactly repeated eigenvalue, say) is recovered by an ARPACK run deflated against
  what was found, and none is duplicated. Band edges are placed in a wide spectral gap, never inside a
  cluster of (nearly) repeated eigenvalues; the last band is checked by one more inertia count.
  Warm start (``initial``): the previous basis's vectors whose Rayleigh quotients on the new
  mesh fall in a band, summed, start that band's Lanczos run (measured: no faster than cold,
  docs/benchmarks.md).
- ``"eigsh"``: scipy's shift-invert Lanczos over the whole range, the reference.

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
import threadpoolctl

log = logging.getLogger(__name__)

DENSE_LIMIT = 2500
# few_smallest_eigenpairs: dense LAPACK up to this many vertices. A leg of 494 vertices took 0.016 s
# dense and 0.006 s by shift-invert Lanczos on an idle machine; beside another numpy job the dense
# solve slowed to 0.08-0.44 s (BLAS threads contending) while Lanczos stayed at 0.011 s, and the
# parts' fields made 38 % of a whole run so (docs/benchmarks.md).
FEW_DENSE_LIMIT = 200
BAND_BLAS_THREADS = 1
BAND_SIZE = 48                    # pairs a band aims for (docs/benchmarks.md)

Progress = Callable[[int, int], None]


def _row_slabs(rows: int, columns: int) -> range:
    """Starts of ~16 MB slabs of rows, so that whole-basis work needs no basis-sized temporary."""
    return range(0, rows, max(1, (1 << 24) // max(1, 8 * columns)))


def _normalise(vectors: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """In place: unit D-norm columns, with deterministic signs (the entry of largest magnitude of
    each eigenvector positive). Works a slab of rows at a time (peak memory)."""
    rows, columns = vectors.shape
    slabs = _row_slabs(rows, columns)
    step = slabs.step
    squares = np.zeros(columns)
    largest = np.zeros(columns)
    signs = np.ones(columns)
    for start in slabs:
        slab = vectors[start:start + step]
        squares += np.einsum("ij,i,ij->j", slab, mass[start:start + step], slab)
        index = np.argmax(np.abs(slab), axis=0)
        values = slab[index, np.arange(columns)]
        larger = np.abs(values) > largest
        largest[larger] = np.abs(values[larger])
        signs[larger] = np.where(values[larger] < 0, -1.0, 1.0)
    scale = signs / np.sqrt(squares)
    for start in slabs:
        vectors[start:start + step] *= scale
    return vectors


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
    ``"auto"`` (dense for small meshes, else bands),
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
        # Bands even for a handful of pairs: one Lanczos run (eigsh) can miss a copy of a repeated
        # eigenvalue (seen on the icosphere, 20 pairs ending inside a cluster), the bands' inertia
        # count cannot.
        method = "dense" if n <= DENSE_LIMIT or count >= n // 3 else "bands"
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
            # One BLAS thread: the bands' level-2 work is memory-bound, and idle BLAS threads that
            # spin while another process holds the other core made a solve 3× slower (measured,
            # docs/benchmarks.md).
            with threadpoolctl.threadpool_limits(limits=BAND_BLAS_THREADS, user_api="blas"):
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
    return eigenvalues, _normalise(vectors, mass)


def few_smallest_eigenpairs(stiffness: sparse.spmatrix, mass: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """A handful of the smallest eigenpairs (a part's Fiedler vector, the patches' embedding).

    Dense LAPACK up to ``FEW_DENSE_LIMIT`` vertices, else one shift-invert Lanczos run
    (:func:`_eigsh`): for a few pairs the band machinery of :func:`smallest_eigenpairs` costs more
    than it saves. Same conventions: ascending, D-orthonormal, largest-magnitude entry positive.
    """
    n = stiffness.shape[0]
    if not 1 <= count < n:
        raise ValueError(f"count must be between 1 and {n - 1}, got {count}")
    mass = np.asarray(mass, dtype=np.float64)
    if n <= FEW_DENSE_LIMIT:
        eigenvalues, vectors = scipy.linalg.eigh(stiffness.toarray(), np.diag(mass), subset_by_index=[0, count - 1])
    else:
        eigenvalues, vectors = _eigsh(stiffness, mass, count)
    return eigenvalues, _normalise(np.array(vectors, order="C"), mass)


def _eigsh(stiffness: sparse.spmatrix, mass: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """One shift-invert Lanczos run for all ``count`` pairs (scipy/ARPACK): the reference solver,
    and the solver for a few pairs. The start vector is fixed, so the answer is the same on
    every run."""
    # Shift slightly below zero so that the factorisation of L − σD is non-singular (L is PSD
    # with the constant vector in its kernel).
    sigma = -1e-8 * float(stiffness.diagonal().max() / mass.max())
    start = np.sqrt(mass) + np.linspace(0.0, 1.0, len(mass))
    eigenvalues, vectors = scipy.sparse.linalg.eigsh(
        stiffness.tocsc(), k=count, M=sparse.diags(mass).tocsc(), sigma=sigma, which="LM", v0=start
    )
    order = np.argsort(eigenvalues)
    return eigenvalues[order], vectors[:, order]


# --------------------------------------------------------------------------------------------
# Spectrum slicing


@dataclass
class _ShiftedFactor:
    """A factorisation of L − σD: its shift, a solver, and how many eigenvalues lie below σ."""

    shift: float
    solve: Callable[[np.ndarray], np.ndarray]
    below: int


def _factorise(stiffness: sparse.csc_matrix, mass_matrix: sparse.csc_matrix, shift: float) -> _ShiftedFactor:
    """Sparse LU of L − σD with a symmetric ordering and diagonal pivots only, so that
    L − σD = Pᵀ (L̂ diag(d) L̂ᵀ) P and, by Sylvester's law of inertia, the number of negative
    pivots d is the number of eigenvalues of L h = λ D h below σ."""
    scale = abs(shift) + float(stiffness.diagonal().max() / mass_matrix.diagonal().max())
    for attempt in range(6):
        try:
            factor = scipy.sparse.linalg.splu(
                (stiffness - shift * mass_matrix).tocsc(),
                permc_spec="MMD_AT_PLUS_A",
                diag_pivot_thresh=0.0,
                options={"SymmetricMode": True},
            )
        except RuntimeError:  # exactly singular: σ hit an eigenvalue; nudge it
            shift += 1e-9 * scale * (attempt + 1)
            continue
        if np.array_equal(factor.perm_r, factor.perm_c):
            pivots = factor.U.diagonal()
            if np.all(np.isfinite(pivots)) and np.all(pivots != 0):
                return _ShiftedFactor(shift, factor.solve, int(np.count_nonzero(pivots < 0)))
        shift += 1e-9 * scale * (attempt + 1)
    raise np.linalg.LinAlgError(f"could not factorise L - sigma D near sigma={shift:g}")


def _orthonormalise(block: np.ndarray, basis: np.ndarray | None, mass: np.ndarray) -> np.ndarray:
    """D-orthonormalise ``block`` against the D-orthonormal ``basis`` and within itself
    (two passes of block Gram–Schmidt, SVQB: directions that vanish are dropped)."""
    for _ in range(2):
        if basis is not None and basis.shape[1]:
            block = block - basis @ (basis.T @ (mass[:, None] * block))
        lengths = np.sqrt(np.einsum("ij,i,ij->j", block, mass, block))
        block = block[:, lengths > 0] / lengths[lengths > 0]
        gram = block.T @ (mass[:, None] * block)
        gram = 0.5 * (gram + gram.T)
        values, rotation = np.linalg.eigh(gram)
        keep = values > 1e-12 * max(values[-1], np.finfo(float).tiny) if len(values) else values > 0
        if not np.any(keep):
            return block[:, :0]
        block = block @ (rotation[:, keep] / np.sqrt(values[keep]))
    return block


KRYLOV_BLOCK = 1              # columns per block: one factorisation solves a block faster per column
KRYLOV_DIMENSION_FACTOR = 5   # a band's Krylov basis stops at this many times the pairs it wants
ACCEPT_RESIDUAL = 1e-10       # relative pencil residual ‖L y − λ D y‖_{D⁻¹} / λ of a converged Ritz pair
REORTHOGONALISE_DROP = 0.7    # DGKS: orthogonalise twice when a column kept less than this share
BREAKDOWN = 1e-10             # relative length below which a new Krylov direction is rounding noise
SHORT_REMAINDER = 1e-3       # relative length below which a new direction is orthogonalised once more
TRUE_RESIDUAL = 1e-9          # the same, computed on L and D, that an accepted pair must pass


def _orthonormal_with_factor(block: np.ndarray, mass: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``block = Q B`` with Q D-orthonormal (SVQB: Gram matrix eigen-decomposition). Directions
    shorter than ``BREAKDOWN`` × ``scale`` (the length of what they were cancelled from) are
    rounding noise, not new directions: they are dropped, so Q may have fewer columns."""
    gram = block.T @ (mass[:, None] * block)
    gram = 0.5 * (gram + gram.T)
    values, rotation = np.linalg.eigh(gram)
    keep = values > (BREAKDOWN * scale) ** 2
    roots = np.sqrt(values[keep])
    return block @ (rotation[:, keep] / roots), roots[:, None] * rotation[:, keep].T


CLUSTER_GAP = 1e-6     # relative: closer eigenvalues count as one (repeated) eigenvalue
EDGE_GAP = 1e-4        # relative: smallest gap a band edge may be placed in
CUT_FROM = 0.9         # the band edge goes in the widest gap of the run above σ past this share of it
SHIFT_POSITION = 0.75  # a band's shift sits this share of its expected width above its lower edge


def _band_cut(values: np.ndarray, below: int, shift: float) -> tuple[int, float]:
    """Where to end a band: ``(cut, upper)`` accepts ``values[:cut]``, all below ``upper``.

    ``values`` (ascending) are the pairs found nearest σ; the first ``below`` lie under σ and
    are complete (inertia). The last cluster found may continue past what was computed, so it
    is never accepted; the cut goes in the widest relative gap (at least EDGE_GAP) among the last
    ``1 − CUT_FROM`` of the rest, else further down, else at σ itself.
    """
    last = len(values) - 1
    while last > below and values[last] - values[last - 1] <= CLUSTER_GAP * abs(values[last]):
        last -= 1
    # values[last] starts the final cluster: cuts can go at indices below+1 .. last.
    for first in (below + max(1, int(CUT_FROM * (last - below))), below + 1):
        candidates = np.arange(first, last + 1)
        if len(candidates) == 0:
            continue
        gaps = (values[candidates] - values[candidates - 1]) / np.abs(values[candidates])
        best = int(np.argmax(gaps))
        if gaps[best] >= EDGE_GAP:
            cut = int(candidates[best])
            return cut, 0.5 * (values[cut - 1] + values[cut])
    return below, shift


class _BandSolver:
    """State shared by the bands of one spectrum-slicing solve."""

    def __init__(self, stiffness, mass, count, band_size, initial, progress):
        self.stiffness = stiffness.tocsr()
        self.stiffness_csc = stiffness.tocsc()
        self.mass = mass
        self.mass_matrix = sparse.diags(mass).tocsc()
        self.count = count
        self.band_size = band_size
        self.progress = progress
        self.n = len(mass)
        self.rng = np.random.default_rng(20080617)
        # Weyl's law for a surface: N(λ) ≈ area · λ / 4π, the first guess of eigenvalue density.
        self.density = mass.sum() / (4.0 * math.pi)
        self.value_floor = 1.0 / self.density        # ~ the spacing of the first eigenvalues
        self.solves = 0
        self.window = (-np.inf, np.inf)
        self.initial = None
        if initial is not None:
            self._prepare_warm_start(initial)

    def _prepare_warm_start(self, initial: np.ndarray) -> None:
        """Rayleigh quotients of the previous basis's vectors on the new mesh (no copy of it)."""
        vectors = np.asarray(initial, dtype=np.float64)
        self.initial = vectors
        squares = np.zeros(vectors.shape[1])
        energies = np.zeros(vectors.shape[1])
        slabs = _row_slabs(*vectors.shape)
        for start in slabs:        # xᵀ D x and xᵀ L x by slabs of rows: no basis-sized temporary
            rows = slice(start, start + slabs.step)
            squares += np.einsum("ij,i,ij->j", vectors[rows], self.mass[rows], vectors[rows])
            energies += np.einsum("ij,ij->j", vectors[rows], self.stiffness[rows] @ vectors)
        self.initial_norms = np.sqrt(squares)
        self.initial_quotients = energies / squares

    def warm_start(self) -> np.ndarray | None:
        """The previous basis's vectors whose Rayleigh quotients fall in the band's window, summed
        (D-normalised first), or ``None`` if there are none."""
        if self.initial is None:
            return None
        low, high = self.window
        inside = np.flatnonzero((self.initial_quotients >= low) & (self.initial_quotients <= high))
        if not len(inside):
            return None
        return self.initial[:, inside] @ (1.0 / self.initial_norms[inside])

    def deflated_lanczos(self, factor: _ShiftedFactor, k: int, deflate: np.ndarray):
        """The ``k`` eigenpairs nearest σ that are not in the span of ``deflate`` (D-orthonormal
        columns U), ascending: implicitly restarted Lanczos (ARPACK) on P S P with
        P = I − U Uᵀ D, so pairs already found are not found again."""
        k = min(k, self.n - 2 - deflate.shape[1])
        mass_deflate = self.mass[:, None] * deflate

        def solve(y: np.ndarray) -> np.ndarray:  # ARPACK passes y = D x
            self.solves += 1
            z = factor.solve(y - mass_deflate @ (deflate.T @ y))
            return z - deflate @ (mass_deflate.T @ z)

        inverse = scipy.sparse.linalg.LinearOperator((self.n, self.n), matvec=solve, dtype=np.float64)
        start = self.rng.standard_normal(self.n)
        start -= deflate @ (deflate.T @ (self.mass * start))
        values, vectors = scipy.sparse.linalg.eigsh(
            self.stiffness, k=k, M=self.mass_matrix, sigma=factor.shift, which="LM", OPinv=inverse, v0=start,
        )
        order = np.argsort(values)
        return values[order], vectors[:, order]

    def krylov(self, factor: _ShiftedFactor, lower: float, target_below: int, wanted_above: int,
               deflate: np.ndarray | None):
        """Pairs of the band by block Krylov on S = (L − σD)⁻¹ D with full re-orthogonalisation
        and no restart: the converged Ritz pairs in [lower, σ) and the converged ones above σ up
        to the first that is not, ascending. Stops once ``target_below`` pairs below σ and
        ``wanted_above`` above it have converged, or at ``KRYLOV_DIMENSION_FACTOR`` times that many.

        With Q the D-orthonormal Krylov basis, the block Arnoldi relation S Q = Q T + Q₊ B Eᵀ
        holds to rounding (every projection coefficient is kept in T), so a Ritz pair (θ, y = Q s)
        of T has the pencil residual r = L y − λ D y = −(1/θ)(L − σD) Q₊ B s₊ with λ = σ + 1/θ:
        its norm for every pair at once from the small Gram matrix of (L − σD) Q₊, and no Ritz
        vector is formed until accepted. ``deflate`` (D-orthonormal exact eigenvectors: the
        previous band's) is projected out, so the run does not spend itself finding them again.
        """
        mass = self.mass
        n = self.n
        width = min(KRYLOV_BLOCK, max(1, n // 8))
        start = self.rng.standard_normal((n, width))
        previous = self.warm_start()
        if previous is not None:
            # Warm start: the previous basis's vectors in the band, summed, start the run (with
            # noise so that nothing is missed). Measured: about as fast as a cold start
            # (docs/benchmarks.md); a block of them converges slower per column.
            start[:, 0] = previous + 1e-3 * start[:, 0] / math.sqrt(n)
        fixed = deflate if deflate is not None and deflate.shape[1] else None
        limit = max(width, min(KRYLOV_DIMENSION_FACTOR * (target_below + wanted_above), n - (0 if fixed is None else fixed.shape[1]) - 2 * width))
        basis = np.empty((n, limit + width), order="F")   # columns contiguous: cheap leading slices
        projection = np.zeros((limit + width, limit + width))       # T, filled block by block
        block = _orthonormalise(start, fixed, mass)
        size = block.shape[1]
        basis[:, :size] = block
        check_at = max(target_below + wanted_above, 2 * width)
        while True:
            current = basis[:, size - block.shape[1]:size]
            self.solves += block.shape[1]
            image = factor.solve(mass[:, None] * current)                      # W = S Q_j
            scale = float(np.sqrt(np.einsum("ij,i,ij->j", image, mass, image).max()))
            # Full re-orthogonalisation (classical Gram–Schmidt, a second pass when the first
            # cancelled more than REORTHOGONALISE_DROP of a column: Daniel–Gragg–Kaufman–Stewart);
            # every coefficient goes into T.
            recent = slice(max(0, size - 2 * block.shape[1] - 1), size)   # the three-term recurrence first
            coefficients = basis[:, recent].T @ (mass[:, None] * image)
            image -= basis[:, recent] @ coefficients
            projection[recent, size - block.shape[1]:size] += coefficients
            lengths = np.einsum("ij,i,ij->j", image, mass, image)
            for _ in range(2):
                coefficients = basis[:, :size].T @ (mass[:, None] * image)
                image -= basis[:, :size] @ coefficients
                projection[:size, size - block.shape[1]:size] += coefficients
                remaining = np.einsum("ij,i,ij->j", image, mass, image)
                if np.all(remaining > REORTHOGONALISE_DROP ** 2 * lengths):
                    break
                lengths = remaining
            if fixed is not None:
                image -= fixed @ (fixed.T @ (mass[:, None] * image))
            next_block, link = _orthonormal_with_factor(image, mass, scale)     # W − Q C = Q₊ B
            if next_block.shape[1] and np.sqrt(remaining.min()) < SHORT_REMAINDER * scale:
                # Normalising a very short remainder magnifies what is left of the basis in it: one
                # more pass, kept in the books (W − Q C = Q₊ B with C and B both updated).
                coefficients = basis[:, :size].T @ (mass[:, None] * next_block)
                next_block -= basis[:, :size] @ coefficients
                projection[:size, size - block.shape[1]:size] += coefficients @ link
                next_block, again = _orthonormal_with_factor(next_block, mass, 1.0)
                link = again @ link
            grows = next_block.shape[1] > 0 and size + next_block.shape[1] <= limit
            if size >= check_at or not grows:
                check_at = size + max(width, 8, size // 8)
                outcome = self._converged_pairs(factor, lower, target_below, wanted_above, basis[:, :size],
                                                projection[:size, :size], next_block, link, block.shape[1],
                                                final=not grows)
                if outcome is not None:
                    return outcome
            projection[size:size + next_block.shape[1], size - block.shape[1]:size] = link
            basis[:, size:size + next_block.shape[1]] = next_block
            size += next_block.shape[1]
            block = next_block

    def _converged_pairs(self, factor: _ShiftedFactor, lower: float, target_below: int, wanted_above: int,
                         basis: np.ndarray, projection: np.ndarray, next_block: np.ndarray, link: np.ndarray,
                         last_width: int, final: bool = False):
        """Rayleigh–Ritz on T: the converged pairs if the band has what it wants (or ``final``),
        else ``None``. Below σ every converged pair in [lower, σ); above σ the converged ones up
        to the first that is not."""
        thetas, ritz = np.linalg.eigh(0.5 * (projection + projection.T))
        keep = np.abs(thetas) > 1e-300
        thetas, ritz = thetas[keep], ritz[:, keep]
        values = factor.shift + 1.0 / thetas
        if next_block.shape[1]:
            # r_i = −(1/θ_i) (L − σD) Q₊ (B s₊,i), its D⁻¹-norm from the Gram matrix of (L − σD) Q₊.
            tails = link @ ritz[-last_width:, :]
            outer = self.stiffness @ next_block - factor.shift * (self.mass[:, None] * next_block)
            gram = outer.T @ (outer / self.mass[:, None])
            residuals = np.sqrt(np.maximum(np.einsum("ij,ik,kj->j", tails, gram, tails), 0.0)) / np.abs(thetas)
        else:
            residuals = np.zeros(len(values))       # an invariant subspace: every pair is exact
        converged = residuals <= ACCEPT_RESIDUAL * np.maximum(np.abs(values), self.value_floor)
        order = np.argsort(values)
        values, ritz, converged = values[order], ritz[:, order], converged[order]
        below = (values >= lower) & (values < factor.shift) & converged
        above = values >= factor.shift
        first_open = np.flatnonzero(above & ~converged)
        stop = first_open[0] if len(first_open) else len(values)
        above &= np.arange(len(values)) < stop
        if not final and (np.count_nonzero(below) < target_below or np.count_nonzero(above) < wanted_above):
            return None
        chosen = np.flatnonzero(below | above)
        vectors = basis @ ritz[:, chosen]
        # The estimate assumes exact solves; a factorisation near a pole can be a little off, so
        # every pair is checked on L and D themselves. Pairs that fail are dropped: one missing
        # below σ is recovered from the inertia count, and above σ the band stops before it.
        true = self.stiffness @ vectors - self.mass[:, None] * vectors * values[chosen]
        true = np.sqrt(np.einsum("ij,i,ij->j", true, 1.0 / self.mass, true))
        passed = true <= TRUE_RESIDUAL * np.maximum(np.abs(values[chosen]), self.value_floor)
        if not np.all(passed):
            log.debug("band at sigma=%g: %d of %d pairs fail the residual check", factor.shift,
                      np.count_nonzero(~passed), len(passed))
            chosen_above = values[chosen] >= factor.shift
            failed_above = np.flatnonzero(chosen_above & ~passed)
            if len(failed_above):
                passed &= ~chosen_above | (np.arange(len(chosen)) < failed_above[0])
            chosen, vectors = chosen[passed], vectors[:, passed]
        return values[chosen], vectors

    def recover(self, factor: _ShiftedFactor, missing: int, found: list[np.ndarray], lowest: float, spare: int):
        """Pairs below σ and at or above ``lowest`` that the inertia says exist but were not
        found (e.g. one copy of an exactly repeated eigenvalue): Lanczos deflated against
        every vector ``found`` near the band."""
        values_out, vectors_out = [], []
        k = missing + max(8, spare)
        for _ in range(6):
            deflate = _orthonormalise(np.hstack(found + vectors_out), None, self.mass)
            values, vectors = self.deflated_lanczos(factor, k, deflate)
            pick = np.flatnonzero((values < factor.shift) & (values >= lowest))[:missing]
            if len(pick):
                values_out.append(values[pick])
                vectors_out.append(vectors[:, pick])
                missing -= len(pick)
            if missing == 0:
                log.debug("recovered missing pairs at sigma=%g", factor.shift)
                return np.concatenate(values_out), np.hstack(vectors_out)
            k *= 2
        raise np.linalg.LinAlgError(f"{missing} eigenpairs below sigma={factor.shift:g} not found")

    def lanczos_band(self, factor: _ShiftedFactor, lower: float, accepted_below: int, wanted: int,
                     previous: np.ndarray | None, previous_lower: float):
        """A band: the pairs in [lower, σ) (all of them: their number is known from the inertia,
        and pairs missed here or in the previous band's run above its shift are recovered by
        deflation) and the converged run above σ, up to a wide gap below the outermost found."""
        shift = factor.shift
        target_below = factor.below - accepted_below
        values, vectors = self.krylov(factor, lower, target_below, max(wanted - target_below, 8), previous)
        keep = values >= lower
        values, vectors = values[keep], vectors[:, keep]
        below = int(np.count_nonzero(values < shift))
        if below > target_below:
            raise np.linalg.LinAlgError(f"band at sigma={shift:g} found {below} pairs, {target_below} exist")
        if below < target_below:
            found = [vectors] + ([previous] if previous is not None else [])
            extra_values, extra_vectors = self.recover(
                factor, target_below - below, found, previous_lower, spare=len(values) - below)
            values = np.concatenate([extra_values, values])
            vectors = np.hstack([extra_vectors, vectors])
            order = np.argsort(values)
            values, vectors = values[order], vectors[:, order]
            below = int(np.count_nonzero(values < shift))
        # The outermost pairs found above σ may be part of a cluster that continues beyond the
        # window: cut in a wide gap near the top of the run above σ.
        cut, upper = _band_cut(values, below, shift)
        return values[:cut], vectors[:, :cut], upper


class _ColumnStore:
    """The accepted eigenvectors, written once into one array as bands are accepted, so that the
    basis is never held twice (peak memory, docs/benchmarks.md). Fortran order: each vector is
    contiguous, so the previous band's vectors deflate the next band without a copy."""

    def __init__(self, rows: int, capacity: int):
        self.columns = np.empty((rows, capacity), order="F")
        self.used = 0

    def append(self, vectors: np.ndarray) -> np.ndarray:
        """Store ``vectors`` after what is there; returns the stored copy (a view)."""
        width = vectors.shape[1]
        if self.used + width > self.columns.shape[1]:       # a band accepted more than planned
            grown = np.empty((self.columns.shape[0], self.used + width + 64), order="F")
            grown[:, :self.used] = self.columns[:, :self.used]
            self.columns = grown
        self.columns[:, self.used:self.used + width] = vectors
        self.used += width
        return self.columns[:, self.used - width:self.used]

    def ordered(self, order: np.ndarray) -> np.ndarray:
        """Columns ``order`` (distinct indices below ``used``) in that order, moved in place
        along the cycles of the permutation, one column of scratch."""
        order = np.asarray(order, dtype=np.int64)
        unused = np.setdiff1d(np.arange(self.used), order)
        source = np.concatenate([order, unused])          # column j takes column source[j]
        done = np.zeros(self.used, dtype=bool)
        for first in range(self.used):
            if done[first] or source[first] == first:
                done[first] = True
                continue
            saved = self.columns[:, first].copy()
            target = first
            while True:
                done[target] = True
                origin = source[target]
                if origin == first:
                    self.columns[:, target] = saved
                    break
                self.columns[:, target] = self.columns[:, origin]
                target = origin
        return self.columns[:, :len(order)]


def _spectrum_slicing(
    stiffness: sparse.spmatrix,
    mass: np.ndarray,
    count: int,
    *,
    initial: np.ndarray | None,
    progress: Progress | None,
    band_size: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Bands from the bottom of the spectrum up until ``count`` pairs are accepted.

    Band j factorises L − σ_j D with σ_j ``SHIFT_POSITION`` of its expected width above its lower
    edge (the previous band's upper edge), so most of its pairs lie below σ_j, where the inertia
    says exactly how many there are; it accepts those plus the converged run above σ_j, cut in a
    wide spectral gap. The next band's inertia verifies that run; the last one is verified by
    one more inertia count at its upper edge.
    """
    solver = _BandSolver(stiffness, mass, count, band_size, initial, progress)
    n = len(mass)
    values_found: list[np.ndarray] = []
    # The last band's vectors (a view into the store) deflate the next band; only the last is
    # kept, so a store that grows does not keep its old array alive through older views.
    previous_band: np.ndarray | None = None
    store = _ColumnStore(n, count + band_size)
    done = 0
    lower = previous_lower = -np.inf
    band_index = 0
    while done < count:
        remaining = count - done
        wanted = min(band_size, remaining + 4)
        if band_index == 0:
            # σ below 0 (L is only semi-definite): nothing lies below it.
            shift = -0.5 * solver.value_floor
            reach = shift + 1.1 * wanted / solver.density
        else:
            shift = lower + SHIFT_POSITION * wanted / solver.density
            reach = lower + 1.1 * wanted / solver.density
        factor = _factorise(solver.stiffness_csc, solver.mass_matrix, shift)
        solver.window = (lower if np.isfinite(lower) else -np.inf, reach)
        values, vectors, upper = solver.lanczos_band(
            factor, lower, done, wanted, previous_band, previous_lower)
        log.debug("band %d: sigma=%.6g below=%d accepted=%d solves=%d", band_index, shift,
                  factor.below, len(values), solver.solves)
        if len(values) > 4:
            # Observed density over this band sharpens the next shift.
            start = max(lower, 0.0) if np.isfinite(lower) else 0.0
            solver.density = len(values) / max(upper - start, 1e-300)
        values_found.append(values)
        previous_band = store.append(vectors)
        done += len(values)
        previous_lower, lower = lower, upper
        band_index += 1
        if progress is not None:
            progress(min(done, count), count)
    # The last band's run above its shift is verified by the inertia at its upper edge.
    top = _factorise(solver.stiffness_csc, solver.mass_matrix, lower)
    if top.below < done:
        raise np.linalg.LinAlgError(f"{top.below} eigenvalues below {lower:g}, {done} accepted")
    if top.below > done:
        values, vectors = solver.recover(top, top.below - done, [previous_band], previous_lower,
                                         spare=previous_band.shape[1])
        values_found.append(values)
        store.append(vectors)
        done += len(values)
    eigenvalues = np.concatenate(values_found)
    order = np.argsort(eigenvalues, kind="stable")[:count]
    return eigenvalues[order], store.ordered(order)
