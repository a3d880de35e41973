"""``ima_topo_localizer``: camera topological localization (thesis 003) as a ROS 2 node.

Subscribes to ``camera/image_raw`` and ``odom``; publishes ``~/pose`` (the
winning place's x, y and the corrected heading), ``~/place`` (std_msgs/String,
the place's name), ``~/candidates`` (the destinations, best first) and
``/diagnostics``. The topological map (``topomap``: a YAML written by
``build_topomap``, with one panorama PNG per place) is read at start; a
relative path is looked up from the working directory, then in the package's
``config/`` folder. Parameters are copied one to one into
:class:`~robot_localization_suite.core.ima_tracking.ImaTrackerSettings`
(``update_min_d`` / ``update_min_a`` keep nav2_amcl's names).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

from std_msgs.msg import String

from ..core.errors import MapError
from ..core.ima.matching import ImaSettings, load_topomap
from ..core.ima.tracking import ODOMETRY_RESETS, ImaTopoLocalizer, ImaTrackerSettings
from ..core.localizer import Estimate
from .common import ParamSpec
from .localizer_node import localizer_node_main

__all__ = ["NODE_NAME", "DESCRIPTION", "PARAMS", "USES_CAMERA", "EXTRAS", "make_localizer", "build_extras", "main"]

NODE_NAME = "ima_topo_localizer"
DESCRIPTION = (
    "Camera topological localization (thesis 003): IMA slot matching with NCC against the "
    "panoramas of a topological map (digital zoom, heading from the panorama), and multi-hypothesis "
    "tracking of the places with odometry (Code 3.1). Publishes the place name on ~/place."
)
USES_CAMERA = True
EXTRAS = {"place": String}

_IMA = ImaSettings()
_TRACK = ImaTrackerSettings()

PARAMS = (
    ParamSpec("topomap", "topomaps/lab/topomap.yaml", "topological map YAML (build_topomap); relative: cwd, then config/"),
    ParamSpec("scale_width", _IMA.width, "working image width [px] (thesis 5.2: 72)", 8, 2048),
    ParamSpec("scale_height", _IMA.height, "working image height [px] (thesis 5.2: 58)", 4, 2048),
    ParamSpec("slots", _IMA.slots, "IMA slots Ns (thesis 5.2: 8)", 1, 1024),
    ParamSpec("clahe", _IMA.clahe, "CLAHE filtering of images and panoramas (thesis 2.2.2)"),
    ParamSpec("clahe_clip_limit", _IMA.clahe_clip_limit, "CLAHE contrast limit", 0.01, 100.0),
    ParamSpec("clahe_tiles", _IMA.clahe_tiles, "CLAHE tiles across the working image", 1, 16),
    ParamSpec("zoom", _IMA.zoom, "digital zoom rho_in (thesis 5.2: 1.1); 1.0 turns the zoom off", 1.0, 2.0),
    ParamSpec("cylindrical", _IMA.cylindrical, "warp images to equal angle per column before matching"),
    ParamSpec("ncc_backend", _IMA.ncc_backend, "NCC computation: gemm (batched) or opencv (cv2.matchTemplate)"),
    ParamSpec("match_threshold", _TRACK.match_threshold, "eps_M: least IMA match of a destination (thesis 5.2: 0.5)", 0.0, 1.0),
    ParamSpec("heading_threshold", _TRACK.heading_threshold, "eps_phi: least match to correct the heading (thesis 5.2: 0.6)", 0.0, 1.0),
    ParamSpec("update_min_d", _TRACK.min_translation, "translation that triggers an update [m] (thesis 5.2: 0.3)", 0.0, 100.0),
    ParamSpec("update_min_a", _TRACK.min_rotation, "rotation that triggers an update [rad] (thesis 5.2: 10 deg)", 0.0, math.pi),
    ParamSpec("odometry_reset", _TRACK.odometry_reset, "where the odometry guess d0 is measured from: " + ", ".join(ODOMETRY_RESETS)),
)


def resolve_topomap(path: str) -> Path:
    """The topological map file: as given, else relative to the package's ``config/`` folder.

    Raises:
        MapError: naming the path when neither exists.
    """
    if not path:
        raise MapError("parameter 'topomap' is empty: give the topological map YAML written by build_topomap")
    candidate = Path(path).expanduser()
    if candidate.is_file() or candidate.is_absolute():
        return candidate
    from ..registry import config_dir

    packaged = config_dir() / candidate
    return packaged if packaged.is_file() else candidate


def make_localizer(params: dict[str, Any]) -> ImaTopoLocalizer:
    """Build the core localizer from parameter values (raises MapError naming a missing file)."""
    ima = ImaSettings(
        width=int(params["scale_width"]),
        height=int(params["scale_height"]),
        slots=int(params["slots"]),
        clahe=bool(params["clahe"]),
        clahe_clip_limit=float(params["clahe_clip_limit"]),
        clahe_tiles=int(params["clahe_tiles"]),
        zoom=float(params["zoom"]),
        ncc_backend=str(params["ncc_backend"]),
        cylindrical=bool(params["cylindrical"]),
    )
    settings = ImaTrackerSettings(
        ima=ima,
        match_threshold=float(params["match_threshold"]),
        heading_threshold=float(params["heading_threshold"]),
        min_translation=float(params["update_min_d"]),
        min_rotation=float(params["update_min_a"]),
        odometry_reset=str(params["odometry_reset"]),
    )
    return ImaTopoLocalizer(load_topomap(resolve_topomap(str(params["topomap"]))), settings)


def build_extras(estimate: Estimate) -> dict[str, Any]:
    """``~/place``: the name of the estimated place."""
    return {"place": String(data=str(estimate.details.get("place", "")))}


def main() -> int:
    return localizer_node_main(sys.modules[__name__])


if __name__ == "__main__":
    sys.exit(main())
