"""What a bag holds for the benchmark: ground truth, odometry, kidnappings, map, map changes,
reinitialization requests, topics.

:func:`load_reference` reads it once before the runs; :func:`resolve_map` picks the map
of a bag (``--map``, the bag's ``/map``, or ``config/maps/``). The ROS modules that read
bags are imported when a bag is read, not when this module is.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ... import registry
from ...core import metrics
from ...core.errors import MapError
from ...core.grid_map import GridMap, load_map_yaml
from ...core.motion import ODOMETRY_NOISE_KEY, read_odometry_noise
from ...core.scan import LaserMount
from ...core.sim.config import REINITIALIZE_TOPIC as _REINITIALIZE

if TYPE_CHECKING:
    from ...ros.bag import BagMessage
    from ...ros.bag_recovery import Recovery

__all__ = [
    "SCAN_TOPIC",
    "IMAGE_TOPIC",
    "ODOM_TOPIC",
    "TRUTH_TOPIC",
    "MAP_TOPIC",
    "REINITIALIZE_TOPIC",
    "BENCH_TOPICS",
    "TF_TOPIC",
    "TF_STATIC_TOPIC",
    "BagReference",
    "load_reference",
    "map_candidates",
    "resolve_map",
]

LOG = logging.getLogger("rls_bench")

SCAN_TOPIC = "/scan"
IMAGE_TOPIC = "/camera/image_raw"
ODOM_TOPIC = "/odom"
TRUTH_TOPIC = "/ground_truth"
MAP_TOPIC = "/map"
TF_STATIC_TOPIC = "/tf_static"
TF_TOPIC = "/tf"  # odometry when the bag has no /odom (or odom_source tf)
# A reinitialization request recorded by scan_sim (docs/simulator.md): the replay calls reinitialize().
REINITIALIZE_TOPIC = "/" + _REINITIALIZE
# Every topic the benchmark reads (what --remap may name).
BENCH_TOPICS = (SCAN_TOPIC, ODOM_TOPIC, TRUTH_TOPIC, MAP_TOPIC, IMAGE_TOPIC, TF_TOPIC, TF_STATIC_TOPIC,
                REINITIALIZE_TOPIC)


@dataclass
class BagReference:
    """Everything about a bag that the metrics need, read once before the runs."""

    name: str
    path: Path
    topics: dict[str, str]
    ground_truth: metrics.Trajectory | None
    odometry: metrics.Trajectory | None
    kidnap_indices: NDArray[np.int64]
    map_msg_grid: GridMap | None
    sensor_counts: dict[str, int]
    recovery: Recovery | None = None  # what was read back from a damaged bag; None: the bag is sound
    undecodable: int = 0  # messages of its truth, odometry and map topics whose bytes could not be decoded
    truth_not_finite: int = 0  # ground-truth poses left out as not finite
    truth_messages: int = 0  # ground-truth messages in the bag (finite or not)
    map_refused: str = ""  # why its /map message was not used ("" when it was, or there was none)
    map_change_stamps: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))  # log times [s] of later /map
    reinitialize_stamps: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))  # log times [s]
    odometry_noise: dict[str, float] | None = None  # alpha1..alpha4 the bag declares for its /odom, if it does
    # the laser's mount in each frame above the scans' on the bag's /tf_static (LocalizerSpec.for_bag takes it)
    laser_mounts: dict[str, LaserMount] = field(default_factory=dict)
    # bag topic -> the name the benchmark reads it as (--remap; every read of the bag goes through it)
    remap: dict[str, str] = field(default_factory=dict)

    @property
    def has_scan(self) -> bool:
        return SCAN_TOPIC in self.topics

    @property
    def has_camera(self) -> bool:
        return IMAGE_TOPIC in self.topics

    @property
    def kidnap_stamps(self) -> NDArray[np.float64]:
        if self.ground_truth is None or self.kidnap_indices.size == 0:
            return np.zeros(0)
        return self.ground_truth.stamps[self.kidnap_indices]


def _topic_counts(path: Path) -> dict[str, int]:
    from rosbags.rosbag2 import Reader

    try:
        with Reader(path) as reader:
            return {name: int(info.msgcount) for name, info in reader.topics.items()}
    except Exception:  # noqa: BLE001 - counts only drive progress bars
        return {}


def _trajectory(messages: list[BagMessage]) -> tuple[metrics.Trajectory | None, int]:
    """The poses of ``messages`` (None without any finite one), and how many were left out as not finite."""
    from ...ros import conversions

    if not messages:
        return None, 0
    stamps, poses = zip(*(conversions.odometry_from_msg(m.msg) for m in messages), strict=True)
    poses_arr = np.array(poses)
    keep = np.all(np.isfinite(poses_arr), axis=1)
    dropped = int((~keep).sum())
    if not keep.any():
        return None, dropped
    return metrics.Trajectory(np.array(stamps)[keep], poses_arr[keep]), dropped


def load_reference(path: str | os.PathLike[str], remap: Mapping[str, str] | None = None) -> BagReference:
    """Read a bag's ground truth, odometry and map, and find its kidnappings (of what is left of a damaged bag).

    ``remap``: bag topic -> the benchmark's name for it (``/base_scan`` -> ``/scan``, as ``ros2 bag play
    --remap``); a remapped topic hides one of the bag's by that name (``ros.bag.remapped_topic``).
    """
    from ...ros import conversions
    from ...ros.bag import bag_custom_data, bag_topics, read_bag, remapped_topic

    path = Path(path)
    remap = dict(remap or {})
    topics = bag_topics(path, remap)
    for source in remap:
        if remapped_topic(source, remap) not in topics:
            LOG.warning("bag %s: --remap %s:=%s: the bag has no %s", path.name, source, remap[source], source)
    odometry_noise = _declared_odometry_noise(path, bag_custom_data(path))
    truth_msgs, odom_msgs = [], []
    map_grid = None
    map_refused = ""  # why the bag's /map was not used
    maps_seen = 0
    map_changes: list[float] = []
    requests: list[float] = []
    static_tf = []
    tf_msgs = []  # odometry when the bag has no /odom
    wanted = [TRUTH_TOPIC, ODOM_TOPIC, MAP_TOPIC, REINITIALIZE_TOPIC, TF_STATIC_TOPIC]
    if ODOM_TOPIC not in topics and TF_TOPIC in topics:
        wanted.append(TF_TOPIC)
    messages = read_bag(path, wanted, remap=remap)
    for item in messages:
        if item.topic == TF_STATIC_TOPIC:
            static_tf.append(item.msg)
        elif item.topic == TF_TOPIC:
            tf_msgs.append(item.msg)
        elif item.topic == TRUTH_TOPIC:
            truth_msgs.append(item)
        elif item.topic == ODOM_TOPIC:
            odom_msgs.append(item)
        elif item.topic == MAP_TOPIC:
            maps_seen += 1
            if maps_seen > 1:  # a map change: the replay gives it to the localizer there
                map_changes.append(item.stamp_ns * 1e-9)
                continue
            try:
                map_grid = conversions.grid_map_from_msg(item.msg)
            except MapError as exc:
                map_refused = str(exc)
                LOG.warning("bag %s: ignoring its /map message: %s", path.name, exc)
        elif item.topic == REINITIALIZE_TOPIC:
            requests.append(item.stamp_ns * 1e-9)
    truth, truth_dropped = _trajectory(truth_msgs)
    odometry = _trajectory(odom_msgs)[0] if odom_msgs else _tf_odometry(path, tf_msgs, static_tf)
    kidnaps = metrics.detect_kidnappings(truth, odometry) if truth is not None else np.zeros(0, dtype=np.int64)
    recovery = messages.recovery
    counts = recovery.topic_counts if recovery is not None else _topic_counts(path)
    counts = {name: count for topic, count in counts.items() if (name := remapped_topic(topic, remap)) is not None}
    return BagReference(
        name=path.name,
        path=path,
        topics=topics,
        ground_truth=truth,
        odometry=odometry,
        kidnap_indices=kidnaps,
        map_msg_grid=map_grid,
        sensor_counts={t: counts.get(t, 0) for t in (SCAN_TOPIC, IMAGE_TOPIC)},
        recovery=recovery,
        undecodable=messages.skipped,
        truth_not_finite=truth_dropped,
        truth_messages=len(truth_msgs),
        map_refused=map_refused,
        map_change_stamps=np.array(map_changes, dtype=np.float64),
        reinitialize_stamps=np.array(requests, dtype=np.float64),
        odometry_noise=odometry_noise,
        laser_mounts=_laser_mounts(path, static_tf, remap) if static_tf and SCAN_TOPIC in topics else {},
        remap=remap,
    )


def _static_tf(path: Path, static_tf: list[Any]) -> Any:
    """A ``ros.tf.TransformBuffer`` holding the bag's ``/tf_static`` messages (what it refuses is logged)."""
    from ...ros.tf import TransformBuffer

    def log(level: str, key: str, text: str) -> None:
        LOG.warning("bag %s: %s", path.name, text)

    buffer = TransformBuffer(log)
    for msg in static_tf:
        buffer.add_message(msg, static=True)
    return buffer


def _tf_odometry(path: Path, tf_msgs: list[Any], static_tf: list[Any]) -> metrics.Trajectory | None:
    """The odometry of a bag without ``/odom``, for finding kidnappings: REP 105's ``odom`` to the first frame
    ``/tf`` moves under it (each localizer's replay reads its own ``odom_frame_id -> base_frame_id``)."""
    from ...ros.tf import frame_name

    base = next((frame_name(t.child_frame_id) for msg in tf_msgs for t in msg.transforms
                 if frame_name(t.header.frame_id) == "odom"), None)
    if base is None:
        return None
    buffer = _static_tf(path, static_tf)
    samples = [sample for msg in tf_msgs for sample in buffer.add_odometry(msg, "odom", base)]
    if not samples:
        return None
    return metrics.Trajectory(np.array([stamp for stamp, _ in samples]), np.array([pose for _, pose in samples]))


def _laser_mounts(path: Path, static_tf: list[Any], remap: Mapping[str, str]) -> dict[str, LaserMount]:
    """The laser's mount in every frame of the bag's ``/tf_static`` tree it can be placed in (the first scan's frame)."""
    from ...ros.bag import read_bag
    from ...ros.tf import frame_name

    scans = read_bag(path, [SCAN_TOPIC], remap=remap)
    try:
        laser = frame_name(next(scans).msg.header.frame_id)
    except StopIteration:
        return {}
    finally:
        scans.close()
    buffer = _static_tf(path, static_tf)
    mounts = {}
    for frame in sorted(buffer.frames() - {laser}):  # above it, or beside it under a common frame (as tf2)
        found = buffer.lookup_mount(frame, laser, static_only=True)
        if found is not None:
            pose, upside_down = found
            try:
                mounts[frame] = LaserMount(float(pose[0]), float(pose[1]), float(pose[2]), upside_down)
            except ValueError as exc:
                LOG.warning("%s: ignoring %s -> %s on /tf_static: %s", path.name, frame, laser, exc)
    return mounts


def _declared_odometry_noise(path: Path, custom_data: dict[str, str]) -> dict[str, float] | None:
    """The odometry noise a bag's metadata declares (``carmen_to_bag`` writes it); None, with a warning for a
    declaration that cannot be read, when it declares none."""
    text = custom_data.get(ODOMETRY_NOISE_KEY)
    if text is None:
        return None
    try:
        return read_odometry_noise(text)
    except ValueError as exc:
        LOG.warning("bag %s: ignoring its declared odometry noise: %s", path.name, exc)
        return None


def map_candidates(bag_name: str) -> list[Path]:
    """``config/maps/<bag>.yaml`` then ``config/maps/<prefix>.yaml`` (prefix: up to the first ``_``)."""
    maps_dir = registry.config_dir() / "maps"
    names = [bag_name, bag_name.split("_")[0]]
    return [maps_dir / f"{n}.yaml" for n in dict.fromkeys(names)]


def resolve_map(reference: BagReference, map_yaml: str | os.PathLike[str] | None) -> tuple[GridMap | None, str]:
    """The map of a bag and where it came from: ``--map``, the bag's ``/map``, or ``config/maps/``."""
    if map_yaml is not None:
        return load_map_yaml(map_yaml), str(map_yaml)
    if reference.map_msg_grid is not None:
        return reference.map_msg_grid, f"{reference.name}:{MAP_TOPIC}"
    for candidate in map_candidates(reference.name):
        if candidate.is_file():
            return load_map_yaml(candidate), str(candidate)
    return None, "none"
