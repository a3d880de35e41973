"""Scan-to-map refinement: Gauss-Newton on a bilinearly sampled distance field (PIL, IR).

The end-points of a scan are pulled onto the map's obstacles by minimising their
weighted squared distances to the nearest occupied cell, as in likelihood-field
scan matching (Thrun et al., *Probabilistic Robotics* 6.4; Kohlbrecher et al.,
Hector SLAM, 2011, for the Gauss-Newton step on an interpolated map).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..grid_map import GridMap
from .gauss_newton import solve_symmetric_3x3

__all__ = ["DistanceField", "refine_poses"]

# Residuals whose Gaussian weight falls below this are left out of the normal equations.
_MIN_WEIGHT = 1e-6


class DistanceField:
    """Distance [m] from a point to the nearest occupied cell of a map, sampled bilinearly with its gradient.

    The gradient is the map's central-difference gradient, interpolated like the
    distance (smoother than the derivative of the bilinear patch, which jumps at
    cell borders). Off-map points have no distance (``inf``) and no gradient.

    Args:
        grid_map: the map.
        compact: keep only the map's float32 distance field (4 bytes a cell instead of 24)
            and take the central differences where they are sampled; the same numbers
            (the float32 distances are exact in float64, the differences are
            ``numpy.gradient``'s), for maps too large to hold the gradients.
    """

    def __init__(self, grid_map: GridMap, *, compact: bool = False) -> None:
        self.compact = bool(compact)
        if self.compact:
            self.distance = np.ascontiguousarray(grid_map.distance_field())  # float32, shared with the map's cache
            self.grad_x: NDArray[np.float64] = np.zeros((0, 0))
            self.grad_y: NDArray[np.float64] = np.zeros((0, 0))
        else:
            self.distance = np.ascontiguousarray(grid_map.distance_field(), dtype=np.float64)
            # Along an axis of one cell there is no gradient (np.gradient needs two): zero, and lookup() has no
            # cell pair to interpolate there anyway (off-map).
            gy, gx = (np.gradient(self.distance, grid_map.resolution, axis=axis) if self.distance.shape[axis] > 1
                      else np.zeros_like(self.distance) for axis in (0, 1))
            self.grad_x = np.ascontiguousarray(gx, dtype=np.float64)
            self.grad_y = np.ascontiguousarray(gy, dtype=np.float64)
        self.resolution = float(grid_map.resolution)
        self.origin = np.asarray(grid_map.origin, dtype=np.float64)

    @property
    def nbytes(self) -> int:
        return int(self.distance.nbytes + self.grad_x.nbytes + self.grad_y.nbytes)

    def lookup(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``(d, dd/dx, dd/dy)`` at world points ``(..., 2)`` [m, -, -]."""
        pts = np.asarray(points, dtype=np.float64)
        flat = np.ascontiguousarray(pts.reshape(-1, 2))
        out = np.empty((3, flat.shape[0]))
        if self.compact:
            _lookup_compact(self.distance, flat, self.origin[0], self.origin[1], self.resolution, out)
        else:
            _lookup(self.distance, self.grad_x, self.grad_y, flat, self.origin[0], self.origin[1], self.resolution, out)
        shape = pts.shape[:-1]
        return out[0].reshape(shape), out[1].reshape(shape), out[2].reshape(shape)


@numba.njit(cache=True, nogil=True)
def _bilinear(shape, x, y, ox, oy, res):
    """Lower-left cell ``(iy, ix)`` of the four cell centres around world point (x, y) and their
    bilinear weights ``w00, w10, w01, w11``; ``iy = -1`` when they are not all on the map."""
    h, w = shape
    fx = (x - ox) / res - 0.5
    fy = (y - oy) / res - 0.5
    ix = int(math.floor(fx))
    iy = int(math.floor(fy))
    if ix < 0 or iy < 0 or ix + 1 >= w or iy + 1 >= h:
        return -1, -1, 0.0, 0.0, 0.0, 0.0
    ax = fx - ix
    ay = fy - iy
    return iy, ix, (1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay


@numba.njit(cache=True, nogil=True)
def _sample(d, gx, gy, x, y, ox, oy, res):
    """Bilinear distance and gradient at world point (x, y); (inf, 0, 0) off the map."""
    iy, ix, w00, w10, w01, w11 = _bilinear(d.shape, x, y, ox, oy, res)
    if iy < 0:
        return math.inf, 0.0, 0.0
    dist = w00 * d[iy, ix] + w10 * d[iy, ix + 1] + w01 * d[iy + 1, ix] + w11 * d[iy + 1, ix + 1]
    dx = w00 * gx[iy, ix] + w10 * gx[iy, ix + 1] + w01 * gx[iy + 1, ix] + w11 * gx[iy + 1, ix + 1]
    dy = w00 * gy[iy, ix] + w10 * gy[iy, ix + 1] + w01 * gy[iy + 1, ix] + w11 * gy[iy + 1, ix + 1]
    return dist, dx, dy


@numba.njit(cache=True, nogil=True)
def _lookup(d, gx, gy, points, ox, oy, res, out):
    for i in range(points.shape[0]):
        out[0, i], out[1, i], out[2, i] = _sample(d, gx, gy, points[i, 0], points[i, 1], ox, oy, res)


@numba.njit(cache=True, nogil=True)
def _gradient_at(d, iy, ix, res):
    """``numpy.gradient(d, res)`` at one cell, in float64: central differences, one-sided at the border."""
    h, w = d.shape
    if w == 1:  # one cell wide: no gradient along x, as the stored field has it
        gx = 0.0
    elif ix == 0:
        gx = (np.float64(d[iy, 1]) - np.float64(d[iy, 0])) / res
    elif ix == w - 1:
        gx = (np.float64(d[iy, w - 1]) - np.float64(d[iy, w - 2])) / res
    else:
        gx = (np.float64(d[iy, ix + 1]) - np.float64(d[iy, ix - 1])) / (2.0 * res)
    if h == 1:
        gy = 0.0
    elif iy == 0:
        gy = (np.float64(d[1, ix]) - np.float64(d[0, ix])) / res
    elif iy == h - 1:
        gy = (np.float64(d[h - 1, ix]) - np.float64(d[h - 2, ix])) / res
    else:
        gy = (np.float64(d[iy + 1, ix]) - np.float64(d[iy - 1, ix])) / (2.0 * res)
    return gx, gy


@numba.njit(cache=True, nogil=True)
def _sample_compact(d, x, y, ox, oy, res):
    """:func:`_sample` with the gradient taken from ``d`` where it is needed."""
    iy, ix, w00, w10, w01, w11 = _bilinear(d.shape, x, y, ox, oy, res)
    if iy < 0:
        return math.inf, 0.0, 0.0
    d00, d10, d01, d11 = np.float64(d[iy, ix]), np.float64(d[iy, ix + 1]), np.float64(d[iy + 1, ix]), np.float64(d[iy + 1, ix + 1])
    dist = w00 * d00 + w10 * d10 + w01 * d01 + w11 * d11
    h, w = d.shape
    if 1 <= ix and ix + 2 < w and 1 <= iy and iy + 2 < h:
        # away from the border: the central differences of the four cells straight from their 4 x 4 patch
        two_res = 2.0 * res
        dx = (w00 * ((d10 - np.float64(d[iy, ix - 1])) / two_res)
              + w10 * ((np.float64(d[iy, ix + 2]) - d00) / two_res)
              + w01 * ((d11 - np.float64(d[iy + 1, ix - 1])) / two_res)
              + w11 * ((np.float64(d[iy + 1, ix + 2]) - d01) / two_res))
        dy = (w00 * ((d01 - np.float64(d[iy - 1, ix])) / two_res)
              + w10 * ((d11 - np.float64(d[iy - 1, ix + 1])) / two_res)
              + w01 * ((np.float64(d[iy + 2, ix]) - d00) / two_res)
              + w11 * ((np.float64(d[iy + 2, ix + 1]) - d10) / two_res))
        return dist, dx, dy
    gx00, gy00 = _gradient_at(d, iy, ix, res)
    gx10, gy10 = _gradient_at(d, iy, ix + 1, res)
    gx01, gy01 = _gradient_at(d, iy + 1, ix, res)
    gx11, gy11 = _gradient_at(d, iy + 1, ix + 1, res)
    dx = w00 * gx00 + w10 * gx10 + w01 * gx01 + w11 * gx11
    dy = w00 * gy00 + w10 * gy10 + w01 * gy01 + w11 * gy11
    return dist, dx, dy


@numba.njit(cache=True, nogil=True)
def _lookup_compact(d, points, ox, oy, res, out):
    for i in range(points.shape[0]):
        out[0, i], out[1, i], out[2, i] = _sample_compact(d, points[i, 0], points[i, 1], ox, oy, res)


@numba.njit(cache=True, nogil=True)
def _sample_either(d, gx, gy, x, y, ox, oy, res, compact):
    if compact:
        return _sample_compact(d, x, y, ox, oy, res)
    return _sample(d, gx, gy, x, y, ox, oy, res)


@numba.njit(cache=True, nogil=True)
def _refine(d, gx, gy, ox, oy, res, poses, bx, by, iterations, inv_two_sigma2, truncation, max_shift, max_turn, scores,
            compact):
    beams = bx.shape[0]
    for k in range(poses.shape[0]):
        x0, y0, t0 = poses[k, 0], poses[k, 1], poses[k, 2]
        x, y, t = x0, y0, t0
        for _ in range(iterations):
            c, s = math.cos(t), math.sin(t)
            h00 = h01 = h02 = h11 = h12 = h22 = 0.0
            g0 = g1 = g2 = 0.0
            for b in range(beams):
                px = x + c * bx[b] - s * by[b]
                py = y + s * bx[b] + c * by[b]
                dist, dx, dy = _sample_either(d, gx, gy, px, py, ox, oy, res, compact)
                if dist >= truncation:
                    continue
                weight = math.exp(-dist * dist * inv_two_sigma2)
                if weight < _MIN_WEIGHT:
                    continue
                jt = dx * (-s * bx[b] - c * by[b]) + dy * (c * bx[b] - s * by[b])
                h00 += weight * dx * dx
                h01 += weight * dx * dy
                h02 += weight * dx * jt
                h11 += weight * dy * dy
                h12 += weight * dy * jt
                h22 += weight * jt * jt
                g0 += weight * dx * dist
                g1 += weight * dy * dist
                g2 += weight * jt * dist
            # A little damping keeps H invertible when the end-points constrain only some directions.
            damping = 1e-6 * (h00 + h11 + h22) + 1e-12
            h00 += damping
            h11 += damping
            h22 += damping
            solved, sx, sy, st = solve_symmetric_3x3(h00, h01, h02, h11, h12, h22, g0, g1, g2)
            if not solved:
                break
            x += sx
            y += sy
            t += st
            ddx = x - x0
            ddy = y - y0
            norm = math.sqrt(ddx * ddx + ddy * ddy)
            if norm > max_shift:
                x = x0 + ddx * max_shift / norm
                y = y0 + ddy * max_shift / norm
            turn = (t - t0 + math.pi) % (2.0 * math.pi) - math.pi
            if turn > max_turn:
                turn = max_turn
            elif turn < -max_turn:
                turn = -max_turn
            t = t0 + turn
        c, s = math.cos(t), math.sin(t)
        total = 0.0
        for b in range(beams):
            px = x + c * bx[b] - s * by[b]
            py = y + s * bx[b] + c * by[b]
            dist, _, _ = _sample_either(d, gx, gy, px, py, ox, oy, res, compact)
            if dist < truncation:
                total += math.exp(-dist * dist * inv_two_sigma2)
        poses[k, 0] = x
        poses[k, 1] = y
        poses[k, 2] = (t + math.pi) % (2.0 * math.pi) - math.pi
        scores[k] = total / max(beams, 1)


def refine_poses(
    field: DistanceField,
    poses: ArrayLike,
    beam_angles: ArrayLike,
    beam_ranges: ArrayLike,
    *,
    iterations: int,
    max_shift: float,
    sigma: float = math.inf,
    truncation: float = math.inf,
    max_turn: float = math.pi,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Align each pose's end-points with the map (Gauss-Newton on the distance field, one pose at a time).

    Args:
        field: the map's :class:`DistanceField`.
        poses: ``(K, 3)`` starting laser poses [m, m, rad].
        beam_angles, beam_ranges: ``(B,)`` the scan's hits in the laser frame [rad, m].
        iterations: Gauss-Newton iterations.
        max_shift: each pose stays within this distance of where it started [m].
        sigma: residual ``d`` weighted by ``exp(-d^2 / 2 sigma^2)`` (``inf``: weight 1) [m].
        truncation: end-points this far or farther from any obstacle are left out [m].
        max_turn: each pose turns at most this much from where it started [rad].

    Returns:
        refined poses ``(K, 3)`` and their scores, the mean end-point weight
        ``exp(-d^2 / 2 sigma^2)`` (0 from ``truncation`` on and off the map) over the beams, in ``[0, 1]``.
    """
    out = np.array(poses, dtype=np.float64, copy=True).reshape(-1, 3)
    scores = np.zeros(len(out))
    angles = np.asarray(beam_angles, dtype=np.float64)
    ranges = np.asarray(beam_ranges, dtype=np.float64)
    if len(out) == 0 or ranges.size == 0:
        return out, scores
    bx = np.ascontiguousarray(ranges * np.cos(angles))
    by = np.ascontiguousarray(ranges * np.sin(angles))
    inv_two_sigma2 = 0.0 if math.isinf(sigma) else 1.0 / (2.0 * sigma * sigma)
    _refine(
        field.distance, field.grad_x, field.grad_y, float(field.origin[0]), float(field.origin[1]), field.resolution,
        out, bx, by, int(iterations), inv_two_sigma2, float(truncation), float(max_shift), float(max_turn), scores,
        field.compact,
    )
    return out, scores
