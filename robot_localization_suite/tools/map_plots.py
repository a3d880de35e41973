"""The map and ground-truth drawing shared by the benchmark's plots and the demo's picture.

matplotlib with the Agg backend (no display needed): the map in grey (occupied black, free white,
unknown grey), the true path as a thin blue line, where kidnappings put the robot as purple stars.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..core.grid_map import GridMap  # noqa: E402

__all__ = ["map_image", "show_map", "draw_truth", "finish_map_axes", "save_figure"]


def map_image(grid_map: GridMap) -> np.ndarray:
    """Grey image of a map for ``imshow(origin="lower")``: occupied black, free white, unknown grey."""
    image = np.full(grid_map.data.shape, 0.8)
    image[grid_map.free_mask] = 1.0
    image[grid_map.occupied_mask] = 0.0
    return image


def show_map(axes: Any, grid_map: GridMap | None) -> None:
    """Draw ``grid_map`` (nothing when None) in world coordinates [m]."""
    if grid_map is None:
        return
    x0, x1, y0, y1 = grid_map.extent
    axes.imshow(map_image(grid_map), cmap="gray", vmin=0.0, vmax=1.0, origin="lower", extent=(x0, x1, y0, y1),
                interpolation="nearest")


def draw_truth(axes: Any, poses: np.ndarray, kidnap_indices: np.ndarray) -> None:
    """The true path (``(N, 3)`` poses) and, as stars, the poses kidnappings put the robot at."""
    axes.plot(poses[:, 0], poses[:, 1], "-", color="tab:blue", lw=0.8, label="ground truth")
    kidnapped = poses[kidnap_indices] if len(kidnap_indices) else np.zeros((0, 3))
    if len(kidnapped):
        axes.plot(kidnapped[:, 0], kidnapped[:, 1], "*", color="tab:purple", ms=12, label="kidnapped to")


def finish_map_axes(axes: Any, title: str) -> None:
    """Equal axes in metres, the title and a small legend."""
    axes.set_aspect("equal")
    axes.set_xlabel("x [m]")
    axes.set_ylabel("y [m]")
    axes.set_title(title)
    axes.legend(loc="best", fontsize=8)


def save_figure(fig: Any, path: Path) -> Path:
    """Write ``fig`` as the benchmark's PNGs are written (110 dpi, tight) and close it."""
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path
