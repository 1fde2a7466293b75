"""The statistics of the map-consistency test (Mazuran et al., ICRA 2014, section IV).

Notation of the paper, used in this module only:

- M_ij, n_ij: the pairwise inconsistency of scans i and j (sum of the distances of the end points
  of each scan that fall inside the other's visibility polygon) and the number of such points.
- s: the scale of the half-normal distribution of one inconsistency distance; s_i is the scale
  estimated for scan i from its temporal neighbourhood (eq. 10).
- Psi_ij: the standardized pairwise inconsistency (eq. 5), compared with the normal quantile
  F^-1(1 - alpha) in the one-sided pairwise test (eq. 6).
- nu-hat: the largest number of failed pairwise tests a scan may have at confidence 1 - alpha'
  when each test fails independently with probability p (eqs. 7-8).
"""
import math
from statistics import NormalDist

import numpy as np
from numba import njit

# |X| with X ~ N(0, s^2) has mean HALFNORMAL_MEAN_FACTOR s and standard deviation
# HALFNORMAL_STD_FACTOR s (eq. 3).
HALFNORMAL_MEAN_FACTOR = math.sqrt(2.0 / math.pi)
HALFNORMAL_STD_FACTOR = math.sqrt(1.0 - 2.0 / math.pi)


def normal_quantile(upper_tail: float) -> float:
    """F^-1(1 - upper_tail) of the standard normal distribution.

    Parameters
    ----------
    upper_tail: the probability of the upper tail, in (0, 1) (else ValueError).

    Returns
    -------
    The x with P(X > x) = upper_tail for X ~ N(0, 1).
    """
    if not 0.0 < upper_tail < 1.0:
        raise ValueError(f'a tail probability must be in (0, 1), got {upper_tail}')
    # the standard library's quantile (Wichura's AS241, as scipy's ndtri): scipy.special
    # alone costs a `check` a quarter of a second of imports
    return -NormalDist().inv_cdf(upper_tail)


def chi_square_3_quantile(upper_tail: float) -> float:
    """The x with P(X > x) = upper_tail for X chi-square with 3 degrees of freedom.

    Its survival function has the closed form erfc(sqrt(x / 2)) + sqrt(2 x / pi) exp(-x / 2),
    decreasing in x; bisection finds the quantile to the last bit.

    Parameters
    ----------
    upper_tail: the probability of the upper tail, in (0, 1) (else ValueError).

    Returns
    -------
    The quantile x (> 0).
    """
    if not 0.0 < upper_tail < 1.0:
        raise ValueError(f'a tail probability must be in (0, 1), got {upper_tail}')

    def survival(x: float) -> float:
        return math.erfc(math.sqrt(x / 2.0)) + math.sqrt(2.0 * x / math.pi) * math.exp(-x / 2.0)

    low, high = 0.0, 1.0
    while survival(high) > upper_tail:
        low, high = high, 2.0 * high
    for _ in range(200):
        middle = 0.5 * (low + high)
        if middle in (low, high):
            break
        low, high = (middle, high) if survival(middle) > upper_tail else (low, middle)
    return high


# A covariance whose smallest eigenvalue is below this share of its largest one does not
# determine the correction in every direction (float64 resolves about 1e-16 of a matrix's scale).
COVARIANCE_RCOND = 1e-12


def mahalanobis_squared(delta: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """delta^T C^-1 delta of each vector under its covariance.

    Parameters
    ----------
    delta: (E, D) vectors.
    covariance: (E, D, D) their covariances C (symmetrised before use).

    Returns
    -------
    (E,) the squared Mahalanobis distances; NaN where C does not determine delta in every
    direction: C or delta holds a non-finite number, or C is not symmetric positive definite
    to `COVARIANCE_RCOND` of its largest eigenvalue (a zero matrix from a fit that left no
    residual, a corridor that fixes nothing along its axis). Never raises for such a C, unlike
    a matrix inverse.
    """
    delta = np.asarray(delta, dtype=np.float64)
    covariance = np.asarray(covariance, dtype=np.float64)
    values = np.full(delta.shape[0], np.nan)
    finite = np.isfinite(covariance).all(axis=(1, 2)) & np.isfinite(delta).all(axis=1)
    if not finite.any():
        return values
    symmetric = 0.5 * (covariance[finite] + np.swapaxes(covariance[finite], 1, 2))
    eigenvalues, eigenvectors = np.linalg.eigh(symmetric)
    largest = eigenvalues[:, -1]
    regular = (largest > 0.0) & (eigenvalues[:, 0] > COVARIANCE_RCOND * largest)
    along = np.einsum('eij,ei->ej', eigenvectors, delta[finite])
    with np.errstate(divide='ignore', invalid='ignore'):
        squared = (along * along / eigenvalues).sum(axis=1)
    values[np.flatnonzero(finite)[regular]] = squared[regular]
    return values


@njit(cache=True, error_model='numpy')
def psi(distance_sum: float, point_count: float, scale: float) -> float:
    """Psi_ij = (M_ij - mu n_ij) / (sigma sqrt(n_ij)) with mu, sigma from the scale s (eq. 5).

    Parameters
    ----------
    distance_sum: M_ij, the pair's summed distances in metres.
    point_count: n_ij, the number of its end points inside the other polygon.
    scale: s, the half-normal scale of one distance in metres.

    Returns
    -------
    Psi_ij; NaN for a pair without points: it carries no evidence either way.
    """
    if not point_count > 0.0:
        return np.nan
    mean, deviation = HALFNORMAL_MEAN_FACTOR * scale, HALFNORMAL_STD_FACTOR * scale
    return (distance_sum - mean * point_count) / math.sqrt(deviation * deviation * point_count)


@njit(cache=True)
def _psi_of(distance_sum: np.ndarray, point_count: np.ndarray, scale: np.ndarray) -> np.ndarray:
    out = np.empty(distance_sum.size)
    for index in range(distance_sum.size):
        out[index] = psi(distance_sum[index], point_count[index], scale[index])
    return out


def standardized_inconsistency(distance_sum: np.ndarray, point_count: np.ndarray,
                               scale: np.ndarray | float) -> np.ndarray:
    """psi of every pair.

    Parameters
    ----------
    distance_sum: M_ij of each pair, metres.
    point_count: n_ij of each pair.
    scale: s of each pair (or one for all), metres; the three broadcast together.

    Returns
    -------
    Psi_ij, float64 of the broadcast shape, NaN for pairs without points.
    """
    arrays = np.broadcast_arrays(np.asarray(distance_sum, dtype=np.float64),
                                 np.asarray(point_count, dtype=np.float64),
                                 np.asarray(scale, dtype=np.float64))
    shape = arrays[0].shape
    return _psi_of(*(np.ascontiguousarray(array).ravel() for array in arrays)).reshape(shape)


def scale_bound(distance_sum: np.ndarray, point_count: np.ndarray, alpha: float) -> np.ndarray:
    """The smallest s with which a pair passes the pairwise test at level alpha (eq. 10).

    s >= (M_ij / n_ij) / (sqrt(2/pi) + F^-1(1 - alpha) sqrt((1 - 2/pi) / n_ij)).

    Parameters
    ----------
    distance_sum: M_ij of each pair, metres.
    point_count: n_ij of each pair, of the shape of `distance_sum` (or broadcastable).
    alpha: the level of the pairwise test, in (0, 1).

    Returns
    -------
    The bound of each pair in metres, 0 for pairs without points.
    """
    count = np.asarray(point_count, dtype=np.float64)
    quantile = normal_quantile(alpha)
    with np.errstate(divide='ignore', invalid='ignore'):
        bound = (np.asarray(distance_sum) / count) / (
            HALFNORMAL_MEAN_FACTOR + quantile * HALFNORMAL_STD_FACTOR / np.sqrt(count))
    return np.where(count > 0, bound, 0.0)


@njit(cache=True)
def _log_binomial_pmf(successes: int, trials: int, log_p: float, log_q: float) -> float:
    # eq. 8: exp of this is C(r, i) p^i (1 - p)^(r - i), without overflowing factorials
    return (successes * log_p + (trials - successes) * log_q + math.lgamma(trials + 1.0)
            - math.lgamma(successes + 1.0) - math.lgamma(trials - successes + 1.0))


@njit(cache=True)
def _critical_count(trials: int, log_p: float, log_q: float, log_alpha: float) -> int:
    # Grow the upper tail P(X > nu) downwards in log space and stop before it exceeds alpha'.
    # Adding the smallest terms first keeps the sum accurate. Above mean + 40 sd the binomial
    # tail is below 1e-300, so the sum starts there rather than at r.
    probability = math.exp(log_p)
    spread = math.sqrt(trials * probability * (1.0 - probability))
    critical = min(trials, int(trials * probability + 40.0 * spread) + 10)
    log_tail = -np.inf
    while critical > 0:
        term = _log_binomial_pmf(critical, trials, log_p, log_q)
        high = max(log_tail, term)
        grown = high + math.log(math.exp(log_tail - high) + math.exp(term - high))
        if grown > log_alpha:
            break
        log_tail = grown
        critical -= 1
    return critical


@njit(cache=True)
def _critical_counts(trials: np.ndarray, log_p: float, log_q: float,
                     log_alpha: float) -> np.ndarray:
    out = np.empty(trials.size, dtype=np.int64)
    for index in range(trials.size):
        out[index] = _critical_count(int(trials[index]), log_p, log_q, log_alpha)
    return out


# nu-hat for r = 0, 1, ... per (p, alpha'), grown on demand: the live monitor asks every update.
_CRITICAL_TABLES: dict[tuple[float, float], np.ndarray] = {}


def _critical_table(size: int, probability: float, alpha: float) -> np.ndarray:
    key = (probability, alpha)
    table = _CRITICAL_TABLES.get(key, np.empty(0, dtype=np.int64))
    if table.size < size:
        grown = max(size, 2 * table.size)
        extra = _critical_counts(np.arange(table.size, grown), math.log(probability),
                                 math.log1p(-probability), math.log(alpha))
        table = np.concatenate([table, extra])
        _CRITICAL_TABLES[key] = table
    return table


def binomial_critical_count(trials: np.ndarray, probability: float, alpha: float) -> np.ndarray:
    """nu-hat of eq. 7 for each number of trials r: min nu with P(X > nu) <= alpha', X ~ B(r, p).

    Computed in log space (eq. 8), stable for r in the tens of thousands.

    Parameters
    ----------
    trials: numbers of trials r (pairwise tests of a scan), non-negative integers, any shape.
    probability: p, the chance that one pairwise test fails, in (0, 1).
    alpha: alpha', the level of the binomial test, in (0, 1).

    Returns
    -------
    int64 nu-hat for each r, of the shape of `trials`. Raises ValueError for p or alpha'
    outside (0, 1) or a negative r.
    """
    if not 0.0 < probability < 1.0:
        raise ValueError(f'failure probability must be in (0, 1), got {probability}')
    if not 0.0 < alpha < 1.0:
        raise ValueError(f'alpha must be in (0, 1), got {alpha}')
    trials = np.asarray(trials, dtype=np.int64)
    if np.any(trials < 0):
        raise ValueError('the number of trials must not be negative')
    if trials.size == 0:
        return np.zeros(trials.shape, dtype=np.int64)
    return _critical_table(int(trials.max()) + 1, probability, alpha)[trials]
