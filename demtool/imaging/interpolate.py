"""Gap filling of gridded data with the spring metaphor (D'Errico's ``inpaint_nans``).

Each missing cell is tied to its four horizontal and vertical neighbours by springs of
equal stiffness; the filled values are those that minimise the total spring energy

    E = sum over springs (i, j) touching a missing cell of (z_i - z_j)^2,

with the measured cells held fixed.  This is method 4 ("springs") of J. D'Errico's
``inpaint_nans`` (MATLAB Central File Exchange #4551, 2004-2012), the interpolator the
Rosetta NavCam study used to densify its sparse DEMs.  The minimiser solves the sparse,
symmetric positive-definite normal equations ``L_uu z_u = -L_uk z_k`` of the graph
Laplacian ``L`` restricted to the unknown cells; only the unknowns are solved for.

Properties (checked by ``tests/test_interpolate.py``):

* measured cells are returned unchanged, bit for bit;
* a linear surface ``z = a x + b y + c`` is reproduced exactly wherever the gap is
  surrounded by measured cells (the discrete Laplacian of a plane is zero).  Gaps that
  touch the grid edge have a free (zero-slope) boundary there, as in D'Errico's method,
  so a plane's values are pulled toward a constant near such an edge;
* the result is bounded by the measured values (discrete maximum principle).

Small systems are solved directly (SuperLU).  Large ones are solved with conjugate
gradients preconditioned by a smoothed-aggregation algebraic multigrid V-cycle built
on 2 × 2 grid blocks, which converges in a few tens of iterations regardless of the
grid size and of how sparse the measured cells are (a 2048 × 2048 grid with half the
cells missing, or a 1024 × 1024 grid with 0.5 % measured, takes seconds).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from demtool.errors import ProcessingError
from demtool.logs import get_logger

log = get_logger(__name__)

#: Unknown counts up to this are solved with a direct sparse factorisation.
DIRECT_SOLVE_MAX_UNKNOWNS = 40_000


def spring_system(values: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray, np.ndarray]:
    """Normal equations of the spring energy for the missing cells of a grid.

    Parameters
    ----------
    values : (H, W) float
        Grid with NaN (or ±inf) marking the cells to fill.

    Returns
    -------
    A : (n, n) scipy.sparse.csr_matrix, float64
        Graph Laplacian restricted to the n unknown cells (row-major order): the
        diagonal holds each unknown's number of in-grid neighbours, −1 couples two
        adjacent unknowns.
    rhs : (n,) float64
        Sum of the measured neighbours' values for each unknown.
    unknown : (H, W) bool
        True where a value is to be filled.
    """
    grid = np.asarray(values, dtype=np.float64)
    height, width = grid.shape
    unknown = ~np.isfinite(grid)
    count = int(unknown.sum())
    index = np.full(grid.shape, -1, dtype=np.int64)
    index[unknown] = np.arange(count)
    measured = np.where(unknown, 0.0, grid)

    degree = np.zeros(grid.shape)
    degree[:, :-1] += 1
    degree[:, 1:] += 1
    degree[:-1, :] += 1
    degree[1:, :] += 1

    rows: list[np.ndarray] = [np.arange(count)]
    cols: list[np.ndarray] = [np.arange(count)]
    data: list[np.ndarray] = [degree[unknown]]
    rhs = np.zeros(count)
    pairs = (((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
             ((slice(None, -1), slice(None)), (slice(1, None), slice(None))))
    for first, second in pairs:
        unknown_a, unknown_b = unknown[first], unknown[second]
        index_a, index_b = index[first], index[second]
        both = unknown_a & unknown_b
        rows += [index_a[both], index_b[both]]
        cols += [index_b[both], index_a[both]]
        data += [np.full(2 * int(both.sum()), -1.0)]
        only_a = unknown_a & ~unknown_b
        rhs += np.bincount(index_a[only_a], weights=measured[second][only_a], minlength=count)
        only_b = unknown_b & ~unknown_a
        rhs += np.bincount(index_b[only_b], weights=measured[first][only_b], minlength=count)
    matrix = sp.csr_matrix((np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))),
                           shape=(count, count))
    return matrix, rhs, unknown


# --------------------------------------------------------------------------------------
# Smoothed-aggregation multigrid preconditioner
# --------------------------------------------------------------------------------------


@dataclass
class _Level:
    A: sp.csr_matrix
    P: sp.csr_matrix | None = None
    inverse_diagonal: np.ndarray | None = None
    relaxation: float = 0.0


def _aggregation_levels(A: sp.csr_matrix, rows: np.ndarray, cols: np.ndarray,
                        coarsest: int) -> list[_Level]:
    """Hierarchy of smoothed-aggregation levels with 2 × 2 block aggregates."""
    levels: list[_Level] = []
    while A.shape[0] > coarsest:
        diagonal = A.diagonal()
        inverse_diagonal = 1.0 / diagonal
        # Spectral radius of D^-1 A for a Laplacian is at most 2 (Gershgorin).
        relaxation = 2.0 / 3.0
        stride = int(cols.max()) // 2 + 1
        keys = (rows // 2) * stride + (cols // 2)
        unique_keys, aggregate = np.unique(keys, return_inverse=True)
        n_coarse = len(unique_keys)
        if n_coarse >= A.shape[0]:
            break
        tentative = sp.csr_matrix((np.ones(A.shape[0]), (np.arange(A.shape[0]), aggregate)),
                                  shape=(A.shape[0], n_coarse))
        # Prolongation smoothing with omega = 4/3 / rho(D^-1 A) and rho <= 2.
        smoother = sp.identity(A.shape[0], format="csr") - sp.diags(
            (2.0 / 3.0) * inverse_diagonal) @ A
        P = (smoother @ tentative).tocsr()
        levels.append(_Level(A=A, P=P, inverse_diagonal=inverse_diagonal,
                             relaxation=relaxation))
        A = (P.T @ A @ P).tocsr()
        rows, cols = unique_keys // stride, unique_keys % stride
    levels.append(_Level(A=A))
    return levels


def _multigrid_preconditioner(A: sp.csr_matrix, rows: np.ndarray, cols: np.ndarray,
                              coarsest: int = 2_000) -> spla.LinearOperator:
    """Symmetric V-cycle (damped Jacobi, 2 pre- and 2 post-sweeps) as a linear operator."""
    levels = _aggregation_levels(A, rows, cols, coarsest)
    coarse_solver = spla.factorized(levels[-1].A.tocsc())

    def cycle(depth: int, b: np.ndarray) -> np.ndarray:
        level = levels[depth]
        if level.P is None:
            return coarse_solver(b)
        weight = level.relaxation * level.inverse_diagonal
        x = weight * b
        x += weight * (b - level.A @ x)
        residual = b - level.A @ x
        x += level.P @ cycle(depth + 1, level.P.T @ residual)
        x += weight * (b - level.A @ x)
        x += weight * (b - level.A @ x)
        return x

    return spla.LinearOperator(A.shape, matvec=lambda b: cycle(0, np.asarray(b).ravel()),
                               dtype=np.float64)


#: Jacobi-preconditioned CG iterations tried before building the multigrid hierarchy.
JACOBI_ITERATIONS = 60


def _solve_iterative(A: sp.csr_matrix, rhs: np.ndarray, unknown: np.ndarray, *, rtol: float,
                     max_iterations: int) -> np.ndarray:
    """CG on the spring system: cheap Jacobi preconditioning first (enough when the gaps
    are small, e.g. scattered missing cells), multigrid when the gaps are wide."""
    count = len(rhs)
    iterations = 0

    def count_iteration(_: np.ndarray) -> None:
        nonlocal iterations
        iterations += 1

    inverse_diagonal = 1.0 / A.diagonal()
    jacobi = spla.LinearOperator(A.shape, matvec=lambda b: inverse_diagonal * np.ravel(b),
                                 dtype=np.float64)
    solution, info = spla.cg(A, rhs, M=jacobi, rtol=rtol, atol=0.0,
                             maxiter=JACOBI_ITERATIONS, callback=count_iteration)
    if info == 0:
        log.debug("springs: %d unknowns, %d Jacobi-CG iterations", count, iterations)
        return solution
    rows, cols = np.nonzero(unknown)
    preconditioner = _multigrid_preconditioner(A, rows, cols)
    iterations = 0
    solution, info = spla.cg(A, rhs, x0=solution, M=preconditioner, rtol=rtol, atol=0.0,
                             maxiter=max_iterations, callback=count_iteration)
    if info != 0:
        raise ProcessingError(f"spring interpolation did not converge in {max_iterations} "
                              f"iterations ({count} unknowns)")
    log.debug("springs: %d unknowns, %d Jacobi-CG then %d multigrid-CG iterations", count,
              JACOBI_ITERATIONS, iterations)
    return solution


# --------------------------------------------------------------------------------------
# Public interface
# --------------------------------------------------------------------------------------


def inpaint_springs(values: np.ndarray, *, rtol: float = 1e-10, max_iterations: int = 500,
                    direct_max_unknowns: int = DIRECT_SOLVE_MAX_UNKNOWNS) -> np.ndarray:
    """Fill the NaN cells of a grid with D'Errico's spring-metaphor interpolation.

    Each missing cell is connected by unit springs to its horizontal and vertical
    neighbours; the filled values minimise the total spring energy with the measured
    cells fixed (``inpaint_nans`` method 4, D'Errico 2004).  Measured cells are kept
    exactly; a plane is reproduced exactly inside gaps enclosed by measured cells;
    at the grid edge the boundary is free (zero normal slope).

    Parameters
    ----------
    values : (H, W) float
        Grid to fill (any units, e.g. heights in metres); NaN or ±inf mark the gaps.
        Not modified.
    rtol : float
        Relative residual tolerance of the iterative solver (large grids only).
    max_iterations : int
        Iteration limit of the preconditioned conjugate gradients.
    direct_max_unknowns : int
        Up to this many unknowns the system is solved with a direct factorisation.

    Returns
    -------
    (H, W) float64
        The grid with every gap filled; measured cells equal the input.

    Raises
    ------
    ProcessingError
        If no cell is measured (nothing to interpolate from), or the solver fails.
    ValueError
        If ``values`` is not 2-D.

    References
    ----------
    J. D'Errico, "inpaint_nans", MATLAB Central File Exchange 4551 (method 4,
    "spring metaphor").
    """
    grid = np.asarray(values, dtype=np.float64)
    if grid.ndim != 2:
        raise ValueError(f"inpaint_springs expects a 2-D grid, got shape {grid.shape}")
    finite = np.isfinite(grid)
    if not finite.any():
        raise ProcessingError("cannot interpolate a grid with no measured (finite) cell")
    result = grid.copy()
    if finite.all():
        return result
    A, rhs, unknown = spring_system(grid)
    count = len(rhs)
    if count <= direct_max_unknowns:
        solution = spla.spsolve(A.tocsc(), rhs)
    else:
        solution = _solve_iterative(A, rhs, unknown, rtol=rtol, max_iterations=max_iterations)
    result[unknown] = solution
    return result
