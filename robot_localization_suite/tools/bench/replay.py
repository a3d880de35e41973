"""One bag replayed through one localizer, in this process: a :class:`RunRecord`.

Messages go to the same ``ros/adapter.py`` :class:`LocalizerAdapter` the nodes use, in
bag order, each handled before the next (``ros/bag.py``), so the benchmark measures the
code a robot runs, without DDS; a ``/map`` after the bag's first is a map change
(``adapter.on_map_msg``), a reinitialization request calls ``adapter.reinitialize()``.
How a run is fed and timed: ``docs/benchmark.md``.
"""

from __future__ import annotations

import functools
import logging
import math
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ...core import metrics
from ...core.grid_map import GridMap
from ...core.interval import angle_hull
from ...core.localizer import Estimate, Idler, LocalizerStatus
from .isolation import rss_mb
from .prepare import prepare_localizer, prepare_scan
from .reference import (
    IMAGE_TOPIC,
    MAP_TOPIC,
    ODOM_TOPIC,
    REINITIALIZE_TOPIC,
    SCAN_TOPIC,
    TF_STATIC_TOPIC,
    TF_TOPIC,
    TRUTH_TOPIC,
    BagReference,
)
from .specs import LocalizerSpec

if TYPE_CHECKING:
    from ...ros.bag import BagMessage

__all__ = ["TRACKING_COVARIANCE", "RunRecord", "log_sink", "replay_localizer"]

LOG = logging.getLogger("rls_bench")

# Initial pose covariance of --mode tracking: sigma 0.1 m in x and y, 5 degrees in heading.
TRACKING_COVARIANCE = np.diag([0.1**2, 0.1**2, np.deg2rad(5.0) ** 2])


class _TimedLocalizer:
    """Delegates to a core localizer and times each ``on_scan`` / ``on_image`` call that updates.

    A call that returns no estimate (MCL waiting for ``update_min_d``, IMA between
    update steps) is not an update: counting its microseconds would hide the cost
    of the real ones, so only calls that return an estimate are timed.
    """

    def __init__(self, inner: Any) -> None:
        self._inner = inner
        self.update_ms: list[float] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def _timed(self, call: Any, *args: Any) -> Any:
        start = time.perf_counter()
        result = call(*args)
        if result is not None:
            self.update_ms.append((time.perf_counter() - start) * 1e3)
        return result

    def on_scan(self, scan: Any) -> Any:
        return self._timed(self._inner.on_scan, scan)

    def on_image(self, stamp: float, image: Any) -> Any:
        return self._timed(self._inner.on_image, stamp, image)


@dataclass
class RunRecord:
    """What one replay of one bag through one localizer produced (raw, before the metrics)."""

    bag: str
    localizer: str
    mode: str
    stamps: NDArray[np.float64]
    poses: NDArray[np.float64]
    statuses: list[str]
    candidates: NDArray[np.float64] | None  # (outputs, CANDIDATE_K, 3) NaN-padded; None: no candidates ever
    update_ms: NDArray[np.float64]
    inputs: int
    first_input_stamp: float | None
    map_setup_s: float | None
    peak_rss_mb: float | None
    truncated: bool = False
    odometry_from: str | None = None  # where the odometry came from when not /odom ("/tf (odom -> base_link)")
    error: str | None = None
    update_errors: int = 0
    containment: list[bool] | None = None
    containment_stamps: list[float] | None = None
    containment_lost: list[bool] | None = None
    containment_needed: list[float] | None = None  # the share of the scan the set's bound assumes explained (NaN: none)
    box_hull_widths: list[tuple[float, float, float]] | None = None  # x [m], y [m], theta [rad] of each output's boxes
    place_correct: list[bool] | None = None
    corrected_heading_error_deg: list[float] | None = None


class _StopReplay(Exception):
    pass


def log_sink(prefix: str) -> Callable[[str, str], None]:
    """The adapter's log function: its lines go to the ``rls_bench`` logger, tagged with ``prefix``."""
    levels = {"debug": logging.DEBUG, "info": logging.DEBUG, "warn": logging.WARNING, "error": logging.ERROR}

    def sink(level: str, text: str) -> None:
        LOG.log(levels.get(level, logging.INFO), "%s %s", prefix, text)

    return sink


def _method_checks(record: RunRecord, estimate: Estimate, base_truth: NDArray[np.float64]) -> None:
    """Checks of one output's method-specific fields (boxes, place, heading correction) against the (base) truth."""
    if not np.all(np.isfinite(base_truth)):
        return
    if estimate.boxes is not None:
        if (record.containment is None or record.containment_stamps is None or record.containment_lost is None
                or record.containment_needed is None):
            record.containment, record.containment_stamps, record.containment_lost = [], [], []
            record.containment_needed = []
        record.containment.append(metrics.boxes_contain(estimate.boxes, base_truth))
        record.containment_stamps.append(float(estimate.stamp))
        record.containment_lost.append(estimate.status is LocalizerStatus.LOST)
        record.containment_needed.append(float((estimate.details or {}).get("explained_needed", math.nan)))
        boxes = np.asarray(estimate.boxes, dtype=np.float64).reshape(-1, 3, 2)
        if len(boxes):
            record.box_hull_widths = record.box_hull_widths if record.box_hull_widths is not None else []
            theta_lo, theta_hi = angle_hull(boxes[:, 2, 0], boxes[:, 2, 1])
            record.box_hull_widths.append((float(boxes[:, 0, 1].max() - boxes[:, 0, 0].min()),
                                           float(boxes[:, 1, 1].max() - boxes[:, 1, 0].min()),
                                           float(theta_hi - theta_lo)))
    if estimate.place is not None:
        record.place_correct = record.place_correct if record.place_correct is not None else []
        record.place_correct.append(metrics.nearest_node_is_place(estimate.place.xy, estimate.place.node_xy, base_truth))
    if estimate.heading_corrected is not None:
        record.corrected_heading_error_deg = record.corrected_heading_error_deg or []
        if estimate.heading_corrected:
            _, dtheta = metrics.pose_errors(estimate.pose, base_truth)
            record.corrected_heading_error_deg.append(float(np.rad2deg(dtheta[0])))


class _RunBag:
    """One replay as an MCAP: the bag's messages, the localizer's outputs as its node publishes them
    (pose, candidates, diagnostics, IAL's boxes as markers), each output's error against the truth at
    its stamp, and the true ``map -> odom`` on ``/tf`` (:mod:`...ros.recording`, as the demo records)."""

    def __init__(self, path: Path, localizer: str, truth: metrics.Trajectory | None, breaks: NDArray[np.int64]) -> None:
        from ...ros.bag import BagWriter
        from ...ros.recording import TrueMapToOdom

        self.localizer = localizer
        self.truth = truth
        self.breaks = breaks
        self.map_to_odom = TrueMapToOdom()
        self.writer = BagWriter(path, compress=True).__enter__()

    def write_input(self, item: BagMessage) -> None:
        from ...ros.tf import TFMessage, tf_message

        self.writer.write(item.topic, item.msg, item.stamp_ns)
        if item.topic in (ODOM_TOPIC, TRUTH_TOPIC) and TFMessage is not None:
            transform = self.map_to_odom.add(item.msg, truth=item.topic == TRUTH_TOPIC)
            if transform is not None:
                self.writer.write("/tf", tf_message([transform]), item.stamp_ns)

    def write_output(self, output: Any, stamp_ns: int) -> None:
        from ...ros.extras import boxes_markers
        from ...ros.recording import ERROR_TYPE, error_message, error_topic

        name = self.localizer
        if output.has_pose:
            self.writer.write(f"/{name}/pose", output.pose, stamp_ns)
        self.writer.write(f"/{name}/candidates", output.candidates, stamp_ns)
        self.writer.write("/diagnostics", output.diagnostics, stamp_ns)
        estimate = output.estimate
        if estimate.boxes is not None:
            self.writer.write(f"/{name}/boxes", boxes_markers(estimate), stamp_ns)
        if output.has_pose and self.truth is not None:
            truth = metrics.interpolate_poses(self.truth, [estimate.stamp], breaks=self.breaks)
            dxy, dtheta = metrics.pose_errors(np.asarray(estimate.pose).reshape(1, 3), truth)
            if np.isfinite(dxy[0]):
                self.writer.write_serialized(error_topic(name), ERROR_TYPE,
                                             error_message(estimate.stamp, dxy[0], dtheta[0]), stamp_ns)

    def close(self) -> None:
        self.writer.__exit__(None, None, None)


def replay_localizer(
    reference: BagReference,
    spec: LocalizerSpec,
    grid_map: GridMap | None,
    *,
    mode: str = "global",
    max_seconds: float | None = None,
    sample_rss: bool = True,
    progress: bool = False,
    record_dir: Path | None = None,
) -> RunRecord:
    """Replay one bag through one localizer, in this process (``docs/benchmark.md``, "How a run works").

    ``record_dir``: also write the run as one MCAP, ``<record_dir>/<bag>_<localizer>_<mode>/``
    (:class:`_RunBag`), which Foxglove opens with ``config/foxglove_demo_layout.json``.
    """
    from ...ros import conversions
    from ...ros.adapter import LocalizerAdapter
    from ...ros.bag import replay

    if mode not in ("global", "tracking"):
        raise ValueError(f"mode must be 'global' or 'tracking', got {mode!r}")
    record = RunRecord(
        bag=reference.name, localizer=spec.name, mode=mode, stamps=np.zeros(0), poses=np.zeros((0, 3)),
        statuses=[], candidates=None, update_ms=np.zeros(0), inputs=0, first_input_stamp=None, map_setup_s=None,
        peak_rss_mb=rss_mb() if sample_rss else None,
    )
    prefix = f"[{reference.name}/{spec.name}]"
    sink = log_sink(prefix)
    timed = _TimedLocalizer(spec.factory())
    # "Now" for the adapter's clock check is the log time of the message being replayed (its receive time).
    log_time = [float("inf")]
    adapter = LocalizerAdapter(timed, node_name=spec.name, log=sink, mount=spec.mount, clock=lambda: log_time[0])
    if grid_map is not None and hasattr(timed, "set_map"):
        first_scan = prepare_scan(timed, reference, spec.mount, uses_camera=spec.uses_camera)
        start = time.perf_counter()
        adapter.set_map(grid_map)
        prepare_localizer(timed, first_scan)
        record.map_setup_s = round(time.perf_counter() - start, 3)
    truth = reference.ground_truth
    stamps: list[float] = []
    poses: list[NDArray[np.float64]] = []
    candidates: list[NDArray[np.float64]] = []
    sensor_topic = IMAGE_TOPIC if spec.uses_camera else SCAN_TOPIC
    sensor_handler = adapter.on_image_msg if spec.uses_camera else adapter.on_scan_msg
    errors_seen: dict[str, int] = {}

    def on_sensor(msg: Any) -> None:
        if record.inputs == 0:
            record.first_input_stamp = conversions.stamp_to_seconds(msg.header.stamp)
            if mode == "tracking" and truth is not None:
                adapter.on_initial_pose_msg(
                    conversions.initial_pose_to_msg(record.first_input_stamp, truth.poses[0], TRACKING_COVARIANCE)
                )
        record.inputs += 1
        try:
            output = sensor_handler(msg)
        except Exception as exc:  # noqa: BLE001 - like the node's guard: log, count, go on
            record.update_errors += 1
            key = type(exc).__name__
            errors_seen[key] = errors_seen.get(key, 0) + 1
            if errors_seen[key] == 1:
                LOG.error("%s update failed: %s: %s\n%s", prefix, key, exc, traceback.format_exc(limit=4))
            return
        if output is None:
            return
        estimate = output.estimate
        if run_bag is not None:
            run_bag.write_output(output, int(log_time[0] * 1e9))
        pose = np.asarray(estimate.pose, dtype=np.float64).reshape(3)
        stamps.append(float(estimate.stamp))
        poses.append(pose)
        first = np.full((metrics.CANDIDATE_K, 3), np.nan)
        ranked = np.asarray(estimate.candidates, dtype=np.float64).reshape(-1, 3)[: metrics.CANDIDATE_K]
        first[: len(ranked)] = ranked
        candidates.append(first)
        record.statuses.append(estimate.status.value)
        has_checks = estimate.boxes is not None or estimate.place is not None or estimate.heading_corrected is not None
        if has_checks and truth is not None:
            base_truth = metrics.interpolate_poses(truth, [estimate.stamp], breaks=reference.kidnap_indices)[0]
            _method_checks(record, estimate, base_truth)

    def on_odom(msg: Any) -> None:
        try:
            adapter.on_odom_msg(msg)
        except Exception as exc:  # noqa: BLE001
            record.update_errors += 1
            LOG.error("%s odometry failed: %s: %s", prefix, type(exc).__name__, exc)

    deadline = time.monotonic() + max_seconds if max_seconds else np.inf
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=reference.sensor_counts.get(sensor_topic) or None, desc=prefix, unit="msg", leave=False,
                   disable=None)

    # Work a localizer does in background threads gets the log time between two messages, as on a robot
    # (core/localizer.py Idler; docs/benchmark.md, "How a run works"); untimed, like the robot's idle time.
    idler = timed if isinstance(timed, Idler) else None

    def on_message(item: BagMessage) -> None:
        previous, log_time[0] = log_time[0], item.stamp_ns * 1e-9
        if idler is not None and math.isfinite(previous):
            idler.idle(log_time[0] - previous)
        if run_bag is not None:
            run_bag.write_input(item)
        if sample_rss and item.topic == sensor_topic:
            record.peak_rss_mb = max(record.peak_rss_mb or 0.0, rss_mb())
            if bar is not None:
                bar.update(1)
        if time.monotonic() > deadline:
            record.truncated = True
            raise _StopReplay

    maps_seen = [0]

    def on_map(msg: Any) -> None:
        # The first /map is the bag's map, given before the replay (or replaced by --map); a later one
        # is a map change, given where it is, as a node gets it on its map topic.
        maps_seen[0] += 1
        if maps_seen[0] > 1 and grid_map is not None and hasattr(timed, "set_map"):
            adapter.on_map_msg(msg)

    def on_reinitialize(_msg: Any) -> None:
        adapter.reinitialize()

    def on_camera_cue(msg: Any) -> None:  # images as one more cue of a laser method: no estimate of their own
        try:
            adapter.on_image_msg(msg)
        except Exception as exc:  # noqa: BLE001
            record.update_errors += 1
            LOG.error("%s image failed: %s: %s", prefix, type(exc).__name__, exc)

    handlers: dict[str, Callable[[Any], Any]] = {ODOM_TOPIC: on_odom, sensor_topic: on_sensor, MAP_TOPIC: on_map,
                                                 REINITIALIZE_TOPIC: on_reinitialize}
    # Odometry from /tf as a node with odom_source tf reads it: asked for, or the bag has no /odom.
    if spec.odometry_from_tf or (ODOM_TOPIC not in reference.topics and TF_TOPIC in reference.topics):
        from ...ros.adapter import ThrottledLog
        from ...ros.tf import TransformBuffer

        tf_buffer = TransformBuffer(ThrottledLog(sink))

        def on_tf(msg: Any) -> None:
            for stamp, pose in tf_buffer.add_odometry(msg, spec.odom_frame, spec.base_frame):
                adapter.on_odometry(stamp, pose)

        del handlers[ODOM_TOPIC]
        handlers[TF_TOPIC] = on_tf
        handlers[TF_STATIC_TOPIC] = functools.partial(tf_buffer.add_message, static=True)
        record.odometry_from = f"/tf ({spec.odom_frame} -> {spec.base_frame})"
    if spec.camera_cue and not spec.uses_camera:
        handlers[IMAGE_TOPIC] = on_camera_cue
    run_bag = None if record_dir is None else _RunBag(Path(record_dir) / f"{reference.name}_{spec.name}_{mode}",
                                                         spec.name, truth, reference.kidnap_indices)
    try:
        replay(reference.path, handlers, on_message=on_message, remap=reference.remap)
    except _StopReplay:
        LOG.warning("%s stopped after %.0f s (--max-seconds)", prefix, max_seconds)
    finally:
        if bar is not None:
            bar.close()
        if run_bag is not None:
            run_bag.close()
    if sample_rss:
        record.peak_rss_mb = round(max(record.peak_rss_mb or 0.0, rss_mb()), 1)
    record.stamps = np.array(stamps, dtype=np.float64)
    record.poses = np.array(poses, dtype=np.float64).reshape(-1, 3)
    if candidates and not np.isnan(np.array(candidates)).all():
        record.candidates = np.array(candidates)
    record.update_ms = np.array(timed.update_ms, dtype=np.float64)
    return record

