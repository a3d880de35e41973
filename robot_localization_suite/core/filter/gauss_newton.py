"""The 3x3 normal-equation solve shared by the scan-to-map refinements (PIL, IR).

Both refine an (x, y, theta) pose by Gauss-Newton on a distance field; each
iteration solves ``H step = -g`` with a symmetric 3x3 ``H``. Cramer's rule in
numba keeps that inside the compiled loop without allocating.
"""

from __future__ import annotations

import numba

__all__ = ["solve_symmetric_3x3"]


@numba.njit(cache=True, nogil=True)
def solve_symmetric_3x3(h00, h01, h02, h11, h12, h22, g0, g1, g2):
    """Step ``s`` with ``H s = -g``; returns ``(ok, s0, s1, s2)``, ``ok`` False when ``H`` is singular."""
    c00 = h11 * h22 - h12 * h12
    c01 = h02 * h12 - h01 * h22
    c02 = h01 * h12 - h02 * h11
    det = h00 * c00 + h01 * c01 + h02 * c02
    if abs(det) < 1e-18:
        return False, 0.0, 0.0, 0.0
    c11 = h00 * h22 - h02 * h02
    c12 = h01 * h02 - h00 * h12
    c22 = h00 * h11 - h01 * h01
    s0 = -(c00 * g0 + c01 * g1 + c02 * g2) / det
    s1 = -(c01 * g0 + c11 * g1 + c12 * g2) / det
    s2 = -(c02 * g0 + c12 * g1 + c22 * g2) / det
    return True, s0, s1, s2
