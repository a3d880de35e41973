"""Trajectories out: a run's estimates and the ground truth in TUM format, for evo.

``rls_bench --export-tum DIR`` writes, per mode and bag, ``<localizer>.tum`` (every estimate),
``<localizer>.truth.tum`` (the ground truth at the estimates that ``rmse_xy_m`` counts: from
the first fix on, outside kidnapping recoveries, interpolated as ``core/metrics.py`` does) and
``ground_truth.tum`` (the bag's whole ``/ground_truth``). TUM: ``stamp x y z qx qy qz qw``, one
pose a line, z = 0, the heading as a rotation about z. ``evo_ape tum <localizer>.truth.tum
<localizer>.tum`` (no ``--align``) then gives ``rmse_xy_m``; with evo installed (the ``evo``
extra) the run's fields get ``evo_ape_rmse_m`` from evo's own reader and APE
(``docs/benchmark.md``, "Dask, sweeps, trajectories out").
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...core import metrics

if TYPE_CHECKING:
    from .reference import BagReference
    from .replay import RunRecord

__all__ = ["write_tum", "read_tum", "export_run", "evo_ape_rmse"]


def write_tum(path: Path, stamps: ArrayLike, poses: ArrayLike) -> Path:
    """Write SE(2) poses ``(N, 3)`` (x, y, theta) at ``stamps`` [s] as a TUM file."""
    stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    half = poses[:, 2] / 2.0
    zeros = np.zeros(len(stamps))
    table = np.column_stack([stamps, poses[:, 0], poses[:, 1], zeros, zeros, zeros, np.sin(half), np.cos(half)])
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, table, fmt=["%.9f"] + ["%.9g"] * 7, header="timestamp x y z q_x q_y q_z q_w")
    return path


def read_tum(path: Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Stamps and SE(2) poses (x, y, yaw about z) of a TUM file."""
    table = np.loadtxt(path, comments="#", ndmin=2)
    yaw = 2.0 * np.arctan2(table[:, 6], table[:, 7])
    return table[:, 0], np.column_stack([table[:, 1], table[:, 2], np.arctan2(np.sin(yaw), np.cos(yaw))])


def export_run(out_dir: Path, reference: BagReference, record: RunRecord, series: dict[str, Any], *,
               name: str) -> dict[str, Any]:
    """Write one run's TUM files into ``out_dir``; returns ``{"evo_ape_rmse_m": ...}`` when evo is installed."""
    out_dir = Path(out_dir)
    estimates = write_tum(out_dir / f"{name}.tum", record.stamps, record.poses)
    truth = reference.ground_truth
    if truth is None or not record.stamps.size:
        return {}
    if not (out_dir / "ground_truth.tum").is_file():
        write_tum(out_dir / "ground_truth.tum", truth.stamps, truth.poses)
    correct = np.asarray(series["correct"], dtype=bool)
    fix = metrics.first_fix_index(record.stamps, correct)
    if fix is None:
        return {}
    counted = ((np.arange(record.stamps.size) >= fix) & np.isfinite(series["position_error_m"])
               & ~np.asarray(series["recovering"], dtype=bool))
    at = record.stamps[counted]
    truth_at = write_tum(out_dir / f"{name}.truth.tum", at,
                         metrics.interpolate_poses(truth, at, breaks=reference.kidnap_indices))
    rmse = evo_ape_rmse(truth_at, estimates)
    return {} if rmse is None else {"evo_ape_rmse_m": round(rmse, 4)}


def evo_ape_rmse(reference_tum: Path, estimate_tum: Path) -> float | None:
    """evo's APE RMSE (translation part, no alignment) of ``estimate_tum`` against ``reference_tum``.

    The trajectories are associated by evo on equal stamps; None when evo is not installed.
    """
    try:
        from evo.core import metrics as evo_metrics
        from evo.core import sync
        from evo.tools import file_interface
    except ImportError:
        return None
    ref = file_interface.read_tum_trajectory_file(str(reference_tum))
    est = file_interface.read_tum_trajectory_file(str(estimate_tum))
    ref, est = sync.associate_trajectories(ref, est, max_diff=1e-6)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    return float(ape.get_statistic(evo_metrics.StatisticsType.rmse))
