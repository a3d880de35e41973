"""Every parameter of ``hybrid_localizer``: its own, and those of the methods it is made of.

The MCL filter, PIL and IR keep their parameters in their own settings classes; here they are
nested under the prefixes ``mcl.``, ``pil.``, ``ir.``, ``ial.`` and ``ima.`` (``mcl.max_particles``). The hybrid's own
parameters say when the global proposals are asked for and what they do to the filter. Why each
mechanism and default: docs/hybrid.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..ial.settings import IALSettings
from ..ima.settings import ImaSettings
from ..ir.settings import IRSettings
from ..mcl.settings import MclSettings
from ..pil.settings import PilSettings
from ..settings import Settings, nested, setting

__all__ = ["HybridSettings"]


def _mcl_settings() -> MclSettings:
    """The filter as the hybrid runs it: the proposals, not Augmented MCL's random particles, recover it
    (an injected fraction must reach 1, which it never does: the fit averages still judge the status); nav2's
    likelihood field without the unmapped-obstacle class, which cost the hybrid more than it gave (docs/hybrid.md,
    "The unmapped-obstacle class"); and updates only after motion, as nav2 (the proposals watch every scan;
    docs/hybrid.md, "Standing still"); its LOCALIZED judged by the proposals, not by the filter's map-vouch gate
    (docs/hybrid.md, "A place the map vouches for")."""
    return MclSettings(recovery_min_injection=1.0, unmapped_obstacle_weight=0.0, standstill_check=False,
                       localized_min_explained=0.0)


@dataclass(frozen=True)
class HybridSettings(Settings):
    """Settings of :class:`~.localizer.HybridLocalizer` (docs/hybrid.md)."""

    mcl: MclSettings = nested(_mcl_settings, prefix="mcl")
    pil: PilSettings = nested(PilSettings, prefix="pil")
    ir: IRSettings = nested(IRSettings, prefix="ir")
    ial: IALSettings = nested(IALSettings, prefix="ial")
    ima: ImaSettings = nested(ImaSettings, prefix="ima")

    pil_every_updates: int = setting(
        1, "PIL's global fix (cheap) runs at every this many filter updates; 0: never", low=0,
        high=1_000_000)
    pil_in_update_while_tracking: bool = setting(
        False, "PIL's global fix runs inside the update while LOCALIZED or AMBIGUOUS too; false: then in a worker "
        "thread, off the tracking path, its answer used from the next update on (always inside the update at start "
        "and while LOST: its answer is wanted at once)")
    ir_every_updates: int = setting(
        10, "while LOCALIZED, IR's global fix (precise, slow, in a worker thread) is asked for at every this many "
        "filter updates; otherwise whenever the worker is free; 0: only while not LOCALIZED", low=0, high=1_000_000)
    proposals_scored: int = setting(
        10, "best candidates of each source scored against the scan at an update", low=1, high=10_000)
    seed_candidates: int = setting(
        10, "at start and on reinitialize the filter is drawn around this many best candidates (K)", low=1,
        high=10_000)
    seed_particles: int = setting(
        5000, "particles of a filter drawn around the candidates (at most mcl.max_particles)", low=1,
        high=10_000_000)
    proposal_std_xy: float = setting(
        0.25, "position standard deviation of the particles drawn around a candidate (seed and injection)",
        unit="m", low=0.0, high=100.0)
    proposal_std_yaw: float = setting(
        0.1, "heading standard deviation of the particles drawn around a candidate (seed and injection)",
        unit="rad", low=0.0, high=math.pi)
    better_log_odds: float = setting(
        3.0, "particles are injected around candidates outside the filter's support once the CUSUM of the best "
        "one's log-odds over the estimate (scan log-likelihoods counted over mcl.effective_beams, as the filter "
        "weighs particles) reaches this", low=0.0, low_open=True, high=1e6)
    better_updates: int = setting(
        2, "unless the filter is LOST or INITIALIZING, the candidate must also have been ahead of the estimate at "
        "this many consecutive updates", low=1, high=1000)
    evidence_where_mapped: bool = setting(
        True, "the recovery's evidence counts only the beams whose end points at the filter's place the map can judge "
        "(not in the unexplored unknown space a laser could see into), each weighing as before: a beam the map "
        "cannot judge there speaks neither for nor against that place, so a robot tracked into space the map has "
        "not seen is not taken by a mapped look-alike elsewhere; and a candidate that ties with the estimate only by "
        "the unknown-space credit (the map judges less of the scan there and explains less of it) is no rival that "
        "makes the state AMBIGUOUS; false: every beam, every candidate (docs/hybrid.md)")
    watch_standing: bool = setting(
        True, "while no filter update is due (the robot stands, or has moved less than mcl.update_min_d / "
        "update_min_a), a scan that contradicts the filter (its fit below mcl.lost_fit_ratio of the average) or comes "
        "while it is not LOCALIZED is still given to PIL in its worker, and a candidate outside the filter's support "
        "that explains one such scan better_log_odds better than the filter's place makes the filter update on it "
        "without motion (a robot carried away while standing); false: nothing is weighed until the robot moves, as "
        "nav2 (ours)")
    support_distance: float = setting(
        0.5, "a candidate is inside the filter's support when particles within this distance ...", unit="m",
        low=0.0, low_open=True, high=100.0)
    support_angle: float = setting(
        0.35, "... and this heading difference ...", unit="rad", low=0.0, low_open=True, high=math.pi)
    support_weight: float = setting(
        0.01, "... hold at least this share of the weight", low=0.0, high=1.0)
    switch_min_explained: float = setting(
        0.9, "a candidate outside the support counts as evidence against the estimate only when at least this "
        "share of the scan's end points lie within two cells of a mapped obstacle there: a place the map cannot "
        "vouch for is no reason to leave the estimate. Where the map refutes the filter's place (at its estimate and "
        "at every candidate within its support it judges at least this share of the end points and explains at "
        "most 1 minus it), a candidate where it explains more than half counts; and so does one where it leaves "
        "unexplained at most half of what it leaves at that place, while the filter, seeded from candidates, has "
        "not been LOCALIZED since; 0: any candidate (docs/hybrid.md)",
        low=0.0, high=1.0)
    inject_fraction: float = setting(
        0.5, "share of the particles replaced by draws around a clearly better candidate", low=0.0, low_open=True,
        high=1.0)
    ambiguity_log_odds: float = setting(
        1.0, "a candidate elsewhere explains the scan as well as the estimate when its log-likelihood (counted as in "
        "better_log_odds) is at least the estimate's minus this: AMBIGUOUS, never LOCALIZED", low=0.0, high=1e6)
    ambiguity_distance: float = setting(
        1.0, "candidates farther than this from the estimate are elsewhere", unit="m", low=0.0, low_open=True,
        high=1e4)
    ambiguity_angle: float = setting(
        0.5, "... or turned more than this from it", unit="rad", low=0.0, low_open=True, high=math.pi)
    wait_for_workers: bool = setting(
        False, "reproducible replay: each worker's result (IR, PIL while tracking, the integrity monitor's IAL "
        "update) is taken at the next update, which waits for it if need be, instead of whenever it ends; the "
        "same bag then gives the same output on any machine and load, and an update's time includes the wait "
        "(docs/hybrid.md)")
    integrity_monitor: bool = setting(
        False, "(off by default: on two cores IAL's global solves take the cores from the updates, and wide boxes "
        "hold LOCALIZED back; docs/hybrid.md) IAL's boxes (ial.*: their declared range_error and max_outliers) as a monitor: an estimate outside "
        "every box, or boxes farther apart than ambiguity_distance, is not LOCALIZED; off by itself on a map with "
        "unknown space a beam can reach and while IAL has no box")
    integrity_margin_xy: float = setting(
        0.25, "an estimate this far outside a box still counts as inside it (its own error)", unit="m", low=0.0,
        high=100.0)
    integrity_margin_yaw: float = setting(
        0.15, "... and this far outside its heading interval", unit="rad", low=0.0, high=math.pi)
    camera_topomap: str = setting(
        "", "topological map YAML (build_topomap) whose places the camera tells apart; empty: no camera. With one, "
        "images on camera/image_raw weigh the particles and the candidates by IMA place recognition (ima.*, "
        "thesis 003), which breaks the laser's ties between look-alike places; relative: the working directory, "
        "then the package's config/", read_only=True)
    camera_weight: float = setting(
        1.0, "exponent of an image's IMA match at a place as its likelihood there (1: as thesis 003 eq. 3.21)",
        low=0.0, high=100.0)
    camera_place_radius: float = setting(
        0.0, "a pose is seen by the camera cue when a place of the topological map lies within this; 0: the median "
        "spacing of its places", unit="m", low=0.0, high=100.0)
    camera_heading_tolerance: float = setting(
        0.5, "the heading IMA finds at that place must agree with the pose's within this, else the image counts "
        "as unlike the place", unit="rad", low=0.0, low_open=True, high=math.pi)
    camera_window: float = setting(
        1.0, "the images of this long before a scan count in its AMBIGUOUS verdict (each image counts once in the "
        "recovery's evidence and in the particles' weights); longer holds look-alikes apart with more images but "
        "also counts images from before a kidnapping", unit="s", low=0.0, high=3600.0)
