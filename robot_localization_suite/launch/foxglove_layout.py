"""The Foxglove layout of a demo run: a 3-D panel (map, scan, truth, each estimate) and plots of the errors.

:func:`demo_layout` builds it for a set of localizers; ``config/foxglove_demo_layout.json`` is the one
for every localizer there is (``python -m robot_localization_suite.launch.foxglove_layout`` rewrites
it), and each demo run writes its own, for the localizers it ran, next to its recording.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["LAYOUT_FILE", "demo_layout", "layout_topics", "main"]

LAYOUT_FILE = "foxglove_demo_layout.json"
# One colour per localizer, in registry order (matplotlib's tab10 without blue, the truth's colour).
_COLOURS = ("#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")
_TRUTH_COLOUR = "#1f77b4"


def demo_layout(localizers: Sequence[str], *, camera: bool = False) -> dict[str, Any]:
    """The layout (Foxglove's JSON) showing the topics :func:`..ros.recording.run_topics` records for ``localizers``."""
    from ..ros.recording import error_topic, run_topics

    topics: dict[str, Any] = {
        "/map": {"visible": True, "colorMode": "map", "alpha": 1.0},
        "/scan": {"visible": True, "colorMode": "flat", "flatColor": "#ff0000", "pointSize": 3},
        "/ground_truth": {"visible": True, "type": "arrow", "color": _TRUTH_COLOUR, "arrowScale": [0.6, 0.15, 0.15]},
    }
    recorded = {topic.name for topic in run_topics(localizers, camera=camera)}
    error_paths, heading_paths = [], []
    for index, name in enumerate(localizers):
        colour = _COLOURS[index % len(_COLOURS)]
        topics[f"/{name}/pose"] = {"visible": True, "type": "arrow", "color": colour,
                                   "arrowScale": [0.5, 0.12, 0.12], "showCovariance": True, "covarianceColor": colour + "40"}
        topics[f"/{name}/candidates"] = {"visible": False, "type": "arrow", "color": colour + "80",
                                         "arrowScale": [0.2, 0.05, 0.05]}
        if f"/{name}/boxes" in recorded:
            topics[f"/{name}/boxes"] = {"visible": True}
        path = error_topic(name)
        error_paths.append({"value": f"{path}.point.x", "enabled": True, "color": colour, "label": f"{name} [m]",
                            "timestampMethod": "headerStamp"})
        heading_paths.append({"value": f"{path}.point.y", "enabled": True, "color": colour, "label": f"{name} [deg]",
                              "timestampMethod": "headerStamp"})
    plot = {"showLegend": True, "legendDisplay": "floating", "showXAxisLabels": True, "showYAxisLabels": True,
            "isSynced": True, "xAxisVal": "timestamp", "sidebarDimension": 240}
    config_by_id: dict[str, Any] = {
        "3D!demo": {
            "followTf": "map",
            "followMode": "follow-none",
            "cameraState": {"perspective": False, "distance": 30.0, "phi": 0.0, "thetaOffset": 0.0,
                            "targetOffset": [10.0, 10.0, 0.0], "target": [0.0, 0.0, 0.0],
                            "targetOrientation": [0.0, 0.0, 0.0, 1.0], "fovy": 45.0, "near": 0.5, "far": 5000.0},
            "scene": {"transforms": {"showLabel": False, "axisScale": 0.5}},
            "transforms": {},
            "topics": topics,
            "layers": {"grid": {"visible": False, "layerId": "foxglove.Grid"}},
            "publish": {"type": "point", "poseTopic": "/initialpose"},
            "imageMode": {},
        },
        "Plot!position_error": {**plot, "title": "position error vs truth at the estimate's stamp [m]",
                                "paths": error_paths},
        "Plot!heading_error": {**plot, "title": "heading error vs truth at the estimate's stamp [deg]",
                               "paths": heading_paths},
    }
    plots: Any = {"direction": "column", "first": "Plot!position_error", "second": "Plot!heading_error",
                  "splitPercentage": 50}
    if camera:  # the camera's images above the plots
        config_by_id["Image!camera"] = {"imageMode": {"imageTopic": "/camera/image_raw"}}
        plots = {"direction": "column", "first": "Image!camera", "second": plots, "splitPercentage": 34}
    return {
        "configById": config_by_id,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1.0},
        "layout": {"direction": "row", "first": "3D!demo", "second": plots, "splitPercentage": 62},
    }


def layout_topics(layout: dict[str, Any]) -> set[str]:
    """Every topic a layout names: the 3-D panels' topics, the plots' message paths' and the image panels'."""
    names: set[str] = set()
    for config in layout["configById"].values():
        names.update(config.get("topics", {}))
        names.update(path["value"].split(".", 1)[0] for path in config.get("paths", []))
        if config.get("imageMode", {}).get("imageTopic"):
            names.add(config["imageMode"]["imageTopic"])
    return names


def main(argv: Sequence[str] | None = None) -> int:
    from ..registry import PLUGINS, config_dir

    parser = argparse.ArgumentParser(description="Write the Foxglove layout of the demo for every localizer there is.")
    parser.add_argument("--out", default=str(config_dir() / LAYOUT_FILE), help="file to write (config/" + LAYOUT_FILE + ")")
    args = parser.parse_args(argv)
    Path(args.out).write_text(json.dumps(demo_layout(list(PLUGINS)), indent=2) + "\n")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
