"""Single-scan global fixes of one localizer on one bag: a :class:`GlobalFixRecord`.

Every ``every``-th scan alone goes to the localizer's ``global_fix(scan)``, with no prior
and no odometry; its best candidate and its ranked candidates are compared with the
ground truth (``--global-fixes``). Localizers without ``global_fix`` are left out.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ...core import metrics
from ...core.errors import LocalizationSuiteError
from ...core.grid_map import GridMap
from .isolation import rss_mb
from .prepare import prepare_localizer, prepare_scan
from .reference import SCAN_TOPIC, BagReference
from .replay import log_sink
from .specs import LocalizerSpec

__all__ = ["GlobalFixRecord", "global_fix_localizer"]

LOG = logging.getLogger("rls_bench")


@dataclass
class GlobalFixRecord:
    """Single-scan global fixes of one localizer on one bag."""

    bag: str
    localizer: str
    supported: bool
    stamps: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))  # the fixes' scan stamps [s]
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
    from ...ros.adapter import LocalizerAdapter
    from ...ros.bag import read_bag

    if every < 1:
        raise ValueError(f"--every must be >= 1, got {every!r}")
    core = spec.factory()
    record = GlobalFixRecord(bag=reference.name, localizer=spec.name, supported=callable(getattr(core, "global_fix", None)))
    if not record.supported or spec.uses_camera:
        record.supported = False
        return record
    prefix = f"[{reference.name}/{spec.name} global fixes]"
    adapter = LocalizerAdapter(core, node_name=spec.name, log=log_sink(prefix), mount=spec.mount)
    if grid_map is None:
        record.error = "no map"
        return record
    first_scan = prepare_scan(core, reference, spec.mount)
    start = time.perf_counter()
    adapter.set_map(grid_map)
    prepare_localizer(core, first_scan)
    record.map_setup_s = round(time.perf_counter() - start, 3)
    truth = reference.ground_truth
    estimates: list[NDArray[np.float64]] = []
    truths: list[NDArray[np.float64]] = []
    fix_ms: list[float] = []
    stamps: list[float] = []
    deadline = time.monotonic() + max_seconds if max_seconds else np.inf
    peak = rss_mb() if sample_rss else 0.0
    for index, item in enumerate(read_bag(reference.path, [SCAN_TOPIC], remap=reference.remap)):
        if index % every:
            continue
        if time.monotonic() > deadline:
            record.truncated = True
            break
        try:
            scan = adapter.scan_from_msg(item.msg)
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
        stamps.append(scan.stamp)
        if estimate is None:
            record.failures += 1
            estimates.append(np.full(3, np.nan))
            record.recalls.append({k: False for k in metrics.RECALL_KS})
        else:
            pose = adapter.to_base(np.asarray(estimate.pose, dtype=np.float64))
            ranked = np.asarray(estimate.candidates, dtype=np.float64).reshape(-1, 3)
            candidates = adapter.to_base(ranked) if len(ranked) else pose[None, :]
            estimates.append(pose)
            record.recalls.append(metrics.recall_at_k(candidates, true_pose))
        if sample_rss:
            peak = max(peak, rss_mb())
    record.estimates = np.array(estimates).reshape(-1, 3)
    record.truths = np.array(truths).reshape(-1, 3)
    record.fix_ms = np.array(fix_ms)
    record.stamps = np.array(stamps, dtype=np.float64)
    record.peak_rss_mb = round(peak, 1) if sample_rss else None
    return record

