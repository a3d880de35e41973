"""Multi-hypothesis topological tracking on IMA place recognition (thesis 003, chapter 3, Code 3.1).

Each update (section 3.8, Code 3.1, section 4.1.5), once the odometry has
moved ``min_translation`` or turned ``min_rotation``: the odometry guess
``d0`` (the anchor plus the displacement since, its direction corrected by the
last heading correction), the destinations IMA finds above ``eps_M`` plus
``d0`` as the virtual destination, the action model ``P(d|o,a)`` of equations
3.14-3.19, prediction and update of the activities (3.21-3.24), the winner
``d*``, and the heading correction from equation 2.2 when
``MATCH(d*) > eps_phi`` (3.7).

Departure from Code 3.1 (``odometry_reset``): by default the odometry guess
is re-anchored at the winner only when vision names a new place, or the same
place with a match that needed no zoom (the thesis' own proposal, 5.2.3 and
6.1); ``"winner"`` keeps Code 3.1 exactly. The published position fuses the odometry and
the recognised places (:mod:`.position`, ``pose_estimate``) instead of being the winner's node.

Notes (the reset in full, choices, status, measured figures): docs/ima.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ImageError
from ..filter.odometry_gate import OdometryGate
from ..localizer import Estimate, LocalizerStatus, Place
from ..se2 import angle_difference, compose, relative, wrap_angle
from .images import to_grey
from .places import PanoramaBank, PlaceMatch
from .position import PlacePositionFilter
from .settings import ODOMETRY_RESETS, ImaTrackerSettings
from .topomap import TopologicalMap

PLAIN_COMPARISON = 0  # PlaceMatch.comparison of image -> panorama without zoom

__all__ = ["ODOMETRY_RESETS", "ImaTrackerSettings", "Hypotheses", "ImaTopoLocalizer", "ImageError", "activity_update"]


@dataclass
class Hypotheses:
    """A set of origins or destinations.

    Attributes:
        node: ``(K,)`` node index of each hypothesis.
        xy: ``(K, 2)`` position [m] (the node's, or a given initial pose).
        heading: ``(K,)`` heading [rad]; NaN when unknown.
        activity: ``(K,)`` activities, summing to 1.
        virtual: ``(K,)`` whether it is the virtual hypothesis of the odometry.
        match: ``(K,)`` ``MATCH`` of the destination (``eps_M`` for the virtual one).
    """

    node: NDArray[np.int64]
    xy: NDArray[np.float64]
    heading: NDArray[np.float64]
    activity: NDArray[np.float64]
    virtual: NDArray[np.bool_]
    match: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.node.shape[0])


def activity_update(
    origins: Hypotheses,
    destination_xy: NDArray[np.float64],
    destination_heading: NDArray[np.float64],
    destination_virtual: NDArray[np.bool_],
    destination_match: NDArray[np.float64],
    displacement: NDArray[np.float64],
    rotation: float,
    *,
    min_sigma_l: float = 0.01,
    min_sigma_phi: float = math.radians(1.0),
) -> NDArray[np.float64]:
    """Activities of the destinations: equations 3.14-3.24.

    Args:
        origins: the origins ``O`` with their activities.
        destination_xy: ``(D, 2)`` positions ``Qd``.
        destination_heading: ``(D,)`` headings ``phi_d`` (NaN unknown).
        destination_virtual: ``(D,)`` which one is the virtual destination.
        destination_match: ``(D,)`` ``MATCH(d)``, the sensor model (3.21).
        displacement: ``(2,)`` odometry displacement in the map frame [m].
        rotation: odometry rotation [rad].

    Returns:
        ``(D,)`` normalised activities ``Act(d)`` (3.24).
    """
    q_a = origins.xy + displacement[None, :]  # (O, 2)
    phi_a = origins.heading + rotation  # (O,)
    delta_l = np.hypot(
        destination_xy[:, None, 0] - q_a[None, :, 0], destination_xy[:, None, 1] - q_a[None, :, 1]
    )  # (D, O), eq. 3.14
    delta_phi = np.asarray(angle_difference(destination_heading[:, None], phi_a[None, :]), dtype=np.float64)  # 3.15
    unknown = np.isnan(delta_phi) | (destination_virtual[:, None] & origins.virtual[None, :])  # footnote 10
    delta_phi = np.where(unknown, 0.0, np.abs(delta_phi))
    sigma_l = max(float(delta_l.max(initial=0.0)), min_sigma_l)
    sigma_phi = max(float(delta_phi.max(initial=0.0)), min_sigma_phi)
    g_l = np.exp(-(delta_l**2) / (2.0 * sigma_l**2)) / (math.sqrt(2.0 * math.pi) * sigma_l)  # 3.16
    g_phi = np.exp(-(delta_phi**2) / (2.0 * sigma_phi**2)) / (math.sqrt(2.0 * math.pi) * sigma_phi)  # 3.17
    action = g_l * g_phi  # 3.18 / 3.19
    predicted = action @ origins.activity  # 3.22
    updated = destination_match * predicted  # 3.23
    total = updated.sum()
    if not np.isfinite(total) or total <= 0.0:
        return np.full(len(updated), 1.0 / len(updated))
    return updated / total  # 3.24


class ImaTopoLocalizer:
    """Camera topological localizer: IMA place recognition + multi-hypothesis tracking.

    Implements :class:`~robot_localization_suite.core.localizer.CameraLocalizer`.

    Args:
        topomap: nodes and panoramas (see :func:`~robot_localization_suite.core.ima.load_topomap`).
        settings: the method's parameters.
    """

    def __init__(self, topomap: TopologicalMap, settings: ImaTrackerSettings | None = None) -> None:
        self.settings = settings or ImaTrackerSettings()
        self.topomap = topomap
        self.bank = PanoramaBank(topomap.panoramas, topomap.hfov_deg, topomap.heading_refs, self.settings.ima)
        self.node_xy = topomap.positions
        self.names = topomap.names
        self._position_sigma = 0.5 * topomap.spacing
        self.position = PlacePositionFilter(self.settings.odometry_drift)
        # The odometry; the reference is the odometry at the last run of Code 3.1.
        self.odometry = OdometryGate(self.settings.min_translation, self.settings.min_rotation)
        self.reinitialize()

    @property
    def _odom(self) -> NDArray[np.float64]:
        """The latest odometry pose (the origin until the first one)."""
        latest = self.odometry.latest
        return np.zeros(3) if latest is None else latest

    # -- CameraLocalizer -------------------------------------------------------------------
    def reinitialize(self) -> None:
        """Global localization: every node an origin with activity 1/N, no winner, no heading correction."""
        count = len(self.node_xy)
        self.origins = Hypotheses(
            node=np.arange(count),
            xy=self.node_xy.copy(),
            heading=np.full(count, np.nan),
            activity=np.full(count, 1.0 / count),
            virtual=np.zeros(count, dtype=bool),
            match=np.zeros(count),
        )
        self._winner_node = -1
        self._reset_odom = self._odom.copy()
        self._anchor_xy: NDArray[np.float64] | None = None
        self._anchor_odom = self._odom.copy()
        self._anchor_node = -1
        self.position.reset()
        self._position_odom = self._odom.copy()
        self._places_since_restart: set[int] = set()
        self._position_given = False
        self.odometry.reset()
        self._heading_offset = 0.0
        self._heading_known = False

    def set_initial_pose(self, pose: ArrayLike, covariance: ArrayLike) -> None:
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        node = int(np.argmin(np.hypot(self.node_xy[:, 0] - pose[0], self.node_xy[:, 1] - pose[1])))
        self.origins = Hypotheses(
            node=np.array([node]),
            xy=pose[None, :2].copy(),
            heading=np.array([pose[2]]),
            activity=np.ones(1),
            virtual=np.zeros(1, dtype=bool),
            match=np.ones(1),
        )
        self._winner_node = node
        self._reset_odom = self._odom.copy()
        self._anchor_xy = pose[:2].copy()
        self._anchor_odom = self._odom.copy()
        self._anchor_node = node
        given = np.asarray(covariance, dtype=np.float64).reshape(-1)
        variance = 0.5 * float(given[0] + given[4]) if given.size == 9 else math.nan  # (3, 3): x and y
        if not (math.isfinite(variance) and variance > 0.0):
            variance = self._position_sigma**2
        self.position.start(pose[:2], variance)
        self._places_since_restart, self._position_given = set(), True
        self._position_odom = self._odom.copy()
        self._heading_offset = float(angle_difference(pose[2], self._odom[2]))
        self._heading_known = True
        self.odometry.request_update()

    def request_nomotion_update(self) -> None:
        self.odometry.request_update()

    def on_odometry(self, stamp: float, odom_pose: ArrayLike) -> None:
        first = self.odometry.latest is None
        if not self.odometry.add(stamp, odom_pose):
            return  # non-finite or older: ignored
        if first:
            # The first odometry defines where the motion since start is measured from.
            self._reset_odom = self._odom.copy()
            self._anchor_odom = self._odom.copy()
            self._position_odom = self._odom.copy()

    def on_image(self, stamp: float, image: ArrayLike) -> Estimate | None:
        """Run Code 3.1 when the robot moved enough since the last run; otherwise return None."""
        try:
            grey = to_grey(image)
        except ValueError as exc:
            raise ImageError(str(exc)) from exc
        if not self.odometry.due(self._odom):
            return None
        self.odometry.mark_updated(self._odom)
        return self._update(float(stamp), grey)

    # -- Code 3.1 --------------------------------------------------------------------------
    def _displacement_since(self, odom_then: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
        """Odometry displacement ``(2,)`` since ``odom_then`` in the map frame (heading-corrected), and rotation."""
        motion = relative(odom_then, self._odom)  # in the frame of the odometry then
        then_heading = odom_then[2] + self._heading_offset  # map heading then
        moved = compose(np.array([0.0, 0.0, then_heading]), motion)
        return moved[:2], float(motion[2])

    def _odometry_action(self) -> tuple[NDArray[np.float64], float, float]:
        """Displacement ``(2,)`` in the map frame, rotation, and the corrected heading now."""
        displacement, rotation = self._displacement_since(self._reset_odom)
        heading_now = float(wrap_angle(self._odom[2] + self._heading_offset))
        return displacement, rotation, heading_now

    def _update(self, stamp: float, image: NDArray[np.uint8]) -> Estimate | None:
        s = self.settings
        displacement, rotation, heading_now = self._odometry_action()
        self.position.predict(self._displacement_since(self._position_odom)[0])
        self._position_odom = self._odom.copy()
        guess_node = -1
        if self._anchor_xy is not None:
            guess = self._anchor_xy + self._displacement_since(self._anchor_odom)[0]
            guess_node = int(np.argmin(np.hypot(self.node_xy[:, 0] - guess[0], self.node_xy[:, 1] - guess[1])))

        place = self.bank.match(image)
        seen = np.nonzero(place.match > s.match_threshold)[0]
        if seen.size == 0:
            if guess_node < 0:
                return None
            return self._supposed(stamp, guess_node, heading_now, place)

        nodes = list(seen)
        xy = [self.node_xy[n] for n in seen]
        headings = list(place.heading[seen])
        virtual = [False] * len(seen)
        matches = list(place.match[seen])
        if guess_node >= 0:
            nodes.append(guess_node)
            xy.append(self.node_xy[guess_node])
            headings.append(heading_now)
            virtual.append(True)
            matches.append(s.match_threshold)
        destination_xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        destination_heading = np.asarray(headings, dtype=np.float64)
        destination_virtual = np.asarray(virtual, dtype=bool)
        destination_match = np.asarray(matches, dtype=np.float64)
        activity = activity_update(
            self.origins,
            destination_xy,
            destination_heading,
            destination_virtual,
            destination_match,
            displacement,
            rotation,
            min_sigma_l=s.min_sigma_l,
            min_sigma_phi=s.min_sigma_phi,
        )
        best = int(np.argmax(activity))
        winner_node = int(nodes[best])
        corrected = bool(destination_match[best] > s.heading_threshold)
        if corrected:
            self._heading_offset = float(angle_difference(destination_heading[best], self._odom[2]))
            self._heading_known = True
        heading = float(wrap_angle(self._odom[2] + self._heading_offset))
        # The action of the next update starts here; the destinations become the origins (O <- D).
        self._reset_odom = self._odom.copy()
        self._winner_node = winner_node
        reset = self._move_anchor(
            winner_node, destination_xy[best], bool(destination_virtual[best]), int(place.comparison[winner_node])
        )
        elsewhere = np.asarray(nodes) != winner_node
        rival = float(activity[elsewhere].max()) if elsewhere.any() else 0.0
        clear = bool(activity[best] >= s.ambiguity_ratio * rival)
        # A place vision recognised measures the position; the virtual destination is the odometry's own guess.
        # A place beyond the gate restarts the position only when vision names it clearly (no rival place within
        # ambiguity_ratio): a near tie is no relocalization, and that place is not fused either.
        restarted = False
        place_xy, place_variance = self.node_xy[winner_node], self._position_sigma**2
        if not destination_virtual[best] and (clear or not self.position.beyond_gate(place_xy, place_variance)):
            restarted = self.position.correct(place_xy, place_variance)
            if restarted:
                self._places_since_restart, self._position_given = set(), False
            self._places_since_restart.add(winner_node)
        confirmed = self._position_given or len(self._places_since_restart) >= s.localized_min_places
        self.origins = Hypotheses(
            node=np.asarray(nodes, dtype=np.int64),
            xy=destination_xy,
            heading=destination_heading,
            activity=activity,
            virtual=destination_virtual,
            match=destination_match,
        )
        order = np.argsort(-activity, kind="stable")
        candidates = np.column_stack([destination_xy, np.where(np.isnan(destination_heading), heading, destination_heading)])
        kind = "virtual" if destination_virtual[best] else "destination"
        # The node stands behind a pose whose heading it could correct (eps_phi); a weaker match names a
        # place but leaves the heading to the odometry. One place recognised from afar puts the position up to
        # its recognition range off: LOCALIZED also needs localized_min_places places since the last restart.
        named = corrected and not destination_virtual[best] and clear and confirmed
        return self._estimate(
            stamp,
            winner_node,
            heading,
            LocalizerStatus.LOCALIZED if named else LocalizerStatus.AMBIGUOUS,
            candidates[order],
            activity[order],
            place,
            kind=kind,
            corrected=corrected,
            match=float(destination_match[best]),
            activity=float(activity[best]),
            destinations=int(len(seen)),
            rival_activity=rival,
            odometry_reset=reset,
            position_restarted=restarted,
            places_since_restart=len(self._places_since_restart),
        )

    def _move_anchor(self, node: int, xy: NDArray[np.float64], virtual: bool, comparison: int) -> bool:
        """Reset the odometry (the anchor of ``d0``) to the winner as ``odometry_reset`` says; True if it moved.

        ``winner``: always (Code 3.1). ``place``: only to a place vision recognised (not the
        virtual destination) that differs from the anchor's. ``zoom``: as ``place``, and
        also to the same place when it matched without zoom (the robot is at the node).
        """
        mode = self.settings.odometry_reset
        if mode == "winner" or self._anchor_xy is None:
            move = True
        elif virtual:
            move = False  # the virtual destination is the odometry's own guess: nothing new to reset to
        elif node != self._anchor_node:
            move = True
        else:
            move = mode == "zoom" and self.bank.zoom_on and comparison == PLAIN_COMPARISON
        if move:
            self._anchor_xy = np.asarray(xy, dtype=np.float64).copy()
            self._anchor_odom = self._odom.copy()
            self._anchor_node = node
        return move

    def _supposed(self, stamp: float, node: int, heading: float, place: PlaceMatch) -> Estimate:
        """No destination: the place nearest the odometry guess, nothing reset (Code 3.1, footnote 21)."""
        candidate = np.array([[*self.node_xy[node], heading]])
        return self._estimate(
            stamp,
            node,
            heading,
            LocalizerStatus.AMBIGUOUS,
            candidate,
            np.ones(1),
            place,
            kind="supposed",
            corrected=False,
            match=float("nan"),
            activity=float("nan"),
            destinations=0,
            odometry_reset=False,
        )

    def _estimate(
        self,
        stamp: float,
        node: int,
        heading: float,
        status: LocalizerStatus,
        candidates: NDArray[np.float64],
        weights: NDArray[np.float64],
        place: PlaceMatch,
        **details: object,
    ) -> Estimate:
        heading_sigma = self.settings.heading_sigma if self._heading_known else math.pi
        position, variance = self.node_xy[node], self._position_sigma**2
        if self.settings.pose_estimate == "fused" and self.position.xy is not None:
            position, variance = self.position.xy, self.position.variance
        covariance = np.diag([variance, variance, heading_sigma**2])
        return Estimate(
            stamp=stamp,
            pose=np.array([position[0], position[1], heading]),
            covariance=covariance,
            status=status,
            candidates=candidates,
            candidate_weights=weights,
            place=Place(self.names[node], self.node_xy[node].copy(), self.node_xy),
            heading_corrected=bool(details.pop("corrected")),
            details={
                "place": self.names[node],
                "place_index": node,
                "hypotheses": int(len(candidates)),
                "best_match": float(np.max(place.match)) if len(place.match) else float("nan"),
                **details,
            },
        )
