"""Particle-set primitives for Monte Carlo localization: resampling, KLD sample size, clusters.

* :func:`low_variance_resample`: Thrun, Burgard & Fox, *Probabilistic
  Robotics*, table 4.4 (systematic resampling). O(N + M).
* :func:`kld_sample_limit` / :func:`kld_particle_count`: Fox, "Adapting the
  sample size in particle filters through KLD-sampling" (IJRR 2003), with
  nav2_amcl's conventions (``pf.c pf_resample_limit``, ``pf_kdtree`` bins of
  0.5 m x 0.5 m x 10 degrees), except that one occupied bin gives
  ``min_particles`` (nav2: ``max_particles``).
* :func:`cluster_particles`: nav2's clusters (``pf_kdtree_cluster``), heading
  bins wrapping around at +-pi.
* :func:`weighted_pose_statistics`: weighted mean (circular for theta) and the
  full 3 x 3 covariance with heading deviations wrapped around the mean.

The bound, and where and why this departs from nav2: docs/mcl.md.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..se2 import angle_difference

__all__ = [
    "KLD_BIN_XY",
    "KLD_BIN_THETA",
    "low_variance_resample",
    "kld_sample_limit",
    "kld_particle_count",
    "pose_bins",
    "cluster_particles",
    "pose_spread",
    "weighted_pose_statistics",
    "densest_neighbourhood_mean",
    "normalize_log_weights",
]

# Histogram bin sizes of nav2_amcl's pf_kdtree [m, m, rad].
KLD_BIN_XY = 0.5
KLD_BIN_THETA = math.radians(10.0)
_THETA_BINS = int(round(2.0 * math.pi / KLD_BIN_THETA))  # 36
# Histograms of more cells than this are clustered over their occupied bins only (16 MB of labels at most).
_DENSE_CELLS_MAX = 4_000_000
_NEIGHBOURS = np.array([(dx, dy, dt) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dt in (-1, 0, 1)
                        if (dx, dy, dt) != (0, 0, 0)], dtype=np.int64)  # the 26-neighbourhood, as ndimage's


def normalize_log_weights(log_weights: ArrayLike) -> NDArray[np.float64]:
    """Normalised weights ``(N,)`` from log-weights (shifted by the maximum to avoid underflow).

    Non-finite log-weights get weight 0; if none is finite the weights are uniform.
    """
    log_w = np.asarray(log_weights, dtype=np.float64)
    finite = np.isfinite(log_w)
    if not finite.any():
        return np.full(log_w.shape, 1.0 / max(log_w.size, 1))
    shifted = np.where(finite, log_w - log_w[finite].max(), -np.inf)
    weights = np.exp(shifted)
    return weights / weights.sum()


def low_variance_resample(weights: ArrayLike, count: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """Indices ``(count,)`` drawn by systematic (low-variance) resampling of normalised ``weights``."""
    weights_arr = np.asarray(weights, dtype=np.float64)
    if count <= 0:
        return np.zeros(0, dtype=np.int64)
    cumulative = np.cumsum(weights_arr)
    cumulative /= cumulative[-1]
    pointers = (rng.uniform(0.0, 1.0) + np.arange(count)) / count
    indices = np.searchsorted(cumulative, pointers, side="right")
    return np.minimum(indices, weights_arr.size - 1).astype(np.int64)


def kld_sample_limit(
    bins: ArrayLike, *, pf_err: float, pf_z: float, min_count: int, max_count: int
) -> NDArray[np.int64]:
    """KLD-sampling bound (Fox 2003, eq. 11) for ``bins`` occupied histogram bins, clipped to the limits."""
    k = np.asarray(bins, dtype=np.float64)
    safe = np.maximum(k - 1.0, 1.0)
    b = 2.0 / (9.0 * safe)
    x = 1.0 - b + np.sqrt(b) * pf_z
    n = np.ceil(safe / (2.0 * pf_err) * x**3)
    n = np.where(k <= 1.0, min_count, n)
    return np.clip(n, min_count, max_count).astype(np.int64)


def pose_bins(poses: ArrayLike) -> NDArray[np.int64]:
    """Integer bin coordinates ``(N, 3)`` of poses in nav2's KLD histogram (heading wrapped)."""
    poses_arr = np.asarray(poses, dtype=np.float64)
    out = np.empty((poses_arr.shape[0], 3), dtype=np.int64)
    out[:, 0] = np.floor(poses_arr[:, 0] / KLD_BIN_XY)
    out[:, 1] = np.floor(poses_arr[:, 1] / KLD_BIN_XY)
    out[:, 2] = np.mod(np.floor((poses_arr[:, 2] + math.pi) / KLD_BIN_THETA), _THETA_BINS)
    return out


def _bin_codes(bins: NDArray[np.int64]) -> NDArray[np.int64]:
    """One int64 per bin (x, y offset to be non-negative, packed with theta)."""
    shifted = bins[:, :2] - bins[:, :2].min(axis=0)
    span_y = int(shifted[:, 1].max()) + 1 if len(bins) else 1
    return (shifted[:, 0] * span_y + shifted[:, 1]) * _THETA_BINS + bins[:, 2]


def kld_particle_count(
    candidate_poses: ArrayLike, *, pf_err: float, pf_z: float, min_count: int, max_count: int
) -> tuple[int, int, bool]:
    """How many samples KLD-sampling keeps when drawing ``candidate_poses`` in order.

    ``candidate_poses`` ``(M, 3)`` are independent draws from the new belief.
    Sampling stops at the first ``n`` with ``n > limit(k_n)``, where ``k_n`` is
    the number of occupied bins among the first ``n`` draws (nav2
    ``pf_update_resample``).

    Returns:
        ``(count, occupied_bins, stopped)``: the sample size within
        ``[min_count, max_count]``, the bins occupied by the draws used, and
        whether the bound stopped the sampling within the ``M`` draws (if not,
        ``count`` is ``max(M, min_count)`` capped at ``max_count`` and more draws
        may be needed).
    """
    poses_arr = np.asarray(candidate_poses, dtype=np.float64)
    if len(poses_arr) == 0:
        return min_count, 0, False
    codes = _bin_codes(pose_bins(poses_arr))
    _, first_index = np.unique(codes, return_index=True)
    is_first = np.zeros(len(codes), dtype=np.int64)
    is_first[first_index] = 1
    occupied = np.cumsum(is_first)  # bins among the first n = index + 1 draws
    limits = kld_sample_limit(occupied, pf_err=pf_err, pf_z=pf_z, min_count=min_count, max_count=max_count)
    drawn = np.arange(1, len(codes) + 1)
    stop = np.nonzero(drawn > limits)[0]
    if len(stop):
        n = int(drawn[stop[0]])
        return int(np.clip(n, min_count, max_count)), int(occupied[stop[0]]), True
    return int(np.clip(len(codes), min_count, max_count)), int(occupied[-1]), False


def cluster_particles(poses: ArrayLike) -> tuple[NDArray[np.int64], int]:
    """Cluster label ``(N,)`` of each pose (0..C-1) and the number of clusters ``C``.

    Poses in touching histogram bins (26-neighbourhood, heading wrapping around)
    share a cluster.
    """
    poses_arr = np.asarray(poses, dtype=np.float64)
    if len(poses_arr) == 0:
        return np.zeros(0, dtype=np.int64), 0
    bins = pose_bins(poses_arr)
    lo = bins[:, :2].min(axis=0)
    local = bins.copy()
    local[:, :2] -= lo
    size_x = int(local[:, 0].max()) + 1
    size_y = int(local[:, 1].max()) + 1
    if size_x * size_y * _THETA_BINS > _DENSE_CELLS_MAX:
        return _cluster_sparse(local, size_y)
    occupied = np.zeros((size_x, size_y, _THETA_BINS), dtype=bool)
    occupied[local[:, 0], local[:, 1], local[:, 2]] = True
    labels, count = ndimage.label(occupied, structure=np.ones((3, 3, 3), dtype=bool))
    if count > 1:
        # Heading wrap: bins in the last and first heading slices touch.
        last, first = labels[:, :, -1], labels[:, :, 0]
        padded_first = np.pad(first, 1)
        sources, targets = [], []
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                neighbour = padded_first[1 + dx : 1 + dx + size_x, 1 + dy : 1 + dy + size_y]
                both = (last > 0) & (neighbour > 0)
                sources.append(last[both])
                targets.append(neighbour[both])
        src = np.concatenate(sources) - 1
        dst = np.concatenate(targets) - 1
        if len(src):
            graph = coo_matrix((np.ones(len(src)), (src, dst)), shape=(count, count))
            count, merged = connected_components(graph, directed=False)
            lookup = np.concatenate([[-1], merged])
            return lookup[labels[local[:, 0], local[:, 1], local[:, 2]]].astype(np.int64), int(count)
    return (labels[local[:, 0], local[:, 1], local[:, 2]] - 1).astype(np.int64), int(count)


def _cluster_sparse(local: NDArray[np.int64], size_y: int) -> tuple[NDArray[np.int64], int]:
    """:func:`cluster_particles` over the occupied bins only, for a cloud spread too far for a dense histogram
    (an odometry jump of a kilometre, a huge initial covariance): the same clusters, numbered alike."""
    codes = (local[:, 0] * size_y + local[:, 1]) * _THETA_BINS + local[:, 2]
    occupied, which = np.unique(codes, return_inverse=True)  # sorted: the dense labelling's raster order
    count = occupied.size
    theta = occupied % _THETA_BINS
    x, y = np.divmod(occupied // _THETA_BINS, size_y)
    nx = x[:, None] + _NEIGHBOURS[:, 0]
    ny = y[:, None] + _NEIGHBOURS[:, 1]
    neighbour = (nx * size_y + ny) * _THETA_BINS + (theta[:, None] + _NEIGHBOURS[:, 2]) % _THETA_BINS
    at = np.minimum(np.searchsorted(occupied, neighbour), count - 1)
    touching = (nx >= 0) & (ny >= 0) & (ny < size_y) & (occupied[at] == neighbour)
    sources = np.broadcast_to(np.arange(count)[:, None], touching.shape)[touching]
    graph = coo_matrix((np.ones(sources.size), (sources, at[touching])), shape=(count, count))
    clusters, labels = connected_components(graph, directed=False)
    return labels[which].astype(np.int64), int(clusters)


def _normalised(weights: ArrayLike, count: int) -> NDArray[np.float64]:
    """Weights summing to 1 (uniform when they sum to 0 or less)."""
    w = np.asarray(weights, dtype=np.float64)
    total = w.sum()
    return w / total if total > 0.0 else np.full(count, 1.0 / max(count, 1))


def _weighted_mean(x: NDArray[np.float64], y: NDArray[np.float64], theta: NDArray[np.float64], w: NDArray[np.float64]) -> NDArray[np.float64]:
    # Element-wise sums instead of BLAS products: OpenBLAS's thread start-up costs
    # milliseconds on a busy 2-core machine for these thin (N, 3) products.
    return np.array(
        [(w * x).sum(), (w * y).sum(), math.atan2(float((w * np.sin(theta)).sum()), float((w * np.cos(theta)).sum()))]
    )


def weighted_pose_statistics(
    poses: ArrayLike, weights: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Weighted mean pose ``(3,)`` (circular mean heading) and covariance ``(3, 3)``.

    Heading deviations are wrapped around the circular mean before the
    covariance, so a cloud straddling +-pi has a small heading variance.
    Weights summing to 0 count as uniform; no pose gives NaN.
    """
    poses_arr = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if len(poses_arr) == 0:
        return np.full(3, np.nan), np.full((3, 3), np.nan)
    w = _normalised(weights, len(poses_arr))
    x, y, theta = poses_arr[:, 0], poses_arr[:, 1], poses_arr[:, 2]
    mean = _weighted_mean(x, y, theta, w)
    deviations = (x - mean[0], y - mean[1], np.asarray(angle_difference(theta, mean[2])))
    covariance = np.empty((3, 3))
    for i in range(3):
        weighted = w * deviations[i]
        for j in range(i, 3):
            covariance[i, j] = covariance[j, i] = (weighted * deviations[j]).sum()
    return mean, covariance


def pose_spread(covariance: ArrayLike) -> tuple[float, float]:
    """``(std_xy, std_yaw)`` of a pose covariance ``(3, 3)``: the standard deviation along the position's
    widest axis and the heading's."""
    cov = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
    std_xy = math.sqrt(max(float(np.linalg.eigvalsh(cov[:2, :2])[-1]), 0.0))
    return std_xy, math.sqrt(max(float(cov[2, 2]), 0.0))


def densest_neighbourhood_mean(
    poses: ArrayLike, weights: ArrayLike, *, radius: float = 0.5, angle: float = math.radians(25.0)
) -> NDArray[np.float64]:
    """Weighted mean pose ``(3,)`` of the poses within ``radius`` [m] and ``angle`` [rad] of the best-supported one.

    The support of a pose is the weight of its neighbourhood; the mean of that
    neighbourhood is one hypothesis, where the mean of all poses may fall between
    two (IR's tracking estimate; O(N^2), meant for a few hundred poses).
    """
    poses_arr = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if len(poses_arr) == 0:
        return np.full(3, np.nan)
    w = np.asarray(weights, dtype=np.float64)
    if not w.sum() > 0.0:
        w = np.ones(len(poses_arr))
    diff = poses_arr[:, None, :2] - poses_arr[None, :, :2]
    close = (np.hypot(diff[..., 0], diff[..., 1]) <= radius) & (
        np.abs(angle_difference(poses_arr[:, None, 2], poses_arr[None, :, 2])) <= angle
    )
    # Unnormalised weights: normalising first would only add rounding that can flip near-ties.
    support = close.astype(np.float64) @ w
    members = close[int(np.argmax(support))]
    inside = w[members] / w[members].sum()
    chosen = poses_arr[members]
    return _weighted_mean(chosen[:, 0], chosen[:, 1], chosen[:, 2], inside)
