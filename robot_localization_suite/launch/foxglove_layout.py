"""The Foxglove layout of a demo run: a 3-D panel (map, scan, truth, each estimate) and plots of the errors.

Built with foxglove-sdk's typed layout model (``foxglove.layouts``, its layout format version 1), so
every panel and setting is one the SDK knows. :func:`demo_layout` builds it for a set of localizers; ``config/foxglove_demo_layout.json`` is the one
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
    """The layout of a run of ``localizers`` as Foxglove's JSON, built with ``foxglove.layouts`` (foxglove-sdk).

    A 3-D panel in the map frame: the map, the scan, the truth and each estimate (its candidates
    hidden, IAL's boxes shown); the camera's images when the run has a camera; plots of each
    localizer's position and heading error against the truth at the estimate's stamp.

    Raises:
        ImportError: foxglove-sdk is not installed (the ``viz`` extra; ``make`` installs it).
    """
    import foxglove.layouts as fl

    from ..ros.recording import error_topic, run_topics

    recorded = {topic.name for topic in run_topics(localizers, camera=camera)}
    topics: dict[str, Any] = {
        "/map": fl.BaseRendererRosOccupancyGridTopicSettings(visible=True, color_mode="map", alpha=1.0),
        "/scan": fl.BaseRendererLaserScanTopicSettings(visible=True, point_size=3.0, color_mode="flat",
                                                      flat_color="#ff0000"),
        "/ground_truth": fl.BaseRendererPoseTopicSettings(visible=True, type="arrow", color=_TRUTH_COLOUR,
                                                         arrow_scale=(0.6, 0.15, 0.15)),
    }
    position, heading = [], []
    for index, name in enumerate(localizers):
        colour = _COLOURS[index % len(_COLOURS)]
        topics[f"/{name}/pose"] = fl.BaseRendererPoseTopicSettings(
            visible=True, type="arrow", color=colour, arrow_scale=(0.5, 0.12, 0.12), show_covariance=True,
            covariance_color=colour + "40")
        topics[f"/{name}/candidates"] = fl.BaseRendererPosesTopicSettings(visible=False, type="arrow",
                                                                         arrow_scale=(0.2, 0.05, 0.05))
        if f"/{name}/boxes" in recorded:
            topics[f"/{name}/boxes"] = fl.BaseRendererBaseSettings(visible=True)
        path = error_topic(name)
        position.append(fl.PlotSeries(value=f"{path}.point.x", enabled=True, color=colour, label=f"{name} [m]",
                                      timestamp_method="headerStamp"))
        heading.append(fl.PlotSeries(value=f"{path}.point.y", enabled=True, color=colour, label=f"{name} [deg]",
                                     timestamp_method="headerStamp"))
    three_d = fl.ThreeDeePanel(title="map, scan, truth (blue) and estimates", config=fl.ThreeDeeConfig(
        follow_tf="map", follow_mode="follow-none", topics=topics,
        camera_state=fl.ThreeDeeCameraState(perspective=False, distance=30.0, phi=0.0, theta_offset=0.0,
                                            target_offset=(10.0, 10.0, 0.0))))

    def plot(title: str, series: list[Any]) -> Any:
        return fl.PlotPanel(title=title, config=fl.PlotConfig(
            paths=series, show_legend=True, legend_display="floating", show_x_axis_labels=True,
            show_y_axis_labels=True, is_synced=True, x_axis_val="timestamp"))

    side = [fl.SplitItem(content=plot("position error vs truth at the estimate's stamp [m]", position)),
            fl.SplitItem(content=plot("heading error vs truth at the estimate's stamp [deg]", heading))]
    if camera:
        side.insert(0, fl.SplitItem(content=fl.ImagePanel(
            title="camera", config=fl.ImageConfig(image_mode=fl.ImageModeConfig(image_topic="/camera/image_raw")))))
    layout = fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=1.6, content=three_d),
        fl.SplitItem(proportion=1.0, content=fl.SplitContainer(direction="column", items=side)),
    ]))
    result: dict[str, Any] = json.loads(layout.to_json())
    return result


def _panels(content: dict[str, Any]) -> list[dict[str, Any]]:
    if content.get("type") == "panel":
        return [content]
    return [panel for item in content.get("items", []) for panel in _panels(item["content"])]


def layout_topics(layout: dict[str, Any]) -> set[str]:
    """Every topic a layout names: the 3-D panels' topics, the plots' message paths' and the image panels'."""
    names: set[str] = set()
    for panel in _panels(layout["content"]):
        config = panel.get("config", {})
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
