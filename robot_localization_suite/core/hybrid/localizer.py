"""The hybrid localizer: the MCL filter tracks, single-scan global fixes propose (``hybrid_localizer``).

Made of the existing methods, not copies of them: :class:`~..mcl.localizer.MonteCarloLocalizer`
tracks; PIL's global fix (Lambert et al. 2020, milliseconds: in the update while the filter does not
track, else in a worker asked after the update) and IR's (Aycard & Brouard, seed 001 IV-B, in a worker
thread: never in the update) propose ranked poses (:mod:`.proposals`). Every candidate and the filter's
estimate are scored against the scan by one measure, the filter's own scan fit
(:meth:`~..mcl.localizer.MonteCarloLocalizer.scan_fit`), counted over the filter's ``effective_beams`` as
it weighs its particles; the proposals are used

* to start: at start and on :meth:`reinitialize` the filter is drawn around the best candidates
  instead of uniformly over the map;
* to recover: a candidate outside the filter's support that has explained the scans clearly
  better than the estimate (a CUSUM of its log-odds) gets particles injected around it; between
  updates (the robot standing), one scan a candidate explains that much better makes the filter
  update on it;
* as the ambiguity signal: a candidate elsewhere that explains the scan as well as the estimate
  makes the state AMBIGUOUS (never LOCALIZED), the places listed as candidates.

With a camera and a topological map of the places it should tell apart (``camera_topomap``), each
image is one more measurement (:mod:`.camera_cue`, IMA of thesis 003, matched in a worker thread): it
weighs the particles, adds to the recovery's evidence, and counts in the AMBIGUOUS verdict (where it makes
the best guess between places the laser cannot tell apart), so look-alike places are told apart by what they
look like.

Notes (why each mechanism, measured figures): docs/hybrid.md.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent import futures
from concurrent.futures import Future
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ImageError
from ..filter.particles import pose_spread
from ..grid_map import GridMap
from ..ir.global_fix import IRGlobalFixer
from ..localizer import Estimate, LocalizerStatus
from ..mcl.localizer import MonteCarloLocalizer
from ..mcl.sensor_models import unjudged_beams
from ..metrics import scan_explained
from ..pil.localizer import PilLocalizer
from ..scan import Scan
from ..se2 import angle_difference, compose, inverse, relative
from .integrity import IntegrityMonitor
from .proposals import Proposal, ProposalRunner, ProposalSource, Worker, power_of_ten
from .settings import HybridSettings

if TYPE_CHECKING:  # the camera's modules load OpenCV: only a hybrid with a camera imports them
    from ..ima.topomap import TopologicalMap
    from .camera_cue import CameraCue, SeenImage

__all__ = ["HybridSettings", "HybridLocalizer", "ProposalSource"]

_LOG = logging.getLogger(__name__)
# Where the map refutes the filter's place, a candidate counts when the map explains more of the scan's end points
# there than it leaves unexplained; against a start on trial, also when it leaves unexplained at most this share of
# what it leaves at the filter's place (HybridLocalizer._explained; docs/hybrid.md, "A start the map refutes", "The
# campus in 5 honest blocks").
_MOST = 0.5


class HybridLocalizer:
    """MCL tracking with PIL and IR proposals; implements :class:`~..localizer.Localizer`.

    Args:
        settings: the hybrid's settings (the filter's, PIL's and IR's nested in them).
        sources: proposal sources instead of PIL (in the update) and IR (in a worker), e.g. a test's.
        log: ``log(level, text)`` for failing sources; default: the module's logger.
        topomap: the places of ``settings.camera_topomap``, loaded (the camera cue is on only with one).
    """

    def __init__(self, settings: HybridSettings | None = None, *, sources: Sequence[ProposalSource] | None = None,
                 log: Callable[[str, str], None] | None = None, topomap: TopologicalMap | None = None) -> None:
        self.settings = settings or HybridSettings()
        s = self.settings
        self.mcl = MonteCarloLocalizer(s.mcl)
        self._methods: list[Any] = []  # the global fixers that need the map (and prepare)
        self._unprepared: set[int] = set()  # ids of the methods whose last prepare() raised
        if sources is None:
            sources = []
            if s.pil_every_updates > 0:
                pil = PilLocalizer(s.pil)
                self._methods.append(pil)
                sources.append(ProposalSource("pil", pil.global_fix))
            ir = IRGlobalFixer(s.ir)
            self._methods.append(ir)
            sources.append(ProposalSource("ir", ir.global_fix, background=True))
        self.sources = list(sources)
        self.monitor = (IntegrityMonitor(s.ial, s.integrity_margin_xy, s.integrity_margin_yaw, s.ambiguity_distance)
                        if s.integrity_monitor else None)
        self.runner = ProposalRunner(self.sources, log, wait=s.wait_for_workers)
        self.camera: CameraCue | None = None
        if topomap is not None:
            from .camera_cue import CameraCue

            self.camera = CameraCue(topomap, s.ima, weight=s.camera_weight, place_radius=s.camera_place_radius,
                                    heading_tolerance=s.camera_heading_tolerance, window_s=s.camera_window)
        self._images: deque[Future[SeenImage]] = deque()  # images being matched, oldest first
        self._camera_worker = Worker("rls-hybrid-camera")
        self._image_errors = 0
        self._images_used = 0  # images matched and used (for /diagnostics)
        self._images_dropped = 0  # images that came while one was being matched
        self.grid_map: GridMap | None = None
        self._seed_pending = True
        self._on_trial = True  # seeded from candidates and not LOCALIZED since (_explained)
        self._better_count = 0  # consecutive updates with a candidate outside the support ahead of the estimate
        self._evidence = 0.0  # CUSUM of its log-odds (_recover)
        self._updates = 0
        self._pil_answered = False  # PIL answered in this update (no worker query about the same scan)
        self._waiting: list[Proposal] = []  # background results not used by an update yet
        # each source's latest candidates, moved by the odometry to the pose they are kept at (until it answers again)
        self._latest: dict[str, tuple[NDArray[np.float64], NDArray[np.float64] | None]] = {}
        # the place the map vouched for as the best guess while the filter's fit had dropped, and the odometry then
        self._vouched: tuple[NDArray[np.float64], NDArray[np.float64] | None] | None = None
        self.last_estimate: Estimate | None = None

    # -- Localizer protocol ---------------------------------------------------------------
    def set_map(self, grid_map: GridMap) -> None:
        """Use ``grid_map`` in the filter and every global fixer (PIL learns, IR indexes); start from proposals."""
        self.grid_map = grid_map
        self.mcl.set_map(grid_map)
        for method in self._methods:
            method.set_map(grid_map)
        self._unprepared.clear()
        if self.monitor is not None:
            self.monitor.set_map(grid_map)
        self.runner.forget()
        self._waiting = []
        if self.camera is not None:
            self.camera.forget()
            self._images.clear()
        self._restart()

    def prepare(self, scan: Scan) -> None:
        """Precompute PIL's learning and IR's index for this scanner now (a failure is logged: that source is
        then skipped at its queries)."""
        self._unprepared.clear()
        for method in self._methods:
            try:
                method.prepare(scan)
                if isinstance(method, PilLocalizer):
                    method.global_fix(scan)  # its compiled kernels load now, not in the first update
            except Exception as exc:  # noqa: BLE001 - the tracking must not depend on a proposal source
                _LOG.warning("hybrid: preparing %s failed: %s: %s", type(method).__name__, type(exc).__name__, exc)
                self._unprepared.add(id(method))

    def prepared_for(self, scan: Scan) -> bool:
        """Whether every source is prepared for this scan's scanner; one whose preparation failed counts as
        done (it is skipped at its queries, and trying again at every scan would stop the tracking)."""
        return all(id(method) in self._unprepared or method.prepared_for(scan) for method in self._methods)

    def on_odometry(self, stamp: float, odom_pose: NDArray[np.float64]) -> None:
        """Odometry for the filter (and to move proposals from their scan's stamp to the update's)."""
        self.mcl.on_odometry(stamp, odom_pose)
        if self.monitor is not None:
            self.monitor.on_odometry(stamp, odom_pose)

    def set_initial_pose(self, pose: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        """Restart the filter around ``pose`` (no seeding from proposals)."""
        self.mcl.set_initial_pose(pose, covariance)
        if self.monitor is not None:
            self.monitor.set_initial_pose(pose, covariance)
        self._seed_pending = False
        self._on_trial = False
        self._better_count, self._evidence = 0, 0.0
        self._vouched = None

    def reinitialize(self) -> None:
        """Global localization again: the filter restarts from the next proposals (uniform until there are any)."""
        self.mcl.reinitialize()
        self._restart()

    def request_nomotion_update(self) -> None:
        self.mcl.request_nomotion_update()

    def idle(self, seconds: float) -> None:
        """Nothing comes for ``seconds`` (a replay's log time between two inputs, :class:`~..localizer.Idler`):
        the queries, image matches and IAL update in flight get that long to end, as on a robot."""
        deadline = time.monotonic() + max(0.0, seconds)
        self.runner.settle(deadline)
        if self._images:
            futures.wait(list(self._images), timeout=max(0.0, deadline - time.monotonic()))
        if self.monitor is not None:
            self.monitor.wait(max(0.0, deadline - time.monotonic()))

    def close(self) -> None:
        """Stop the proposal, camera and integrity workers."""
        self.runner.close()
        self._camera_worker.close()
        if self.monitor is not None:
            self.monitor.close()

    @property
    def wants_images(self) -> bool:
        """Whether camera images are used (a ``camera_topomap`` was given)."""
        return self.camera is not None

    def on_image(self, stamp: float, image: NDArray[np.uint8]) -> Estimate | None:
        """A camera image, with a ``camera_topomap``: matched against its places in a worker thread (never in the
        tracking update), then used at the next scan (:meth:`_take_images`). One match at a time: an image that
        comes while one is being matched is dropped (all are kept with ``wait_for_workers``). Never an estimate:
        the filter updates on scans.

        Raises:
            ImageError: the image cannot be read (the next one is tried).
        """
        if self.camera is None:
            return None
        from ..ima.images import to_grey

        try:
            grey = to_grey(image)
        except ValueError as exc:
            raise ImageError(str(exc)) from exc
        if self._images and not self._images[-1].done() and not self.settings.wait_for_workers:
            self._images_dropped += 1  # one match at a time: a camera faster than the matching is not queued
            return None
        camera = self.camera
        self._images.append(self._camera_worker.submit(lambda: camera.match(stamp, grey)))
        return None

    def on_scan(self, scan: Scan) -> Estimate | None:
        """Proposals, then the filter update, then the verdict; None when the filter has no update due."""
        self._waiting.extend(self.runner.collect())
        self._take_images()
        if self.grid_map is None:
            return self.mcl.on_scan(scan)
        if self.monitor is not None:
            if self.settings.wait_for_workers:
                self.monitor.wait()  # the boxes of the previous scan, always; this scan's update after the verdict
            else:
                self.monitor.submit(scan)
        gate = self.mcl.odometry
        odom = gate.at(scan.stamp)
        due = gate.forced if odom is None else gate.due(odom)
        standing = (not due and self.settings.watch_standing and not self._seed_pending
                    and self.last_estimate is not None and self._watched(scan, odom))
        notes: dict[str, Any] = {}
        if standing and self._standing_alarm(scan, odom):
            self.mcl.request_nomotion_update()  # carried away while standing: update on this scan
            due, standing = True, False
            notes["update_without_motion"] = True
        pool: NDArray[np.float64] = np.zeros((0, 3))
        self._pil_answered = False
        if due:
            self._updates += 1
            pool = self._proposals(scan, odom, in_update=not self._tracking(self.last_estimate)
                                   or self.settings.pil_in_update_while_tracking)
            notes["proposals"] = len(pool)
            if len(pool):
                fits = self.mcl.scan_fit(pool, scan)
                if self._seed_pending:
                    self._seed(pool, fits)
                    notes["seeded"] = True
                else:
                    notes.update(self._recover(scan, pool, fits, odom))
        estimate = self.mcl.on_scan(scan)
        if not self.mcl.fit_dropped:
            self._vouched = None
        if estimate is not None:
            verdict = self._verdict(scan, estimate, pool)
            was_localized = self.last_estimate is not None and self.last_estimate.status is LocalizerStatus.LOCALIZED
            if due and was_localized and verdict.status is not LocalizerStatus.LOCALIZED and not self._pil_answered:
                # leaving LOCALIZED (a kidnapping, a rival place): what AMBIGUOUS lists must be about this scan
                pool = self._proposals(scan, odom, in_update=True)
                notes["proposals"] = len(pool)
                verdict = self._verdict(scan, estimate, pool)
            if verdict.details.get("pose_from") == "candidate":
                self._vouched = (verdict.pose.copy(), self.mcl.odometry.at(scan.stamp))
            estimate = self._integrity(scan, verdict)
            if estimate.status is LocalizerStatus.LOCALIZED:
                self._on_trial = False
        if due:
            self._ask_in_background(scan, estimate)
        elif standing:
            self._ask_while_standing(scan)
        if self.monitor is not None and self.settings.wait_for_workers:
            self.monitor.submit(scan)
        if estimate is None:
            return None
        if self.camera is not None:
            notes.update(camera_images=self._images_used, camera_image_errors=self._image_errors,
                         camera_images_dropped=self._images_dropped)
        estimate = replace(estimate, details={**estimate.details, **notes, **self.runner.details(),
                                              "better_updates": self._better_count})
        self.last_estimate = estimate
        return estimate

    # -- internals --------------------------------------------------------------------------
    def _take_images(self) -> None:
        """The images matched since the last scan, in order (all of them with ``wait_for_workers``): each kept for
        the verdict and the recovery, and every particle and rival weighed by it (moved to its time)."""
        camera = self.camera
        while camera is not None and self._images and (self._images[0].done() or self.settings.wait_for_workers):
            try:
                seen = self._images.popleft().result()
            except Exception as exc:  # noqa: BLE001 - a bad image is skipped, the tracking goes on
                self._image_errors += 1
                if power_of_ten(self._image_errors):
                    _LOG.warning("hybrid: image matching failed (%d times so far), skipped: %s: %s",
                                 self._image_errors, type(exc).__name__, exc)
                continue
            camera.add(seen)
            self._images_used += 1
            if self.grid_map is not None:
                # the particles (and the filter's rivals) are at the filter's last update
                self.mcl.weigh(functools.partial(self._camera_evidence, odom=self.mcl.odometry.reference,
                                                 images=[seen]))

    def _restart(self) -> None:
        self._seed_pending = True
        self._on_trial = True
        self._latest = {}
        self._vouched = None
        self._better_count, self._evidence = 0, 0.0

    def _log_odds(self, fits: NDArray[np.float64]) -> NDArray[np.float64]:
        """Scan fits as the filter weighs particles: ``effective_beams`` times the per-beam log-likelihood."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(self.settings.mcl.effective_beams * np.log(fits), dtype=np.float64)

    def _proposals(self, scan: Scan, odom: NDArray[np.float64] | None, *, in_update: bool) -> NDArray[np.float64]:
        """The candidates of this update ``(C, 3)``: each source's latest, moved by the odometry since their scan.

        ``in_update``: PIL answers now, about this scan (at start, while the filter does not track, and when the
        verdict leaves LOCALIZED: its answer is wanted at once). Otherwise the sources' answers come from their
        workers, asked after the update before (:meth:`_ask_in_background`), and count from the first update
        after they have come in.
        """
        s = self.settings
        found: list[Proposal] = []
        if in_update and self._pil_due():
            self._pil_answered = True
            for source in self.sources:
                if not source.background:
                    found.extend(self.runner.ask(source.name, scan, background=False))
        found.extend(self._waiting)
        self._waiting = []
        for proposal in sorted(found, key=lambda proposal: proposal.stamp):  # a source's newest answer is kept
            self._latest[proposal.source] = (proposal.candidates[: s.proposals_scored],
                                             self.mcl.odometry.at(proposal.stamp))
        poses = []
        for name, (candidates, then) in self._latest.items():
            if then is not None and odom is not None:
                candidates = compose(candidates, relative(then, odom))
                self._latest[name] = (candidates, odom)
            poses.append(candidates)
        return np.vstack(poses) if poses else np.zeros((0, 3))

    def _tracking(self, estimate: Estimate | None) -> bool:
        """Whether the filter tracks (one place, or rival places it weighs): proposals can then come from a worker."""
        return (estimate is not None and not self._seed_pending
                and estimate.status in (LocalizerStatus.LOCALIZED, LocalizerStatus.AMBIGUOUS))

    def _pil_due(self) -> bool:
        every = self.settings.pil_every_updates
        return every > 0 and self._updates % every == 0

    def _ask_in_background(self, scan: Scan, estimate: Estimate | None) -> None:
        """After an update, the worker queries about its scan: they run while the node waits for the next scan,
        off the tracking path. PIL while the filter tracks (unless it answered in this update); IR whenever its
        worker is free while the filter was not LOCALIZED, at every ``ir_every_updates``-th update while it was."""
        s = self.settings
        localized = self.last_estimate is not None and self.last_estimate.status is LocalizerStatus.LOCALIZED
        for source in self.sources:
            if self.runner.in_flight(source.name):
                continue
            if not source.background:
                if self._tracking(estimate) and self._pil_due() and not self._pil_answered:
                    self.runner.ask(source.name, scan, background=True)
            elif not localized or (s.ir_every_updates > 0 and self._updates % s.ir_every_updates == 0):
                self.runner.ask(source.name, scan)

    def _watched(self, scan: Scan, odom: NDArray[np.float64] | None) -> bool:
        """Whether a scan with no update due is looked at: the filter is not LOCALIZED, or the scan contradicts it
        (its fit at the filter's pose collapsed, :meth:`~..mcl.localizer.MonteCarloLocalizer.contradicts`). While
        the filter tracks and the scans agree with it, no source is asked between updates (PIL's cost stays that
        of the updates)."""
        last = self.mcl.last_estimate
        return last is None or last.status is not LocalizerStatus.LOCALIZED or self.mcl.contradicts(scan, odom)

    def _ask_while_standing(self, scan: Scan) -> None:
        """A watched scan with no update due (:meth:`_watched`): the sources that answer in the update (PIL, cheap)
        are asked about it in their worker, so that :meth:`_standing_alarm` weighs fresh candidates."""
        for source in self.sources:
            if not source.background and not self.runner.in_flight(source.name):
                self.runner.ask(source.name, scan, background=True)

    def _standing_alarm(self, scan: Scan, odom: NDArray[np.float64] | None) -> bool:
        """Whether a scan with no update due (the robot stands, or has not moved ``mcl.update_min_d`` since the last
        update) shows a kidnapping: the best candidate outside the filter's support explains this one scan
        ``better_log_odds`` better than the filter's place. Such scans are not summed (a standing robot's repeat one
        measurement, and nav2 does not update on them): the slow evidence of a look-alike place stays the updates'
        (:meth:`_recover`). The filter then updates on this scan without motion, and the recovery runs as at any
        update."""
        pool = self._proposals(scan, odom, in_update=False)
        if len(pool) == 0:
            return False
        found = self._outside_advantage(scan, pool, self.mcl.scan_fit(pool, scan), odom, ())
        return found is not None and found[0] >= self.settings.better_log_odds

    def _seed(self, pool: NDArray[np.float64], fits: NDArray[np.float64]) -> None:
        """Start the filter around the ``seed_candidates`` best-fitting candidates, as many particles each."""
        s = self.settings
        order = np.argsort(-np.nan_to_num(fits, nan=-1.0), kind="stable")[: s.seed_candidates]
        self.mcl.seed_from_poses(pool[order], np.ones(len(order)), min(s.seed_particles, s.mcl.max_particles),
                                 s.proposal_std_xy, s.proposal_std_yaw)
        self._seed_pending = False
        self._better_count, self._evidence = 0, 0.0

    def _recover(self, scan: Scan, pool: NDArray[np.float64], fits: NDArray[np.float64],
                 odom: NDArray[np.float64] | None) -> dict[str, Any]:
        """Inject particles around candidates outside the filter's support once they have explained the scans
        clearly better than its estimate (moved to this scan by the odometry).

        The evidence is Page's CUSUM of the log-odds of the best candidate outside the support over the filter's
        place (the better of its estimate and the candidates within its support), ``e <- max(0, e + a)``: a
        kidnapping's large advantage crosses ``better_log_odds`` at once, the small steady one of a look-alike place
        once the scans start to differ, and a candidate that does worse takes evidence away. Unless the filter is
        LOST or INITIALIZING the advantage must also have held for ``better_updates`` updates in a row.
        """
        s = self.settings
        last = self.mcl.last_estimate
        if last is None or len(self.mcl.particles) == 0:
            return {}
        images = self.camera.take_new(scan.stamp) if self.camera is not None else ()  # each once in the sum
        found = self._outside_advantage(scan, pool, fits, odom, images)
        if found is None:
            self._evidence, self._better_count = 0.0, 0
            return {"switch_evidence": 0.0}
        step, advantage, outside, back = found
        self._evidence = max(0.0, self._evidence + step)
        self._better_count = self._better_count + 1 if step > 0.0 else 0
        notes: dict[str, Any] = {"best_outside_log_odds": round(step, 3), "switch_evidence": round(self._evidence, 3)}
        # A filter whose own fit holds (LOCALIZED) or that weighs rival places (AMBIGUOUS) is contradicted only by
        # evidence over better_updates updates; one that has lost its fit (or never converged) has nothing to protect.
        needed = 1 if last.status in (LocalizerStatus.LOST, LocalizerStatus.INITIALIZING) else s.better_updates
        if self._evidence < s.better_log_odds or self._better_count < needed:
            return notes
        # around each candidate ahead of the estimate in proportion to its likelihood for this scan (the share a
        # Bayes update would give it from a uniform prior): look-alikes of the best get theirs, worse ones little
        chosen = np.flatnonzero(outside & (advantage > 0.0))
        share = np.exp(advantage[chosen] - advantage[chosen].max())
        std_xy, std_yaw = self._injection_spread(last)
        notes["injected"] = self.mcl.inject_around(back[chosen], share, s.inject_fraction, std_xy, std_yaw)
        self._evidence, self._better_count = 0.0, 0
        return notes

    def _outside_advantage(self, scan: Scan, pool: NDArray[np.float64], fits: NDArray[np.float64],
                           odom: NDArray[np.float64] | None, images: Sequence[SeenImage]
                           ) -> tuple[float, NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]] | None:
        """The recovery's step on this scan (and ``images``): the best log-odds of a candidate outside the filter's
        support that the map vouches for over the filter's place, with every candidate's advantage, which ones are
        such, and the candidates in the particles' frame (before this update's motion); None without one. With
        ``evidence_where_mapped`` every place is scored on the beams the map can judge at the filter's place
        (:meth:`_mapped_at`), scaled by their share; None when it judges none."""
        s, last = self.settings, self.mcl.last_estimate
        if last is None or len(self.mcl.particles) == 0:
            return None
        delta = self.mcl.odometry_since_update(odom)
        predicted = compose(last.pose, delta)
        scored, share = scan, 1.0
        if s.evidence_where_mapped:
            judged, share = self._mapped_at(scan, predicted)
            if share == 0.0:
                return None  # the map judges none of the scan at the filter's place: no evidence either way
            if share < 1.0:  # every place scored on the beams the map judges at the filter's place
                scored, fits = judged, self.mcl.scan_fit(pool, judged)
        own = self._log_odds(self.mcl.scan_fit(predicted[None, :], scored))
        scores = share * np.nan_to_num(np.concatenate([own, self._log_odds(fits)]), nan=-math.inf)
        if images:
            scores = scores + self._camera_evidence(np.vstack([predicted[None, :], pool]), odom, images)
        back = compose(pool, inverse(delta))
        inside = self._support(back) >= s.support_weight
        # The filter's place scores as the better of its estimate and the candidates within its support: candidates
        # (fitted poses) against candidates, so that where two places explain the scans equally the CUSUM does not
        # drift up only because a fitted pose beats the filter's mean.
        reference = self._place_score(scores[0], scores[1:], inside)
        advantage = np.nan_to_num(scores[1:] - reference, nan=-math.inf)
        outside = ~inside
        if outside.any():
            place = np.vstack([predicted[None, :], pool[inside]])  # the filter's place: its poses, as reference
            outside[outside] = self._explained(scan, pool[outside], against=place)
        if not outside.any() or not np.isfinite(advantage[outside]).any():
            return None
        return float(advantage[outside].max()), advantage, outside, back

    def _mapped_at(self, scan: Scan, pose: NDArray[np.float64]) -> tuple[Scan, float]:
        """The hits of ``scan`` whose end points seen from ``pose`` the map can judge, as a scan, and their share of
        the hits (1 without a hit): all but those in unknown space a laser could see into (``GridMap.open_unknown``,
        the map's unexplored parts, or off the map) that the beam reaches through no mapped obstacle, as the
        filter's partial-map credit. An end point on a known cell, in unknown space sealed off by walls, or behind
        a mapped wall says the pose is wrong or right."""
        known = self._judged_hits(scan, pose[None, :])[0]
        if len(known) == 0:
            return scan, 1.0
        keep = np.flatnonzero(scan.hit_mask)[known]
        judged = Scan(scan.stamp, scan.angles[keep], scan.ranges[keep], scan.range_min, scan.range_max)
        return judged, float(known.mean())

    def _ties_by_unexplored_space(self, scan: Scan, pose: NDArray[np.float64],
                                  places: NDArray[np.float64]) -> NDArray[np.bool_]:
        """``(K,)`` whether each of ``places`` scores as well as ``pose`` only by the unknown-space credit: the map
        judges a smaller share of the scan's hits there (:meth:`_mapped_at`) and explains a smaller share of them
        (end points near a mapped obstacle). A place the map judges as much, or explains as much, stays a rival:
        twins of a mapped place, and the true place when the map contradicts a wrong estimate."""
        shares = self._map_shares(scan, np.vstack([pose[None, :], places]))
        if shares is None:
            return np.zeros(len(places), dtype=bool)
        judged, explained = shares
        return np.asarray((judged[1:] < judged[0]) & (explained[1:] < explained[0]), dtype=bool)

    def _map_shares(self, scan: Scan, poses: NDArray[np.float64]
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """``(K,)`` twice: per pose, the share of the scan's hits the map can judge there (:meth:`_mapped_at`) and
        the share it explains (end points near a mapped obstacle); None without a hit."""
        assert self.grid_map is not None
        known = self._judged_hits(scan, poses)
        if known.shape[1] == 0:
            return None
        return known.mean(axis=1), scan_explained(self.grid_map, poses, scan)

    def _judged_hits(self, scan: Scan, poses: NDArray[np.float64]) -> NDArray[np.bool_]:
        """``(K, H)`` per pose, whether the map can judge each hit's end point there (:meth:`_mapped_at`): all but
        those the filter's sensor model credits as unknown space (``sensor_models.unjudged_beams``)."""
        assert self.grid_map is not None
        return ~unjudged_beams(self.grid_map, poses, *scan.hits())

    @staticmethod
    def _place_score(own: float, others: NDArray[np.float64], near: NDArray[np.bool_]) -> float:
        """The filter's place's log-odds: the better of its estimate's ``own`` and the candidates ``near`` it."""
        return max(float(own), float(np.nan_to_num(others[near], nan=-math.inf).max(initial=-math.inf)))

    def _injection_spread(self, last: Estimate) -> tuple[float, float]:
        """Position and heading spread of particles injected around a candidate: the filter's own cluster's (its
        estimate's covariance), at most ``proposal_std_*``. The injected place is then weighed against the filter's
        as sure of itself as the filter is: a wider draw would lose the comparison by its spread, not its place."""
        s = self.settings
        covariance = last.covariance
        if covariance is None or not np.all(np.isfinite(covariance)):
            return s.proposal_std_xy, s.proposal_std_yaw
        std_xy, std_yaw = pose_spread(covariance)
        return min(std_xy, s.proposal_std_xy), min(std_yaw, s.proposal_std_yaw)

    def _camera_evidence(self, poses: NDArray[np.float64], odom: NDArray[np.float64] | None,
                         images: Sequence[SeenImage]) -> NDArray[np.float64]:
        """``(N,)`` summed camera log-likelihood of poses at odometry ``odom`` for ``images``, each pose moved to
        an image's time by the odometry (unmoved where the odometry does not reach)."""
        assert self.camera is not None
        total = np.zeros(len(poses))
        for seen in images:
            then = self.mcl.odometry.at(seen.stamp)
            moved = poses if odom is None or then is None else compose(poses, relative(odom, then))
            total += self.camera.log_likelihood(moved, seen)
        return total

    def _support(self, poses: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(K,)`` the filter's weight within ``support_distance`` and ``support_angle`` of each of ``poses``."""
        s, particles = self.settings, self.mcl.particles
        close = np.hypot(particles[None, :, 0] - poses[:, None, 0],
                         particles[None, :, 1] - poses[:, None, 1]) <= s.support_distance
        turned = np.abs(angle_difference(particles[None, :, 2], poses[:, None, 2])) <= s.support_angle
        return np.asarray((close & turned) @ self.mcl.weights, dtype=np.float64)

    def _elsewhere(self, poses: NDArray[np.float64], pose: NDArray[np.float64]) -> NDArray[np.bool_]:
        s = self.settings
        far = np.hypot(poses[:, 0] - pose[0], poses[:, 1] - pose[1]) > s.ambiguity_distance
        return np.asarray(far | (np.abs(angle_difference(poses[:, 2], pose[2])) > s.ambiguity_angle), dtype=bool)

    def _integrity(self, scan: Scan, estimate: Estimate) -> Estimate:
        """No LOCALIZED against IAL's boxes (the estimate moved back by odometry to their scan), when the monitor
        is on."""
        if self.monitor is None:
            return estimate
        pose = estimate.pose
        gate = self.mcl.odometry
        now, then = gate.at(scan.stamp), gate.at(self.monitor.boxes_stamp)
        if now is not None and then is not None:
            pose = compose(pose, relative(now, then))
        allowed, details = self.monitor.judge(pose)
        status = estimate.status
        if not allowed and status is LocalizerStatus.LOCALIZED:
            status = LocalizerStatus.AMBIGUOUS
        return replace(estimate, status=status, details={**estimate.details, **details})

    def _verdict(self, scan: Scan, estimate: Estimate, pool: NDArray[np.float64]) -> Estimate:
        """AMBIGUOUS when a candidate elsewhere explains the scan as well as the estimate; else the filter's own
        status (LOCALIZED only when converged)."""
        s = self.settings
        if len(pool) == 0:
            return estimate
        poses = np.vstack([estimate.pose[None, :], pool])
        laser = self._log_odds(self.mcl.scan_fit(poses, scan))
        scores = laser
        if self.camera is not None:
            scores = laser + self._camera_evidence(poses, self.mcl.odometry.at(scan.stamp),
                                                   self.camera.window(scan.stamp))
        own, others = scores[0], scores[1:]
        if not np.isfinite(own):
            return estimate
        elsewhere = self._elsewhere(pool, estimate.pose)
        here = self._place_score(own, others, ~elsewhere)  # as in the recovery (_recover)
        rivals = np.flatnonzero(elsewhere & (np.nan_to_num(others, nan=-math.inf) >= here - s.ambiguity_log_odds))
        if rivals.size and s.evidence_where_mapped:
            rivals = rivals[~self._ties_by_unexplored_space(scan, estimate.pose, pool[rivals])]
        details = {**estimate.details, "estimate_log_fit": round(float(own), 3), "rivals": 0}
        if rivals.size == 0:
            return replace(estimate, details=details)
        # one rival a place: the best-scoring candidate of each, best first
        places: list[int] = []
        for k in rivals[np.argsort(-others[rivals], kind="stable")]:
            if all(self._elsewhere(pool[[k]], pool[j])[0] for j in places):
                places.append(int(k))
        poses = np.vstack([estimate.pose[None, :], pool[places]])
        log_weights = np.concatenate([[here], others[places]])
        weights = np.exp(log_weights - log_weights.max())
        details["rivals"] = len(places)
        pose, covariance = estimate.pose, estimate.covariance
        # The best guess is the rival (listed first, with a candidate's spread; the filter follows once the recovery's
        # evidence has held for better_updates updates) when the scan contradicts the filter (its fit dropped as at a
        # kidnapping) and the rival explains it as clearly better as a recovery needs, where the map vouches for it;
        # or when the camera tells it apart from a look-alike of the filter's place (_camera_breaks_tie).
        if (self.mcl.fit_dropped and others[places[0]] - here >= s.better_log_odds
                and self._explained(scan, pool[places[:1]])[0]):
            details["pose_from"] = "candidate"
        elif self._camera_breaks_tie(scan, laser, others[places[0]] - here, places[0], elsewhere, pool):
            details["pose_from"] = "camera"
        if "pose_from" in details:
            order = [1, 0, *range(2, len(poses))]
            poses, weights = poses[order], weights[order]
            pose = poses[0].copy()
            covariance = np.diag([s.proposal_std_xy**2, s.proposal_std_xy**2, s.proposal_std_yaw**2])
        return replace(estimate, pose=pose, covariance=covariance, status=LocalizerStatus.AMBIGUOUS, candidates=poses,
                       candidate_weights=weights / weights.sum(), details=details)

    def _camera_breaks_tie(self, scan: Scan, laser: NDArray[np.float64], lead: float, rival: int,
                           elsewhere: NDArray[np.bool_], pool: NDArray[np.float64]) -> bool:
        """Whether the verdict's best rival ``pool[rival]`` is the best guess by the camera, a look-alike the laser
        cannot tell apart: by the laser alone (``laser``: the estimate's log-odds, then each candidate's) it is
        within ``ambiguity_log_odds`` of the filter's place or ahead of it, and the images of ``camera_window`` put
        it more than ``ambiguity_log_odds`` further ahead (``lead``: its log-odds over the filter's place, laser
        and images), and the map vouches for it."""
        s = self.settings
        if self.camera is None:
            return False
        laser_lead = laser[1 + rival] - self._place_score(laser[0], laser[1:], ~elsewhere)
        return bool(laser_lead >= -s.ambiguity_log_odds and lead - laser_lead > s.ambiguity_log_odds
                    and self._explained(scan, pool[[rival]])[0])

    def _count_against(self, scan: Scan, explained: NDArray[np.float64],
                       place: NDArray[np.float64]) -> NDArray[np.bool_]:
        """``(K,)`` whether poses whose shares of ``scan`` the map explains are ``explained`` count against the filter's
        place, its ``(P, 3)`` poses (:meth:`_explained`). Only where the map judges (:meth:`_mapped_at`) at least
        ``switch_min_explained`` of the end points at each of them: all count where it refutes the place (explains
        at most ``1 - switch_min_explained`` at each); while a seeded start is on trial, those where it leaves
        unexplained at most half of what it leaves at the best of them."""
        s = self.settings
        none = np.zeros(len(explained), dtype=bool)
        shares = self._map_shares(scan, place)
        if shares is None or not np.all(shares[0] >= s.switch_min_explained):
            return none
        at_place = shares[1]
        if np.all(at_place <= 1.0 - s.switch_min_explained):
            return ~none
        if not self._on_trial:
            return none
        return np.asarray(1.0 - explained <= _MOST * (1.0 - at_place.max()), dtype=bool)

    def _explained(self, scan: Scan, poses: NDArray[np.float64],
                   against: NDArray[np.float64] | None = None) -> NDArray[np.bool_]:
        """``(K,)`` whether the map vouches for each pose: ``switch_min_explained`` of the scan's end points lie near
        a mapped obstacle there (no hit cannot be judged: True). Given the filter's place ``against`` (its predicted
        pose and the candidates within its support), where the map refutes that place a pose also counts where the
        map explains more of the scan's end points than it leaves unexplained. The map refutes a pose, the mirror of
        vouching, when it can judge (:meth:`_mapped_at`) at least ``switch_min_explained`` of the end points there
        and explains at most ``1 - switch_min_explained``; it refutes the place when it refutes each of its poses:
        the candidates are fitted to the scan, the prediction is not, and on long beams a pose a degree off in
        heading leaves most end points unexplained where the place is right. While a start seeded from candidates
        has not been LOCALIZED, a pose the map explains more than half of also counts where it leaves unexplained at
        most half of what it leaves at the best pose of the place, judged there as above (:meth:`_count_against`):
        outdoors the truth itself is seldom explained at ``switch_min_explained``.
        While the filter's fit stays dropped and the map vouches for none of ``poses``, the
        place it vouched for as the best guess (moved by the odometry) stays vouched for: a person beside the robot
        after a kidnapping hides walls from the later scans, not the place."""
        s = self.settings
        if s.switch_min_explained <= 0.0 or self.grid_map is None:
            return np.ones(len(poses), dtype=bool)
        explained = scan_explained(self.grid_map, poses, scan)
        vouched = ~(explained < s.switch_min_explained)
        if against is not None:
            most = ~vouched & (explained > _MOST)
            if most.any():
                vouched |= most & self._count_against(scan, explained, against)
        if self._vouched is not None and self.mcl.fit_dropped and not vouched.any():
            place, then = self._vouched
            now = self.mcl.odometry.at(scan.stamp)
            if then is not None and now is not None:
                place = compose(place, relative(then, now))
            vouched |= ~self._elsewhere(poses, place)
        return np.asarray(vouched, dtype=bool)
