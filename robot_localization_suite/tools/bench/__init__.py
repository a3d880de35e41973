"""``rls_bench``: every localizer on the same bags, measured the same way.

    rls_bench BAG... --localizers NAMES --out DIR [--map MAP_YAML] [--mode global|tracking]
              [--set name.param=value ...] [--max-seconds S] [--no-plots]
    rls_bench --global-fixes [--every N] BAG... [--localizers NAMES] --out DIR
    rls_bench --all [--with-global-fixes] [--out results]

Each bag is replayed *in-process* through each localizer with the
deterministic replay (``ros/bag.py``: messages in bag order, each handled
before the next) and the same ``ros/adapter.py`` :class:`LocalizerAdapter` the
nodes use, so the benchmark measures the code a robot runs, without DDS.
Every (bag, localizer) run happens in a fresh child process (``spawn``) so
that ``peak_rss_mb`` is that run's own peak (``VmHWM`` of the child; not
``ru_maxrss``, which on Linux carries over the parent's resident size from the
fork that precedes the exec) and a
crash or hang in one localizer cannot take the table down; ``--in-process``
runs them in this process instead (peak RSS is then sampled with psutil after
each message, which misses spikes inside an update). A child's output goes to
the same (often logged) stderr, so it runs with ``TQDM_DISABLE=1`` unless
``-v`` is given: the localizers' precomputation progress bars that honour it
(``core/progress.py``: IR's index) stay off; nothing measured changes.

Inputs of a run: ``/odom`` to ``adapter.on_odom_msg``; ``/scan`` to
``adapter.on_scan_msg`` (laser localizers) or ``/camera/image_raw`` to
``adapter.on_image_msg`` (``USES_CAMERA`` modules). The map is ``--map``,
else the bag's first ``/map`` message, else ``config/maps/<bag>.yaml`` or
``config/maps/<prefix>.yaml`` (``office_kidnap`` -> ``office``); it is given
to the localizer before the first message (``map_setup_s`` times that call).
``--mode tracking`` then sends the first ground-truth pose on ``initialpose``
(``adapter.on_initial_pose_msg``, covariance ``diag(0.1 m, 0.1 m, 5 deg)^2``).
``update_ms`` is the wall time of each ``on_scan`` / ``on_image`` call of the
core localizer that returns an estimate (calls that only buffer an input are
not updates and are not timed).

The metrics are defined in ``core/metrics.py`` and README ``## Benchmark``.
Localizer-specific fields come from ``Estimate.details``: ``boxes``
(``(K, 3, 2)``, in the base frame as ``core/ial.py`` writes them) ->
``containment_rate``; ``place_xy`` and
``node_xy`` -> ``correct_place_rate``; ``heading_corrected`` ->
``heading_error_when_corrected_deg`` (median, max).

``--all``: every available localizer over every bag in ``bags/`` (camera
localizers on bags with ``/camera/image_raw``, laser localizers on bags with
``/scan``), except pairs a localizer module declares it cannot do in
``BENCH_SKIP = {"bag-name glob": "reason"}`` or ``--skip NAME:GLOB``.

The injection point for other localizers (the tests' echo double) is
:class:`LocalizerSpec`: :func:`run_benchmark` and :func:`run_global_fixes`
take specs, each with a factory that builds a fresh core localizer.
"""

from __future__ import annotations

import argparse
import fnmatch
import functools
import json
import logging
import multiprocessing as mp
import os
import resource
import sys
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from ... import registry
from ...core import metrics
from ...core.errors import BagError, LocalizationSuiteError, MapError
from ...core.grid_map import GridMap, load_map_yaml
from ...core.scan import LaserMount
from ...ros import conversions
from ...ros.adapter import LocalizerAdapter
from ...ros.bag import BagMessage, bag_topics, read_bag

__all__ = [
    "LocalizerSpec",
    "BagReference",
    "RunRecord",
    "GlobalFixRecord",
    "registry_spec",
    "load_reference",
    "resolve_map",
    "replay_localizer",
    "global_fix_localizer",
    "summarize_run",
    "run_benchmark",
    "run_global_fixes",
    "write_summary",
    "main",
]

LOG = logging.getLogger("rls_bench")

SCAN_TOPIC = "/scan"
IMAGE_TOPIC = "/camera/image_raw"
ODOM_TOPIC = "/odom"
TRUTH_TOPIC = "/ground_truth"
MAP_TOPIC = "/map"

# Initial pose covariance of --mode tracking: sigma 0.1 m in x and y, 5 degrees in heading.
TRACKING_COVARIANCE = np.diag([0.1**2, 0.1**2, np.deg2rad(5.0) ** 2])
# Child processes get this long beyond --max-seconds to build, replay and hand back their result.
_CHILD_GRACE_S = 600.0
# Environment of a child run without -v: no precomputation progress bars in the output (core/progress.py).
_QUIET_CHILD_ENV = {"TQDM_DISABLE": "1"}


# -- what is benchmarked --------------------------------------------------------------------------
@dataclass(frozen=True)
class LocalizerSpec:
    """A localizer as the benchmark sees it.

    Attributes:
        name: column name in the tables.
        factory: builds a fresh core localizer (must be picklable for child processes,
            e.g. a module-level function or ``functools.partial`` of one).
        uses_camera: fed ``/camera/image_raw`` instead of ``/scan``.
        mount: laser pose in the base frame (the adapter's mounting offset).
        skip: bag-name glob -> reason, pairs ``--all`` leaves out.
    """

    name: str
    factory: Callable[[], Any]
    uses_camera: bool = False
    mount: LaserMount = field(default_factory=LaserMount)
    skip: Mapping[str, str] = field(default_factory=dict)

    def skip_reason(self, bag_name: str) -> str | None:
        for pattern, reason in self.skip.items():
            if fnmatch.fnmatch(bag_name, pattern):
                return str(reason)
        return None


def _plugin_factory(name: str, settings: Any) -> Any:
    return registry.plugin(name).create(settings)


def registry_spec(name: str, overrides: Mapping[str, Any] | None = None) -> LocalizerSpec:
    """The spec of a packaged localizer: its settings from ``config/<name>.yaml`` and ``overrides``."""
    plugin = registry.plugin(name)
    node_settings, settings = plugin.load_settings(overrides)
    return LocalizerSpec(
        name=name,
        factory=functools.partial(_plugin_factory, name, settings),
        uses_camera=plugin.uses_camera,
        mount=node_settings.mount,
        skip=dict(plugin.bench_skip),
    )


# -- what a bag holds -----------------------------------------------------------------------------
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


def _trajectory(messages: list[BagMessage]) -> metrics.Trajectory | None:
    if not messages:
        return None
    stamps, poses = zip(*(conversions.odometry_from_msg(m.msg) for m in messages), strict=True)
    poses_arr = np.array(poses)
    keep = np.all(np.isfinite(poses_arr), axis=1)
    if not keep.any():
        return None
    return metrics.Trajectory(np.array(stamps)[keep], poses_arr[keep])


def load_reference(path: str | os.PathLike[str]) -> BagReference:
    """Read a bag's ground truth, odometry and map, and find its kidnappings."""
    path = Path(path)
    topics = bag_topics(path)
    truth_msgs, odom_msgs = [], []
    map_grid = None
    for item in read_bag(path, [TRUTH_TOPIC, ODOM_TOPIC, MAP_TOPIC]):
        if item.topic == TRUTH_TOPIC:
            truth_msgs.append(item)
        elif item.topic == ODOM_TOPIC:
            odom_msgs.append(item)
        elif item.topic == MAP_TOPIC and map_grid is None:
            try:
                map_grid = conversions.grid_map_from_msg(item.msg)
            except MapError as exc:
                LOG.warning("bag %s: ignoring its /map message: %s", path.name, exc)
    truth = _trajectory(truth_msgs)
    odometry = _trajectory(odom_msgs)
    kidnaps = metrics.detect_kidnappings(truth, odometry) if truth is not None else np.zeros(0, dtype=np.int64)
    counts = _topic_counts(path)
    return BagReference(
        name=path.name,
        path=path,
        topics=topics,
        ground_truth=truth,
        odometry=odometry,
        kidnap_indices=kidnaps,
        map_msg_grid=map_grid,
        sensor_counts={t: counts.get(t, 0) for t in (SCAN_TOPIC, IMAGE_TOPIC)},
    )


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


# -- one run ---------------------------------------------------------------------------------------
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
    error: str | None = None
    update_errors: int = 0
    containment: list[bool] | None = None
    containment_stamps: list[float] | None = None
    containment_lost: list[bool] | None = None
    place_correct: list[bool] | None = None
    corrected_heading_error_deg: list[float] | None = None


class _StopReplay(Exception):
    pass


def _log_sink(prefix: str) -> Callable[[str, str], None]:
    levels = {"debug": logging.DEBUG, "info": logging.DEBUG, "warn": logging.WARNING, "error": logging.ERROR}

    def sink(level: str, text: str) -> None:
        LOG.log(levels.get(level, logging.INFO), "%s %s", prefix, text)

    return sink


def _rss_mb() -> float:
    import psutil

    return psutil.Process().memory_info().rss / 2**20


def _details_checks(record: RunRecord, details: dict[str, Any], base_truth: NDArray[np.float64],
                    estimate_pose: NDArray[np.float64]) -> None:
    """Localizer-specific checks of one output against the (base) truth at its stamp."""
    if not np.all(np.isfinite(base_truth)):
        return
    if "boxes" in details:
        boxes = np.asarray(details["boxes"], dtype=np.float64)
        if record.containment is None:
            record.containment, record.containment_stamps, record.containment_lost = [], [], []
        record.containment.append(metrics.boxes_contain(boxes, base_truth))
        record.containment_stamps.append(float(details.get("stamp", np.nan)))
        record.containment_lost.append(bool(details.get("lost", False)))
    if "place_xy" in details and "node_xy" in details:
        record.place_correct = record.place_correct if record.place_correct is not None else []
        record.place_correct.append(metrics.nearest_node_is_place(details["place_xy"], details["node_xy"], base_truth))
    if details.get("heading_corrected") is not None:
        record.corrected_heading_error_deg = record.corrected_heading_error_deg or []
        if bool(details["heading_corrected"]):
            _, dtheta = metrics.pose_errors(estimate_pose, base_truth)
            record.corrected_heading_error_deg.append(float(np.rad2deg(dtheta[0])))


def replay_localizer(
    reference: BagReference,
    spec: LocalizerSpec,
    grid_map: GridMap | None,
    *,
    mode: str = "global",
    max_seconds: float | None = None,
    sample_rss: bool = True,
    progress: bool = False,
) -> RunRecord:
    """Replay one bag through one localizer, in this process (see the module docstring)."""
    if mode not in ("global", "tracking"):
        raise ValueError(f"mode must be 'global' or 'tracking', got {mode!r}")
    record = RunRecord(
        bag=reference.name, localizer=spec.name, mode=mode, stamps=np.zeros(0), poses=np.zeros((0, 3)),
        statuses=[], candidates=None, update_ms=np.zeros(0), inputs=0, first_input_stamp=None, map_setup_s=None,
        peak_rss_mb=_rss_mb() if sample_rss else None,
    )
    prefix = f"[{reference.name}/{spec.name}]"
    sink = _log_sink(prefix)
    timed = _TimedLocalizer(spec.factory())
    adapter = LocalizerAdapter(timed, node_name=spec.name, log=sink, mount=spec.mount)
    if grid_map is not None and hasattr(timed, "set_map"):
        start = time.perf_counter()
        adapter.set_map(grid_map)
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
        pose = np.asarray(estimate.pose, dtype=np.float64).reshape(3)
        stamps.append(float(estimate.stamp))
        poses.append(pose)
        first = np.full((metrics.CANDIDATE_K, 3), np.nan)
        ranked = np.asarray(estimate.candidates, dtype=np.float64).reshape(-1, 3)[: metrics.CANDIDATE_K]
        first[: len(ranked)] = ranked
        candidates.append(first)
        record.statuses.append(estimate.status.value)
        if estimate.details and truth is not None:
            base_truth = metrics.interpolate_poses(truth, [estimate.stamp], breaks=reference.kidnap_indices)[0]
            checked = {**estimate.details, "stamp": estimate.stamp, "lost": estimate.status.value == "LOST"}
            _details_checks(record, checked, base_truth, pose)

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

    def on_message(item: BagMessage) -> None:
        if sample_rss and item.topic == sensor_topic:
            record.peak_rss_mb = max(record.peak_rss_mb or 0.0, _rss_mb())
            if bar is not None:
                bar.update(1)
        if time.monotonic() > deadline:
            record.truncated = True
            raise _StopReplay

    handlers = {ODOM_TOPIC: on_odom, sensor_topic: on_sensor}
    try:
        from ...ros.bag import replay

        replay(reference.path, handlers, on_message=on_message)
    except _StopReplay:
        LOG.warning("%s stopped after %.0f s (--max-seconds)", prefix, max_seconds)
    finally:
        if bar is not None:
            bar.close()
    if sample_rss:
        record.peak_rss_mb = round(max(record.peak_rss_mb or 0.0, _rss_mb()), 1)
    record.stamps = np.array(stamps, dtype=np.float64)
    record.poses = np.array(poses, dtype=np.float64).reshape(-1, 3)
    if candidates and not np.isnan(np.array(candidates)).all():
        record.candidates = np.array(candidates)
    record.update_ms = np.array(timed.update_ms, dtype=np.float64)
    return record


# -- global fixes ---------------------------------------------------------------------------------
@dataclass
class GlobalFixRecord:
    """Single-scan global fixes of one localizer on one bag."""

    bag: str
    localizer: str
    supported: bool
    estimates: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    truths: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    fix_ms: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    recalls: list[dict[int, bool]] = field(default_factory=list)
    failures: int = 0
    map_setup_s: float | None = None
    peak_rss_mb: float | None = None
    truncated: bool = False
    error: str | None = None


def global_fix_localizer(
    reference: BagReference,
    spec: LocalizerSpec,
    grid_map: GridMap | None,
    *,
    every: int = 10,
    max_seconds: float | None = None,
    sample_rss: bool = True,
) -> GlobalFixRecord:
    """Ask ``global_fix(scan)`` for every ``every``-th scan alone and compare with the truth."""
    if every < 1:
        raise ValueError(f"--every must be >= 1, got {every!r}")
    core = spec.factory()
    record = GlobalFixRecord(bag=reference.name, localizer=spec.name, supported=callable(getattr(core, "global_fix", None)))
    if not record.supported or spec.uses_camera:
        record.supported = False
        return record
    prefix = f"[{reference.name}/{spec.name} global fixes]"
    adapter = LocalizerAdapter(core, node_name=spec.name, log=_log_sink(prefix), mount=spec.mount)
    if grid_map is None:
        record.error = "no map"
        return record
    start = time.perf_counter()
    adapter.set_map(grid_map)
    record.map_setup_s = round(time.perf_counter() - start, 3)
    truth = reference.ground_truth
    estimates, truths, fix_ms = [], [], []
    deadline = time.monotonic() + max_seconds if max_seconds else np.inf
    peak = _rss_mb() if sample_rss else 0.0
    for index, item in enumerate(read_bag(reference.path, [SCAN_TOPIC])):
        if index % every:
            continue
        if time.monotonic() > deadline:
            record.truncated = True
            break
        try:
            scan = conversions.scan_from_msg(item.msg)
        except LocalizationSuiteError:
            continue
        true_pose = (metrics.interpolate_poses(truth, [scan.stamp], breaks=reference.kidnap_indices)[0]
                     if truth is not None else np.full(3, np.nan))
        started = time.perf_counter()
        try:
            estimate = core.global_fix(scan)
        except LocalizationSuiteError as exc:
            estimate = None
            LOG.debug("%s fix failed: %s", prefix, exc)
        fix_ms.append((time.perf_counter() - started) * 1e3)
        truths.append(true_pose)
        if estimate is None:
            record.failures += 1
            estimates.append(np.full(3, np.nan))
            record.recalls.append({k: False for k in metrics.RECALL_KS})
        else:
            pose = adapter.to_base(np.asarray(estimate.pose, dtype=np.float64))
            candidates = np.asarray(estimate.candidates, dtype=np.float64).reshape(-1, 3)
            candidates = adapter.to_base(candidates) if len(candidates) else pose[None, :]
            estimates.append(pose)
            record.recalls.append(metrics.recall_at_k(candidates, true_pose))
        if sample_rss:
            peak = max(peak, _rss_mb())
    record.estimates = np.array(estimates).reshape(-1, 3)
    record.truths = np.array(truths).reshape(-1, 3)
    record.fix_ms = np.array(fix_ms)
    record.peak_rss_mb = round(peak, 1) if sample_rss else None
    return record


# -- child processes ------------------------------------------------------------------------------
def _child_main(conn: Any, func: Callable[..., Any], args: tuple, kwargs: dict) -> None:
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    try:
        result = func(*args, **kwargs)
        result.peak_rss_mb = _own_peak_rss_mb()
        conn.send(("ok", result))
    except BaseException as exc:  # noqa: BLE001 - everything goes back to the parent as text
        conn.send(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}"))
    finally:
        conn.close()


def _own_peak_rss_mb() -> float:
    """Peak resident memory [MB] of this process image.

    ``VmHWM`` of ``/proc/self/status`` belongs to the address space made by ``exec``, so a
    spawned child reports its own peak; ``ru_maxrss`` would keep the parent's size from the
    ``fork`` before the ``exec`` (Linux keeps it across exec). Elsewhere ``ru_maxrss`` it is.
    """
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return round(int(line.split()[1]) / 1024.0, 1)
    except OSError:
        pass
    scale = 1024.0 if sys.platform != "darwin" else 1024.0**2
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / scale, 1)


def _run_isolated(
    func: Callable[..., Any], args: tuple, kwargs: dict, timeout: float, env: Mapping[str, str] | None = None
) -> tuple[str, Any]:
    """Run ``func(*args, **kwargs)`` in a fresh spawned process; ``("ok", result)`` or ``("error", text)``.

    ``env``: variables added to the child's environment (a spawned child copies this
    process's environment when it starts; it is set just for that and restored).
    """
    context = mp.get_context("spawn")
    receiver, sender = context.Pipe(duplex=False)
    process = context.Process(target=_child_main, args=(sender, func, args, kwargs), daemon=True)
    saved = {name: os.environ.get(name) for name in env or {}}
    try:
        os.environ.update(env or {})
        process.start()
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    sender.close()
    answered = False
    try:
        if receiver.poll(timeout):
            outcome = receiver.recv()
            answered = True
        else:
            outcome = ("error", f"no result within {timeout:.0f} s; child stopped")
    except EOFError:
        process.join(5.0)
        outcome = ("error", f"child process died (exit code {process.exitcode})")
    finally:
        # A child that answered exits by itself (and releases its semaphores); a stuck one is killed.
        process.join(30.0 if answered else 0.0)
        if process.is_alive():
            process.kill()
        process.join()
        receiver.close()
    return outcome


# -- from records to fields -----------------------------------------------------------------------
def _rate(values: list[bool] | None) -> float | None:
    if not values:
        return None
    return round(float(np.mean(values)), 4)


def summarize_run(record: RunRecord, reference: BagReference) -> tuple[dict[str, Any], dict[str, Any]]:
    """``summary.json`` fields of one run, and per-output arrays for the plots."""
    fields: dict[str, Any] = {"mode": record.mode}
    series: dict[str, Any] = {}
    truth = reference.ground_truth
    if truth is not None:
        evaluation = metrics.evaluate_outputs(
            record.stamps, record.poses, truth,
            first_input_stamp=record.first_input_stamp, kidnap_indices=reference.kidnap_indices,
            candidates=record.candidates,
        )
        fields["correct"] = int(np.count_nonzero(evaluation["correct"]))
        fields["fine"] = int(np.count_nonzero(evaluation["fine"]))
        for key in ("time_to_first_fix_s", "kidnap_recovery_s", "kidnap_recovery_updates",
                    "kidnap_candidate_recovery_updates", "correct_rate", "fine_rate", "rmse_xy_m", "rmse_theta_rad"):
            fields[key] = evaluation[key]
        series = {key: evaluation[key] for key in ("correct", "fine", "position_error_m", "heading_error_rad")}
    else:
        fields.update(correct=None, fine=None, time_to_first_fix_s=None, kidnap_recovery_s=[],
                      kidnap_recovery_updates=[], kidnap_candidate_recovery_updates=None, correct_rate=None,
                      fine_rate=None, rmse_xy_m=None, rmse_theta_rad=None)
    fields.update(metrics.timing_fields(record.update_ms))
    fields["peak_rss_mb"] = record.peak_rss_mb
    fields["outputs"] = int(record.stamps.size)
    # Beyond the list: what the reader needs to trust the numbers.
    fields["inputs"] = record.inputs
    fields["ground_truth"] = truth is not None
    fields["kidnappings"] = int(reference.kidnap_indices.size)
    fields["map_setup_s"] = record.map_setup_s
    if record.containment is not None:
        fields["containment_rate"] = _rate(record.containment)
        # A kidnapping breaks the odometry bound the guarantee rests on: the promise holds
        # again once the method has restarted (an empty box list, reported LOST).
        after_restart = metrics.outside_kidnap_until_restart(
            np.asarray(record.containment_stamps), np.asarray(record.containment_lost), reference.kidnap_stamps
        )
        fields["containment_rate_after_restart"] = _rate(list(np.asarray(record.containment)[after_restart]))
    if record.place_correct is not None:
        fields["correct_place_rate"] = _rate(record.place_correct)
    if record.corrected_heading_error_deg is not None:
        errors = record.corrected_heading_error_deg
        fields["heading_error_when_corrected_deg"] = {
            "median": round(float(np.median(errors)), 3) if errors else None,
            "max": round(float(np.max(errors)), 3) if errors else None,
            "count": len(errors),
        }
    if record.update_errors:
        fields["update_errors"] = record.update_errors
    if record.truncated:
        fields["truncated"] = True
    if truth is None:
        fields["note"] = "bag has no /ground_truth: timing only"
    return fields, series


# -- the benchmark ---------------------------------------------------------------------------------
def _plan(references: Sequence[BagReference], specs: Sequence[LocalizerSpec], *, honour_skips: bool):
    """Yield ``(reference, spec, skip_reason or None)`` for every pair."""
    for reference in references:
        for spec in specs:
            if spec.uses_camera and not reference.has_camera:
                yield reference, spec, f"no {IMAGE_TOPIC} in the bag"
            elif not spec.uses_camera and not reference.has_scan:
                yield reference, spec, f"no {SCAN_TOPIC} in the bag"
            elif honour_skips and spec.skip_reason(reference.name):
                yield reference, spec, spec.skip_reason(reference.name)
            else:
                yield reference, spec, None


def run_benchmark(
    bags: Sequence[str | os.PathLike[str]],
    specs: Sequence[LocalizerSpec],
    out_dir: str | os.PathLike[str],
    *,
    mode: str = "global",
    map_yaml: str | os.PathLike[str] | None = None,
    isolate: bool = True,
    max_seconds: float | None = None,
    plots: bool = True,
    honour_skips: bool = False,
    progress: bool = False,
    child_progress: bool = False,
) -> dict[str, dict[str, dict[str, Any]]]:
    """Replay every bag through every localizer; write ``summary.json``, ``summary.md`` and plots.

    ``progress``: a replay progress bar per run; ``child_progress``: the localizers'
    own precomputation bars in child runs (off: ``TQDM_DISABLE=1`` for the child).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    references = [load_reference(b) for b in bags]
    summary: dict[str, dict[str, dict[str, Any]]] = {r.name: {} for r in references}
    maps: dict[str, tuple[GridMap | None, str]] = {}
    for reference in references:
        maps[reference.name] = resolve_map(reference, map_yaml)
        if reference.ground_truth is None:
            LOG.warning("bag %s has no %s: reporting timing only", reference.name, TRUTH_TOPIC)
            print(f"rls_bench: bag {reference.name} has no {TRUTH_TOPIC}; reporting timing only", file=sys.stderr)
    for reference, spec, skip in _plan(references, specs, honour_skips=honour_skips):
        if skip is not None:
            summary[reference.name][spec.name] = {"mode": mode, "skipped": skip}
            continue
        grid_map, map_source = maps[reference.name]
        if grid_map is None and not spec.uses_camera:
            summary[reference.name][spec.name] = {"mode": mode, "error": "no map: give --map, a /map in the bag, "
                                                  f"or one of {', '.join(str(p) for p in map_candidates(reference.name))}"}
            continue
        print(f"rls_bench: {reference.name} / {spec.name} ({mode}) ...", file=sys.stderr, flush=True)
        kwargs = {"mode": mode, "max_seconds": max_seconds, "sample_rss": not isolate, "progress": progress}
        started = time.perf_counter()
        if isolate:
            timeout = (max_seconds or 24 * 3600.0) + _CHILD_GRACE_S
            status, result = _run_isolated(replay_localizer, (reference, spec, grid_map), kwargs, timeout,
                                           env=None if child_progress else _QUIET_CHILD_ENV)
        else:
            try:
                status, result = "ok", replay_localizer(reference, spec, grid_map, **kwargs)
            except Exception as exc:  # noqa: BLE001 - one localizer must not stop the table
                status, result = "error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}"
        if status != "ok":
            LOG.error("[%s/%s] failed: %s", reference.name, spec.name, result)
            summary[reference.name][spec.name] = {"mode": mode, "error": str(result).splitlines()[0]}
            continue
        fields, series = summarize_run(result, reference)
        fields["map"] = map_source
        fields["wall_s"] = round(time.perf_counter() - started, 1)
        summary[reference.name][spec.name] = fields
        print(f"rls_bench: {reference.name} / {spec.name}: {_one_line(fields)}", file=sys.stderr, flush=True)
        if plots:
            from .plots import plot_run

            plot_run(out / "plots" / reference.name, spec.name, grid_map, reference, result, series)
    write_summary(out, summary, title=f"rls_bench ({mode} mode)")
    return summary


def run_global_fixes(
    bags: Sequence[str | os.PathLike[str]],
    specs: Sequence[LocalizerSpec],
    out_dir: str | os.PathLike[str],
    *,
    every: int = 10,
    map_yaml: str | os.PathLike[str] | None = None,
    isolate: bool = True,
    max_seconds: float | None = None,
    honour_skips: bool = False,
    child_progress: bool = False,
) -> dict[str, dict[str, dict[str, Any]]]:
    """Single-scan global fixes of every localizer that offers ``global_fix``; write the summary.

    ``child_progress``: as in :func:`run_benchmark`.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    references = [load_reference(b) for b in bags]
    summary: dict[str, dict[str, dict[str, Any]]] = {r.name: {} for r in references}
    for reference, spec, skip in _plan(references, specs, honour_skips=honour_skips):
        if skip is not None or spec.uses_camera:
            continue
        grid_map, map_source = resolve_map(reference, map_yaml)
        print(f"rls_bench: {reference.name} / {spec.name} (global fixes, every {every}) ...", file=sys.stderr,
              flush=True)
        kwargs = {"every": every, "max_seconds": max_seconds, "sample_rss": not isolate}
        if isolate:
            timeout = (max_seconds or 24 * 3600.0) + _CHILD_GRACE_S
            status, result = _run_isolated(global_fix_localizer, (reference, spec, grid_map), kwargs, timeout,
                                           env=None if child_progress else _QUIET_CHILD_ENV)
        else:
            try:
                status, result = "ok", global_fix_localizer(reference, spec, grid_map, **kwargs)
            except Exception as exc:  # noqa: BLE001
                status, result = "error", f"{type(exc).__name__}: {exc}"
        if status != "ok":
            summary[reference.name][spec.name] = {"mode": "global_fixes", "error": str(result).splitlines()[0]}
            continue
        if not result.supported:
            continue
        if result.error:
            summary[reference.name][spec.name] = {"mode": "global_fixes", "error": result.error}
            continue
        fields = {"mode": "global_fixes", "every": every}
        fields.update(metrics.evaluate_global_fixes(result.estimates, result.truths, result.fix_ms, result.recalls))
        fields["failures"] = result.failures
        fields["peak_rss_mb"] = result.peak_rss_mb
        fields["map_setup_s"] = result.map_setup_s
        fields["map"] = map_source
        fields["ground_truth"] = reference.ground_truth is not None
        if result.truncated:
            fields["truncated"] = True
        summary[reference.name][spec.name] = fields
        print(f"rls_bench: {reference.name} / {spec.name}: global_correct_rate {fields['global_correct_rate']}, "
              f"fix {fields['fix_ms_median']} ms", file=sys.stderr, flush=True)
    write_summary(out, summary, title=f"rls_bench --global-fixes (every {every}th scan)")
    return summary


# -- tables ---------------------------------------------------------------------------------------
def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.{digits}g}" if abs(value) < 1e4 else f"{value:.0f}"
    if isinstance(value, list):
        return "[" + ", ".join(_fmt(v, digits) for v in value) + "]" if value else "–"
    if isinstance(value, dict):
        return ", ".join(f"{k} {_fmt(v, digits)}" for k, v in value.items())
    return str(value)


def _one_line(fields: dict[str, Any]) -> str:
    return (f"outputs {fields.get('outputs')}, correct_rate {_fmt(fields.get('correct_rate'))}, "
            f"first fix {_fmt(fields.get('time_to_first_fix_s'))} s, rmse {_fmt(fields.get('rmse_xy_m'))} m, "
            f"update {_fmt(fields.get('update_ms_median'))} ms")


_REPLAY_COLUMNS = (
    ("outputs", "outputs"),
    ("correct_rate", "correct rate"),
    ("fine_rate", "fine rate"),
    ("time_to_first_fix_s", "first fix [s]"),
    ("kidnap_recovery_s", "kidnap recovery [s]"),
    ("kidnap_recovery_updates", "kidnap recovery [updates]"),
    ("kidnap_candidate_recovery_updates", f"truth in top {metrics.CANDIDATE_K} [updates]"),
    ("rmse_xy_m", "RMSE xy [m]"),
    ("rmse_theta_rad", "RMSE θ [rad]"),
    ("update_ms_median", "update median [ms]"),
    ("update_ms_p95", "update p95 [ms]"),
    ("peak_rss_mb", "peak RSS [MB]"),
)
_GLOBAL_COLUMNS = (
    ("fixes", "fixes"),
    ("global_correct_rate", "correct rate"),
    ("global_fine_rate", "fine rate"),
    ("recall_at_k", "recall@k"),
    ("fix_ms_median", "fix median [ms]"),
    ("fix_ms_p95", "fix p95 [ms]"),
    ("peak_rss_mb", "peak RSS [MB]"),
)
_SPECIFIC = ("containment_rate", "containment_rate_after_restart", "correct_place_rate", "heading_error_when_corrected_deg")


def _is_global_fixes(summary: Mapping[str, Mapping[str, Mapping[str, Any]]]) -> bool:
    return any(f.get("mode") == "global_fixes" for runs in summary.values() for f in runs.values())


def summary_table(summary: Mapping[str, Mapping[str, Mapping[str, Any]]]) -> str:
    """One markdown table: a row per (bag, localizer)."""
    columns = _GLOBAL_COLUMNS if _is_global_fixes(summary) else _REPLAY_COLUMNS
    header = ["bag", "localizer", *(title for _, title in columns), "notes"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for bag, runs in summary.items():
        if not runs:
            lines.append(f"| {bag} | – |" + " |" * len(columns) + " no localizer ran |")
        for name, fields in runs.items():
            notes = []
            if "skipped" in fields:
                notes.append(f"skipped: {fields['skipped']}")
            if "error" in fields:
                notes.append(f"error: {fields['error']}")
            for key in _SPECIFIC:
                if key in fields:
                    notes.append(f"{key} {_fmt(fields[key])}")
            if fields.get("truncated"):
                notes.append("truncated by --max-seconds")
            if fields.get("ground_truth") is False:
                notes.append("no ground truth")
            if fields.get("update_errors"):
                notes.append(f"{fields['update_errors']} update errors")
            if "skipped" in fields or ("error" in fields and "outputs" not in fields):
                cells = ["" for _ in columns]
            else:
                cells = [_fmt(fields.get(key)) for key, _ in columns]
            lines.append("| " + " | ".join([bag, name, *cells, "; ".join(notes)]) + " |")
    return "\n".join(lines)


def write_summary(out_dir: Path, summary: Mapping[str, Any], *, title: str) -> None:
    """``summary.json`` (bag -> localizer -> fields) and ``summary.md`` (the table and the definitions)."""
    out_dir = Path(out_dir)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=False) + "\n")
    criteria = (f"correct: |dxy| <= {metrics.CORRECT_XY_M} m and |dθ| <= "
                f"{np.rad2deg(metrics.CORRECT_THETA_RAD):.0f} deg; fine: <= {metrics.FINE_XY_M} m and <= "
                f"{metrics.FINE_THETA_RAD} rad.")
    if _is_global_fixes(summary):
        explanation = ("Each fix is the best candidate of global_fix(scan) for one scan alone, with no prior; "
                       "recall@k: a correct candidate among the first k.")
    else:
        explanation = (f"A fix is a correct output followed by {metrics.FIX_FOLLOWERS} more. Rates and RMSE count "
                       f"outputs from the first fix on; RMSE (the tracking error) leaves out each kidnapping's "
                       f"recovery, from the jump to its recovery fix (at least {metrics.KIDNAP_EXCLUSION_S:.0f} s; "
                       "to the next kidnapping if never recovered).")
    text = [f"# {title}", "", summary_table(summary), "",
            f"{criteria} {explanation} Definitions: README, section Benchmark.", ""]
    (out_dir / "summary.md").write_text("\n".join(text))


# -- command line ---------------------------------------------------------------------------------
def _parse_overrides(items: Sequence[str]) -> dict[str, dict[str, Any]]:
    overrides: dict[str, dict[str, Any]] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        name, dot, param = key.partition(".")
        if not sep or not dot or not name or not param:
            raise ValueError(f"--set expects name.param=value, got {item!r}")
        overrides.setdefault(name, {})[param] = yaml.safe_load(raw)
    return overrides


def _parse_skips(items: Sequence[str]) -> dict[str, dict[str, str]]:
    skips: dict[str, dict[str, str]] = {}
    for item in items:
        name, sep, pattern = item.partition(":")
        if not sep or not name or not pattern:
            raise ValueError(f"--skip expects NAME:BAG_GLOB, got {item!r}")
        skips.setdefault(name, {})[pattern] = "skipped on the command line"
    return skips


def _split_names(values: Sequence[str] | None) -> list[str]:
    return [n for v in values or () for n in v.split(",") if n]


def default_bags_dir() -> Path:
    return registry.config_dir().parent / "bags"


def discover_bags(bags_dir: Path) -> list[Path]:
    """Bag directories (with ``metadata.yaml``) under ``bags_dir``, by name."""
    if not bags_dir.is_dir():
        return []
    return sorted(p for p in bags_dir.iterdir() if (p / "metadata.yaml").is_file())


def _append_section(out: Path, sub: str) -> None:
    """Append ``out/sub/summary.md`` to ``out/summary.md``, its title one level down."""
    extra = (out / sub / "summary.md").read_text().replace("# ", "## ", 1)
    with open(out / "summary.md", "a") as stream:
        stream.write("\n" + extra)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rls_bench",
        description="Replay bags through localizers in-process and measure them against /ground_truth.",
    )
    parser.add_argument("bags", nargs="*", type=Path, help="rosbag2 bag directories")
    parser.add_argument("--localizers", nargs="+", help="names (comma or space separated); default: all available")
    parser.add_argument("--out", type=Path, default=Path("results"), help="output directory (default: results)")
    parser.add_argument("--map", type=Path, default=None, help="map YAML for every bag (default: the bag's /map, "
                        "else config/maps/<bag or prefix>.yaml)")
    parser.add_argument("--mode", choices=("global", "tracking"), default="global",
                        help="global (default): no prior; tracking: the first ground-truth pose on initialpose")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="NAME.PARAM=VALUE",
                        help="override a localizer parameter (YAML value)")
    parser.add_argument("--all", action="store_true", help="every available localizer over every bag in bags/")
    parser.add_argument("--bags-dir", type=Path, default=None, help="where --all looks for bags (default: bags/)")
    parser.add_argument("--skip", action="append", default=[], metavar="NAME:BAG_GLOB",
                        help="with --all, leave this localizer out on matching bags")
    parser.add_argument("--global-fixes", action="store_true", help="single-scan global fixes instead of replays")
    parser.add_argument("--every", type=int, default=10, help="with --global-fixes: use every N-th scan (default: 10)")
    parser.add_argument("--with-global-fixes", action="store_true",
                        help="after the replays, also run --global-fixes into OUT/global_fixes and append its "
                        "table to OUT/summary.md")
    parser.add_argument("--with-tracking", action="store_true",
                        help="after global-mode replays, also replay in tracking mode into OUT/tracking and append "
                        "its table to OUT/summary.md")
    parser.add_argument("--max-seconds", type=float, default=None, help="stop each run after this wall time [s] (default: no limit)")
    parser.add_argument("--in-process", action="store_true", help="run in this process, not one child per run")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log the localizers' warnings and show their precomputation progress bars")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.ERROR, format="%(name)s: %(message)s")
    try:
        overrides = _parse_overrides(args.overrides)
        skips = _parse_skips(args.skip)
        bags = list(args.bags)
        if args.all:
            bags += [b for b in discover_bags(args.bags_dir or default_bags_dir()) if b not in bags]
        if not bags:
            raise ValueError("no bag given (pass BAG... or --all)")
        available = list(registry.PLUGINS)
        names = _split_names(args.localizers) or available
        unknown = [n for n in names if n not in available]
        if unknown:
            raise ValueError(f"localizer(s) {', '.join(unknown)} not available; available: {', '.join(available) or 'none'}")
        if not names:
            raise ValueError("no localizer is available in this checkout")
        specs = []
        for name in names:
            spec = registry_spec(name, overrides.get(name))
            if name in skips:
                spec = LocalizerSpec(spec.name, spec.factory, spec.uses_camera, spec.mount, {**spec.skip, **skips[name]})
            specs.append(spec)
        if args.global_fixes:
            summary = run_global_fixes(bags, specs, args.out, every=args.every, map_yaml=args.map,
                                       isolate=not args.in_process, max_seconds=args.max_seconds,
                                       honour_skips=args.all, child_progress=args.verbose)
        else:
            summary = run_benchmark(bags, specs, args.out, mode=args.mode, map_yaml=args.map,
                                    isolate=not args.in_process, max_seconds=args.max_seconds,
                                    plots=not args.no_plots, honour_skips=args.all, progress=True,
                                    child_progress=args.verbose)
            if args.with_tracking and args.mode == "global":
                print(summary_table(summary))
                summary = run_benchmark(bags, specs, args.out / "tracking", mode="tracking", map_yaml=args.map,
                                        isolate=not args.in_process, max_seconds=args.max_seconds,
                                        plots=not args.no_plots, honour_skips=args.all, progress=True,
                                        child_progress=args.verbose)
                _append_section(args.out, "tracking")
            if args.with_global_fixes:
                print(summary_table(summary))
                summary = run_global_fixes(bags, specs, args.out / "global_fixes", every=args.every,
                                           map_yaml=args.map, isolate=not args.in_process,
                                           max_seconds=args.max_seconds, honour_skips=args.all,
                                           child_progress=args.verbose)
                _append_section(args.out, "global_fixes")
    except (ValueError, KeyError, LocalizationSuiteError, BagError) as exc:
        print(f"rls_bench: error: {exc}", file=sys.stderr)
        return 1
    print(summary_table(summary))
    print(f"\nwritten: {args.out / 'summary.json'}, {args.out / 'summary.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
