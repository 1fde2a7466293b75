"""Sparse Levenberg-Marquardt for SE(2) pose graphs with Dynamic Covariance Scaling (DCS).

Edge residual: e = Log(z^-1 (x_i^-1 x_j)), the SE(2) logarithm (translation part V^-1 t), as
GTSAM's BetweenFactor<Pose2> defines it; chi2 = e^T Omega e.

DCS (Agarwal et al., ICRA 2013) scales a loop closure's residual by
s = min(1, 2 Phi / (Phi + chi2)); Phi is the free parameter the Phi search tunes. Odometry
edges are never scaled. The optimizer minimises the robust cost whose iteratively reweighted
least-squares weight is s^2, i.e. rho(chi2) = chi2 for chi2 <= Phi and
3 Phi - 4 Phi^2 / (Phi + chi2) above (twice GTSAM's DCS loss, so both have the same minima).
"""
from dataclasses import dataclass

import numpy as np
from numba import njit

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.backend._posegraph import PoseGraph

_SMALL_ANGLE = 1e-5
_SINGULAR = 'the normal equations are singular: no edge constrains the free vertices'


@dataclass(frozen=True)
class OptimizationResult:
    """Outcome of `optimize`.

    `poses (N, 3)` the estimate, `iterations` linear solves done, `chi2` the plain (unscaled)
    sum of edge chi2 at `poses`, `converged` whether a step criterion was met before the
    iteration limit, `cost` the robust cost, `scales (E,)` the final DCS scales s (1 on
    odometry edges and with phi=None).
    """

    poses: np.ndarray
    iterations: int
    chi2: float
    converged: bool
    cost: float
    scales: np.ndarray


class SparseSystem:
    """The sparsity pattern of a graph's normal equations and its fill-reducing ordering, built
    once and reused by every solve of the graph (whatever Phi).

    Maps each of the 36 entries of an edge's four 3x3 Hessian blocks to its slot in a CSC
    matrix over the free (non-fixed) vertices, stored already permuted by SuperLU's minimum
    degree ordering of the pattern: every iteration fills the matrix with one `np.bincount` and
    factors it in that order, instead of a sparse sum of duplicates and a new ordering per
    factorisation (a third of its time).
    """

    def __init__(self, graph: PoseGraph) -> None:
        if graph.edge_count == 0:
            raise ValueError(_SINGULAR)
        fixed = graph.fixed.copy()
        if not fixed.any():
            # The gauge: without a fixed vertex the solution may slide freely.
            fixed[0] = True
        self.free = np.flatnonzero(~fixed)
        column = np.full(graph.vertex_count, -1, dtype=np.int64)
        column[self.free] = np.arange(len(self.free))
        self.size = 3 * len(self.free)
        ends = np.stack([column[graph.edge_from], column[graph.edge_to]], axis=1)  # (E, 2)
        block_row = np.repeat(ends, 2, axis=1)           # (E, 4): ii, ij, ji, jj
        block_col = np.tile(ends, 2)
        offset = np.arange(3)
        rows = (3 * block_row[:, :, None, None] + offset[:, None]).repeat(3, axis=3)
        cols = (3 * block_col[:, :, None, None] + offset[None, :]).repeat(3, axis=2)
        self._keep = ((block_row >= 0) & (block_col >= 0))[:, :, None, None].repeat(
            3, axis=2).repeat(3, axis=3).reshape(-1)
        # The whole diagonal is in the pattern: damping alone holds a vertex without edges.
        diagonal = np.arange(self.size)
        kept_rows = np.r_[rows.reshape(-1)[self._keep], diagonal]
        kept_cols = np.r_[cols.reshape(-1)[self._keep], diagonal]
        # position[k]: where unknown k sits in the factorisation order.
        self._position = _minimum_degree_positions(kept_rows, kept_cols, self.size)
        kept_rows, kept_cols = self._position[kept_rows], self._position[kept_cols]
        # CSC order is by column, then row; equal (column, row) entries share one slot.
        order = np.lexsort((kept_rows, kept_cols))
        new_entry = np.r_[True, (np.diff(kept_cols[order]) != 0) | (np.diff(kept_rows[order]) != 0)]
        slot = np.empty_like(order)
        slot[order] = np.cumsum(new_entry) - 1
        self._slot = slot[:len(slot) - self.size]
        self._indices = kept_rows[order][new_entry]
        entry_columns = kept_cols[order][new_entry]
        self._indptr = np.r_[0, np.cumsum(np.bincount(entry_columns, minlength=self.size))]
        self._diagonal = np.flatnonzero(self._indices == entry_columns)
        # Gradient entry of each edge end's three components, in the factorisation order.
        component = 3 * ends.reshape(-1)[:, None] + offset
        self._gradient_keep = np.repeat(ends.reshape(-1) >= 0, 3)
        self._gradient_slot = self._position[component.reshape(-1)[self._gradient_keep]]

    def hessian(self, blocks: np.ndarray) -> np.ndarray:
        """The normal-equation matrix H of the graph, the edges' blocks summed.

        Parameters
        ----------
        blocks: (E, 4, 3, 3) the Hessian blocks (ii, ij, ji, jj) of each edge.

        Returns
        -------
        (nnz,) CSC data of H over the free vertices, in the factorisation order; the blocks'
        entries on fixed vertices are dropped.
        """
        return np.bincount(self._slot, weights=blocks.reshape(-1)[self._keep],
                           minlength=len(self._indices))

    def gradient(self, edge_gradients: np.ndarray) -> np.ndarray:
        """The gradient g of the normal equations, the edges' gradients summed.

        Parameters
        ----------
        edge_gradients: (E, 2, 3) the gradient of each edge w.r.t. its from and to vertex.

        Returns
        -------
        (3 F,) g over the F free vertices, in the factorisation order.
        """
        return np.bincount(self._gradient_slot,
                           weights=edge_gradients.reshape(-1)[self._gradient_keep],
                           minlength=self.size)

    def max_diagonal(self, hessian: np.ndarray) -> float:
        """The largest diagonal entry of H, the scale of the damping.

        Parameters
        ----------
        hessian: (nnz,) CSC data of H, as `hessian` gives it.

        Returns
        -------
        The entry.
        """
        return float(hessian[self._diagonal].max())

    def solve(self, hessian: np.ndarray, gradient: np.ndarray, damping: float) -> np.ndarray:
        """The Levenberg-Marquardt step -(H + damping I)^-1 g.

        Parameters
        ----------
        hessian: (nnz,) CSC data of H, as `hessian` gives it (not modified).
        gradient: (3 F,) g, as `gradient` gives it.
        damping: added to every diagonal entry of H (absolute).

        Returns
        -------
        (F, 3) step of each free vertex (in the order of `free`), composed onto its pose.
        ValueError when the damped matrix is singular.
        """
        import scipy.sparse.linalg  # where it is used: see _minimum_degree_positions
        data = hessian.copy()
        data[self._diagonal] += damping
        damped = scipy.sparse.csc_matrix((data, self._indices, self._indptr),
                                         shape=(self.size, self.size))
        try:
            factor = scipy.sparse.linalg.splu(damped, permc_spec='NATURAL',
                                              diag_pivot_thresh=0.0,
                                              options={'SymmetricMode': True})
        except RuntimeError:
            raise ValueError(_SINGULAR) from None
        return -factor.solve(gradient)[self._position].reshape(-1, 3)


def _minimum_degree_positions(rows: np.ndarray, cols: np.ndarray, size: int) -> np.ndarray:
    """SuperLU's minimum degree ordering of the symmetric pattern (rows, cols), as the position
    of each unknown. It depends on the pattern only, so a diagonally dominant matrix of that
    pattern (always factorable) yields it."""
    # scipy.sparse (and the scipy.linalg it loads) only where a graph is solved: `check`
    # imports this package through the configuration (TuningSettings) and solves none
    import scipy.sparse.linalg
    pattern = scipy.sparse.csc_matrix((np.full(len(rows), -1.0), (rows, cols)),
                                      shape=(size, size))
    pattern.sum_duplicates()
    pattern.setdiag(2.0 * abs(pattern).sum(axis=0).A1 + 1.0)
    factor = scipy.sparse.linalg.splu(pattern.tocsc(), permc_spec='MMD_AT_PLUS_A',
                                      diag_pivot_thresh=0.0, options={'SymmetricMode': True})
    return np.ascontiguousarray(factor.perm_c, dtype=np.int64)


def dcs_scales(chi2: np.ndarray, phi: float | None) -> np.ndarray:
    """The DCS scales s = min(1, 2 Phi / (Phi + chi2)).

    Parameters
    ----------
    chi2: (E,) chi2 of each edge (the callers scale loop closures only).
    phi: the DCS parameter Phi (> 0); None: plain least squares.

    Returns
    -------
    (E,) scales in [0, 1]; all ones when phi is None.
    """
    chi2 = np.asarray(chi2, dtype=np.float64)
    if phi is None:
        return np.ones_like(chi2)
    with np.errstate(invalid='ignore', divide='ignore'):
        scaled = np.where(chi2 > phi, 2.0 * phi / (phi + chi2), 1.0)
    return np.minimum(1.0, scaled)


def robust_cost(chi2: np.ndarray, loop_closure: np.ndarray, phi: float | None) -> float:
    """The robust cost: chi2 summed over odometry edges, the DCS loss rho(chi2) (see the module
    docstring) over loop closures.

    Parameters
    ----------
    chi2: (E,) chi2 of each edge.
    loop_closure: (E,) True for loop closures (PoseGraph.is_loop_closure).
    phi: the DCS parameter Phi (> 0); None: plain least squares, every edge's chi2.

    Returns
    -------
    The cost, dimensionless like chi2 (inf or nan when a chi2 is).
    """
    if phi is None:
        return float(np.sum(chi2))
    loop_chi2 = chi2[loop_closure]
    rho = np.where(loop_chi2 > phi, 3.0 * phi - 4.0 * phi * phi / (phi + loop_chi2), loop_chi2)
    return float(np.sum(chi2[~loop_closure]) + np.sum(rho))


def edge_residuals(graph: PoseGraph, poses: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Residuals, chi2 and Jacobians of every edge at `poses`.

    Jacobians are taken w.r.t. a right perturbation x <- x Exp(delta) of each pose.

    Parameters
    ----------
    graph: the edges (and the default poses).
    poses: (N, 3) poses to linearise at; None: the graph's.

    Returns
    -------
    (residuals (E, 3), the SE(2) logarithm (m, m, rad); chi2 (E,); Jacobians (E, 3, 3)
    w.r.t. x_i; Jacobians (E, 3, 3) w.r.t. x_j).
    """
    poses = graph.poses if poses is None else np.asarray(poses, dtype=np.float64)
    return _linearize(poses, graph.edge_from, graph.edge_to, graph.measurements,
                      graph.information)


def optimize(graph: PoseGraph, phi: float | None, iterations: int = 50,
             step_tolerance: float = 1e-10, initial_damping: float = 1e-6,
             system: SparseSystem | None = None, relative_tolerance: float = 0.0,
             absolute_tolerance: float = 0.0) -> OptimizationResult:
    """Optimize `graph` from its poses with a DCS parameter.

    Levenberg-Marquardt on the robust cost: each iteration reweights loop closures by s^2 at
    the current estimate, solves the damped normal equations with a sparse LU factorisation in
    symmetric mode (a Cholesky-grade direct solve on the SPD matrix), and keeps the step only
    if the robust cost does not rise. Converged when the largest step component is below
    `step_tolerance`, or when no damping lets the cost fall any more (a cost decrease test
    alone stops too early: along weakly constrained directions the cost is flat to rounding
    while the poses still move by 1e-6). GTSAM's criteria are there when asked for: converged
    also when an accepted step lowers the cost by at most `relative_tolerance` of it or by at
    most `absolute_tolerance` (on this cost, twice GTSAM's error; 0 leaves a criterion off).
    Fixed vertices stay put; if none is fixed the first vertex is held as the gauge.
    A component of the graph without a fixed vertex is held near its initial guess by the
    damping alone.

    Parameters
    ----------
    graph: the graph; its poses are the initial guess.
    phi: the DCS parameter Phi (> 0); None: plain least squares.
    iterations: at most this many iterations, each one reweighting and one accepted step
        (after as many damped solves as it takes).
    step_tolerance: converged once the largest step component (m or rad) is below this.
    initial_damping: the first damping, times the largest diagonal entry of the normal
        equations; it grows tenfold per rejected step and shrinks tenfold per accepted one.
    system: `SparseSystem(graph)`, to share the sparsity analysis across calls; None: a new
        one.
    relative_tolerance: converged once an accepted step lowers the cost by at most this
        fraction of it (0: off).
    absolute_tolerance: converged once an accepted step lowers the cost by at most this
        (0: off).

    Returns
    -------
    The OptimizationResult. ValueError for a non-positive phi or singular normal equations
    (no edge constrains the free vertices).
    """
    if phi is not None and not phi > 0.0:
        raise ValueError(f'phi must be positive, got {phi}')
    system = SparseSystem(graph) if system is None else system
    loop = graph.is_loop_closure
    poses = graph.poses.copy()
    errors, chi2, jac_from, jac_to = edge_residuals(graph, poses)
    cost = robust_cost(chi2, loop, phi)
    damping, converged, iteration = initial_damping, False, 0
    while iteration < iterations and not converged and np.isfinite(cost):
        iteration += 1
        weights = np.where(loop, dcs_scales(chi2, phi) ** 2, 1.0)
        blocks, gradients = _normal_blocks(errors, jac_from, jac_to, graph.information, weights)
        hessian = system.hessian(blocks)
        gradient = system.gradient(gradients)
        scale = system.max_diagonal(hessian)
        while True:
            step = system.solve(hessian, gradient, damping * scale)
            candidate = poses.copy()
            candidate[system.free] = se2.compose(poses[system.free], step)
            new = edge_residuals(graph, candidate)
            new_cost = robust_cost(new[1], loop, phi)
            if new_cost <= cost:
                break
            damping *= 10.0
            if damping > 1e8:
                return _result(graph, poses, chi2, iteration, True, cost, phi)
        decrease = cost - new_cost
        converged = bool(np.abs(step).max() < step_tolerance
                         or (relative_tolerance > 0.0 and decrease <= relative_tolerance * cost)
                         or (absolute_tolerance > 0.0 and decrease <= absolute_tolerance))
        poses, (errors, chi2, jac_from, jac_to), cost = candidate, new, new_cost
        damping = max(damping / 10.0, 1e-12)
    return _result(graph, poses, chi2, iteration, converged, cost, phi)


def _result(graph: PoseGraph, poses: np.ndarray, chi2: np.ndarray, iteration: int,
            converged: bool, cost: float, phi: float | None) -> OptimizationResult:
    scales = np.where(graph.is_loop_closure, dcs_scales(chi2, phi), 1.0)
    return OptimizationResult(poses=poses, iterations=iteration, chi2=float(np.sum(chi2)),
                              converged=converged and np.isfinite(cost), cost=cost,
                              scales=scales)


@njit(cache=True, nogil=True)
def _normal_blocks(errors: np.ndarray, jac_from: np.ndarray, jac_to: np.ndarray,
                   information: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per edge: the four Hessian blocks w A_a^T Omega A_b and gradients w A_a^T Omega e.

    Written out over the 3x3 entries: small matrix products through BLAS cost more in call
    overhead than in arithmetic.
    """
    count = errors.shape[0]
    blocks = np.empty((count, 4, 3, 3))
    gradients = np.empty((count, 2, 3))
    weighted = np.empty((2, 3, 3))  # w Omega A_from, w Omega A_to
    for edge in range(count):
        omega = information[edge]
        weight = weights[edge]
        for side in range(2):
            jacobian = jac_from[edge] if side == 0 else jac_to[edge]
            for row in range(3):
                for col in range(3):
                    total = 0.0
                    for inner in range(3):
                        total += omega[row, inner] * jacobian[inner, col]
                    weighted[side, row, col] = weight * total
        for left in range(2):
            jacobian = jac_from[edge] if left == 0 else jac_to[edge]
            for right in range(2):
                block = blocks[edge, 2 * left + right]
                for row in range(3):
                    for col in range(3):
                        total = 0.0
                        for inner in range(3):
                            total += jacobian[inner, row] * weighted[right, inner, col]
                        block[row, col] = total
            for row in range(3):
                total = 0.0
                for inner in range(3):
                    total += weighted[left, inner, row] * errors[edge, inner]
                gradients[edge, left, row] = total
    return blocks, gradients


@njit(cache=True, nogil=True)
def _linearize(poses: np.ndarray, edge_from: np.ndarray, edge_to: np.ndarray,
               measurements: np.ndarray, information: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    count = edge_from.shape[0]
    errors = np.empty((count, 3))
    chi2 = np.empty(count)
    jac_from = np.zeros((count, 3, 3))
    jac_to = np.zeros((count, 3, 3))
    inverse_jr = np.empty((3, 3))
    adjoint = np.empty((3, 3))
    for edge in range(count):
        xi, xj, z = poses[edge_from[edge]], poses[edge_to[edge]], measurements[edge]
        # T = x_i^-1 x_j, then D = z^-1 T.
        ci, si = np.cos(xi[2]), np.sin(xi[2])
        tx = ci * (xj[0] - xi[0]) + si * (xj[1] - xi[1])
        ty = -si * (xj[0] - xi[0]) + ci * (xj[1] - xi[1])
        tth = xj[2] - xi[2]
        cz, sz = np.cos(z[2]), np.sin(z[2])
        dx = cz * (tx - z[0]) + sz * (ty - z[1])
        dy = -sz * (tx - z[0]) + cz * (ty - z[1])
        angle = np.arctan2(np.sin(tth - z[2]), np.cos(tth - z[2]))
        # Log: translation part V(angle)^-1 (dx, dy), V = [[a, -b], [b, a]].
        if abs(angle) < _SMALL_ANGLE:
            a, b = 1.0 - angle * angle / 6.0, angle / 2.0
        else:
            a, b = np.sin(angle) / angle, (1.0 - np.cos(angle)) / angle
        norm = a * a + b * b
        u = (a * dx + b * dy) / norm
        v = (-b * dx + a * dy) / norm
        errors[edge, 0], errors[edge, 1], errors[edge, 2] = u, v, angle
        # Right Jacobian of Exp at e: [[a, b, p], [-b, a, q], [0, 0, 1]].
        if abs(angle) < _SMALL_ANGLE:
            p = -v / 2.0 + u * angle / 6.0
            q = u / 2.0 + v * angle / 6.0
        else:
            cosine, sine = np.cos(angle), np.sin(angle)
            p = (angle * u - v + v * cosine - u * sine) / (angle * angle)
            q = (u + angle * v - u * cosine - v * sine) / (angle * angle)
        # Its inverse: [[A^-1, -A^-1 (p, q)], [0, 1]] with A^-1 = [[a, -b], [b, a]] / norm.
        inv00, inv01, inv10, inv11 = a / norm, -b / norm, b / norm, a / norm
        inverse_jr[0, 0], inverse_jr[0, 1] = inv00, inv01
        inverse_jr[1, 0], inverse_jr[1, 1] = inv10, inv11
        inverse_jr[0, 2] = -(inv00 * p + inv01 * q)
        inverse_jr[1, 2] = -(inv10 * p + inv11 * q)
        inverse_jr[2, 0], inverse_jr[2, 1], inverse_jr[2, 2] = 0.0, 0.0, 1.0
        # Adjoint of T^-1 = x_j^-1 x_i: [[R, (y, -x)], [0, 1]] with R = R(-tth).
        ct, st = np.cos(tth), np.sin(tth)
        inv_x = -ct * tx - st * ty
        inv_y = st * tx - ct * ty
        adjoint[0, 0], adjoint[0, 1], adjoint[0, 2] = ct, st, inv_y
        adjoint[1, 0], adjoint[1, 1], adjoint[1, 2] = -st, ct, -inv_x
        adjoint[2, 0], adjoint[2, 1], adjoint[2, 2] = 0.0, 0.0, 1.0
        # Explicit 3x3 products: BLAS calls per edge would cost more than the arithmetic.
        for row in range(3):
            for col in range(3):
                total = 0.0
                for inner in range(3):
                    total += inverse_jr[row, inner] * adjoint[inner, col]
                jac_from[edge, row, col] = -total
                jac_to[edge, row, col] = inverse_jr[row, col]
        total = 0.0
        for row in range(3):
            for col in range(3):
                total += errors[edge, row] * information[edge, row, col] * errors[edge, col]
        chi2[edge] = total
    return errors, chi2, jac_from, jac_to
