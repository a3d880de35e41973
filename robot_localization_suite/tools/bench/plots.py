"""PNG plots of one benchmark run: trajectory over the map, errors over time, update times.

matplotlib with the Agg backend (no display needed); the map and the true path are drawn by
:mod:`..map_plots`, which the demo's picture shares. Files, per bag and localizer:
``<localizer>_trajectory.png``, ``<localizer>_error.png``, ``<localizer>_update_time.png``.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ...core import metrics  # noqa: E402
from ...core.grid_map import GridMap  # noqa: E402
from ..map_plots import draw_truth, finish_map_axes, map_image, save_figure, show_map  # noqa: E402

if TYPE_CHECKING:
    from .reference import BagReference
    from .replay import RunRecord

__all__ = ["map_image", "plot_run"]


def plot_run(
    out_dir: Path,
    localizer: str,
    grid_map: GridMap | None,
    reference: BagReference,
    record: RunRecord,
    series: dict[str, Any],
) -> list[Path]:
    """Write the three plots of one run; returns their paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    title = f"{reference.name} / {localizer} ({record.mode})"
    truth = reference.ground_truth
    written = []

    fig, axes = plt.subplots(figsize=(8, 8))
    show_map(axes, grid_map)
    if truth is not None:
        draw_truth(axes, truth.poses, reference.kidnap_indices)
    if record.poses.size:
        correct = np.asarray(series.get("correct", np.zeros(len(record.poses), dtype=bool)), dtype=bool)
        axes.plot(record.poses[correct, 0], record.poses[correct, 1], ".", color="tab:green", ms=3, label="correct")
        axes.plot(record.poses[~correct, 0], record.poses[~correct, 1], ".", color="tab:red", ms=3,
                  label="not correct")
    finish_map_axes(axes, title)
    written.append(save_figure(fig, out_dir / f"{localizer}_trajectory.png"))

    fig, (ax_xy, ax_theta) = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    if truth is not None and record.stamps.size:
        t0 = record.first_input_stamp if record.first_input_stamp is not None else record.stamps[0]
        t = record.stamps - t0
        # Log scales, with errors floored at 1 mm and 0.01 degree so that exact outputs still show.
        ax_xy.plot(t, np.maximum(series["position_error_m"], 1e-3), ".", ms=3)
        ax_theta.plot(t, np.maximum(np.rad2deg(series["heading_error_rad"]), 1e-2), ".", ms=3)
        for jump in reference.kidnap_stamps:
            for axes in (ax_xy, ax_theta):
                axes.axvline(jump - t0, color="tab:purple", lw=0.8, ls="--")
        ax_xy.set_yscale("log")
        ax_theta.set_yscale("log")
    else:
        ax_xy.text(0.5, 0.5, "no ground truth" if truth is None else "no output", ha="center",
                   transform=ax_xy.transAxes)
    ax_xy.axhline(metrics.CORRECT_XY_M, color="tab:orange", lw=0.8)
    ax_xy.axhline(metrics.FINE_XY_M, color="tab:green", lw=0.8)
    ax_theta.axhline(np.rad2deg(metrics.CORRECT_THETA_RAD), color="tab:orange", lw=0.8)
    ax_theta.axhline(np.rad2deg(metrics.FINE_THETA_RAD), color="tab:green", lw=0.8)
    ax_xy.set_ylabel("position error [m]")
    ax_theta.set_ylabel("heading error [deg]")
    ax_theta.set_xlabel("time since first input [s] (dashed: kidnappings)")
    ax_xy.set_title(title)
    written.append(save_figure(fig, out_dir / f"{localizer}_error.png"))

    fig, axes = plt.subplots(figsize=(6, 4))
    if record.update_ms.size:
        positive = np.maximum(record.update_ms, 1e-3)
        bins = np.logspace(np.log10(positive.min()), np.log10(positive.max()) + 1e-9, 40)
        axes.hist(positive, bins=bins.tolist())
        axes.set_xscale("log")
        axes.axvline(np.median(positive), color="k", lw=0.8, label=f"median {np.median(positive):.2f} ms")
        axes.axvline(np.percentile(positive, 95), color="tab:red", lw=0.8,
                     label=f"p95 {np.percentile(positive, 95):.2f} ms")
        axes.legend(fontsize=8)
    axes.set_xlabel("update time [ms]")
    axes.set_ylabel("updates")
    axes.set_title(title)
    written.append(save_figure(fig, out_dir / f"{localizer}_update_time.png"))
    return written
