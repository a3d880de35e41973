"""IMA place recognition and multi-hypothesis tracking (thesis 003, chapters 2-3, appendix A)."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from robot_localization_suite.core.errors import MapError
from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.ima.matching import best_matching, ima, match_slots, slot_values
from robot_localization_suite.core.ima.panorama import build_panorama, heading_from_col, panorama_width
from robot_localization_suite.core.ima.places import PanoramaBank, PlaceMatch
from robot_localization_suite.core.ima.settings import ImaSettings
from robot_localization_suite.core.ima.topomap import TopologicalMap, TopoNode, load_topomap, save_topomap
from robot_localization_suite.core.ima.tracking import (
    Hypotheses,
    ImageError,
    ImaTopoLocalizer,
    ImaTrackerSettings,
    activity_update,
)
from robot_localization_suite.core.localizer import LocalizerStatus
from robot_localization_suite.core.se2 import angle_difference
from robot_localization_suite.core.sim.camera import CameraRenderer
from robot_localization_suite.tools.build_topomap import snapshot_turns

HFOV = 60.0
PLACES = {"WEST": (1.5, 2.0), "MIDDLE": (3.5, 2.0), "EAST": (5.5, 3.0)}


def _world() -> GridMap:
    """A 7 m x 5 m room at 5 cm with two boxes, so the three places see different scenes."""
    data = np.zeros((100, 140), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    data[60:80, 40:60] = 100  # box x 2-3, y 3-4
    data[10:24, 96:110] = 100  # box x 4.8-5.5, y 0.5-1.2
    return GridMap(data, 0.05, (0.0, 0.0))


@pytest.fixture(scope="module")
def camera() -> CameraRenderer:
    return CameraRenderer(_world(), width=160, height=120, texture_seed=7, lighting_variation=0.2)


@pytest.fixture(scope="module")
def true_panoramas(camera: CameraRenderer) -> list[np.ndarray]:
    """Ground-truth cylindrical panoramas of the places (column 0 looks at heading 0 + hfov/2)."""
    width = panorama_width(160, HFOV)
    return [camera.render_panorama(np.array([x, y, 0.0]), width) for x, y in PLACES.values()]


@pytest.fixture(scope="module")
def bank(true_panoramas: list[np.ndarray]) -> PanoramaBank:
    return PanoramaBank(true_panoramas, HFOV, 0.0, ImaSettings())


def _topomap(true_panoramas: list[np.ndarray]) -> TopologicalMap:
    nodes = [TopoNode(name, x, y, f"{name}.png", 0.0) for name, (x, y) in PLACES.items()]
    return TopologicalMap(nodes, HFOV, list(true_panoramas))


# -- NCC and IMA ---------------------------------------------------------------------
def test_ncc_is_cv2_match_template_mapped_to_unit_interval() -> None:
    rng = np.random.default_rng(0)
    panorama = cv2.GaussianBlur(rng.uniform(0, 255, (58, 300)).astype(np.float32), (5, 5), 1.5)
    image = panorama[:, 40:112] + rng.normal(0, 8, (58, 72)).astype(np.float32)
    values = slot_values(image, panorama, 8)
    wide = panorama.astype(np.float64)
    for n in range(8):
        slot = np.ascontiguousarray(image[:, 9 * n : 9 * n + 9])
        # equation A.1 in float64: the gemm backend agrees to 2.3e-7 here (float32 inputs)
        template = slot.astype(np.float64) - slot.mean(dtype=np.float64)
        exact = np.empty(panorama.shape[1] - 8)
        for c in range(exact.size):
            window = wide[:, c : c + 9] - wide[:, c : c + 9].mean()
            exact[c] = (window * template).sum() / math.sqrt((window * window).sum() * (template * template).sum())
        assert np.allclose(values[n, : exact.size], (exact + 1.0) / 2.0, atol=1e-6)  # equation A.4
        # cv2.matchTemplate accumulates in float32: 1.15e-5 from A.1 on these data (1.6e-5 at worst over seeds
        # 0-19), so OpenCV is held to 5e-5, not to the float64 tolerance above
        reference = cv2.matchTemplate(panorama, slot, cv2.TM_CCOEFF_NORMED)[0]
        assert np.allclose(values[n, : reference.size], (reference + 1.0) / 2.0, atol=5e-5)
    assert np.allclose(slot_values(image, panorama, 8, backend="opencv"), values, atol=5e-5)


def test_an_image_cut_from_a_panorama_matches_near_one_at_its_column_across_the_wrap(bank: PanoramaBank) -> None:
    panorama = bank.panoramas[0]
    width = panorama.shape[1]
    for col in (17, 200, width - 30):  # the last one runs past the right edge and wraps to the left
        cut = np.take(panorama, np.arange(col, col + 72), axis=1, mode="wrap")
        result = ima(cut, panorama, 8)
        assert result.col == col
        assert result.match > 0.99
    other = ima(np.take(bank.panoramas[1], np.arange(100, 172), axis=1, mode="wrap"), panorama, 8)
    assert other.match < 0.6  # a view of another place does not match


def test_code_2_1_keeps_the_best_slot_and_code_2_2_finds_the_ordered_sequence() -> None:
    # 3 slots of width 2 over a 10-column reference; slot n matches best at column 2 + 2 (n - 1).
    values = np.full((3, 10), 0.55, dtype=np.float32)
    values[0, 2], values[1, 4], values[2, 6] = 0.9, 0.8, 0.7
    values[1, 8] = 0.95  # slot 2 also matches well out of order: the mask ignores it
    match_slot, match_val = match_slots(values)
    assert match_slot.tolist() == [1, 1, 1, 1, 2, 1, 3, 1, 2, 1]  # ties (0.55) keep slot 1
    best, col = best_matching(match_slot, match_val, 3, 2)
    assert int(col) == 2
    assert float(best) == pytest.approx((0.9 + 0.8 + 0.7) / 3)


def test_code_2_3_adds_the_mean_of_the_previous_slots_over_black_zones() -> None:
    # A black zone (value exactly 0.5) after two matched slots: slots 3 and 4 add the running mean.
    match_slot = np.array([1, 1, 2, 1, 1, 1, 1, 1])
    match_val = np.array([0.5, 0.8, 0.6, 0.5, 0.5, 0.5, 0.5, 0.5], dtype=np.float32)
    plain, _ = best_matching(match_slot, match_val, 4, 1)
    variant, col = best_matching(match_slot, match_val, 4, 1, panorama_variant=True)
    assert int(col) == 1
    # SUM: 0.8, 1.4, 1.4 + 1.4/2 = 2.1, 2.1 + 2.1/3 = 2.8 -> MAX = 2.8 / 4
    assert float(variant) == pytest.approx(0.7)
    assert float(plain) == pytest.approx((0.8 + 0.6) / 4)


def test_a_black_or_saturated_image_is_ncc_one_half_everywhere(bank: PanoramaBank) -> None:
    for level in (0, 255):
        image = np.full((58, 72), level, dtype=np.float32)
        values = slot_values(image, bank.panoramas[0], 8)
        assert np.all(values == 0.5)
        match_slot, match_val = match_slots(values)
        best, _ = best_matching(match_slot, match_val, 8, 9)
        assert float(best) == pytest.approx(0.5 / 8)
        assert np.all(bank.match(np.full((120, 160), level, dtype=np.uint8)).match < 0.5)


def test_occluding_columns_lower_the_match_but_the_right_panorama_still_wins(camera: CameraRenderer, bank: PanoramaBank) -> None:
    x, y = PLACES["MIDDLE"]
    pose = np.array([x, y, 0.4])
    # a person 2 m away in view covers ~15 of the 60 degrees: a quarter of the image (thesis 5.1.1)
    person = np.array([[x + 2.0 * math.cos(0.5), y + 2.0 * math.sin(0.5), 0.25]])
    clear = bank.match(camera.render(pose))
    occluded = bank.match(camera.render(pose, person))
    middle = list(PLACES).index("MIDDLE")
    assert occluded.match[middle] < clear.match[middle] - 0.05
    assert int(np.argmax(occluded.match)) == middle
    assert occluded.match[middle] > 0.5  # still a destination (eps_M = 0.5)


def test_heading_from_the_panorama_column_is_equation_2_2(bank: PanoramaBank, camera: CameraRenderer) -> None:
    width = bank.width
    # For an unzoomed panorama and Wnew a multiple of Ns: heading = heading_ref - 2 pi COL / Wref.
    assert heading_from_col(width // 4, width, 72, 8, HFOV, 0.3) == pytest.approx(0.3 - math.pi / 2)
    for name, (x, y) in PLACES.items():
        for yaw in (-2.5, -0.7, 0.0, 1.2, 2.9):
            image = camera.render(np.array([x, y, yaw]), None, np.random.default_rng(3))
            result = bank.match(image)
            index = list(PLACES).index(name)
            assert int(np.argmax(result.match)) == index
            assert abs(math.degrees(angle_difference(result.heading[index], yaw))) < 3.0


def test_digital_zoom_extends_the_recognised_area(camera: CameraRenderer, true_panoramas: list[np.ndarray]) -> None:
    zoom_on = PanoramaBank(true_panoramas, HFOV, 0.0, ImaSettings(zoom=1.1))
    zoom_off = PanoramaBank(true_panoramas, HFOV, 0.0, ImaSettings(zoom=1.0))
    index = list(PLACES).index("WEST")
    x, y = PLACES["WEST"]
    gains, chosen = [], []
    for yaw in (-0.3, 0.0, 0.3):
        for step in (0.25, -0.25):  # moved towards / away from the scene it looks at
            pose = np.array([x + step * math.cos(yaw), y + step * math.sin(yaw), yaw])
            image = camera.render(pose)
            on, off = zoom_on.match(image), zoom_off.match(image)
            gains.append(on.match[index] - off.match[index])
            chosen.append(int(on.comparison[index]))
    assert min(gains) >= 0.0  # the best of three is never below the plain comparison
    assert np.mean(gains) > 0.03
    assert {1, 2} <= set(chosen)  # zoomed image when moved forward, zoomed panorama when moved back


def test_a_panorama_rebuilt_from_imprecise_snapshots_is_within_two_percent(camera: CameraRenderer) -> None:
    settings = ImaSettings(width=144, height=116, slots=15, zoom=1.0)
    rng = np.random.default_rng(11)
    for x, y in (PLACES["WEST"], PLACES["EAST"]):
        turns = snapshot_turns(40.0, 10.0, rng)  # 40 +- 10 degree steps, clockwise
        steps = np.degrees(np.diff(turns))
        assert steps.min() < 36.0 and steps.max() > 44.0  # the steps really are imprecise
        snapshots = [camera.render(np.array([x, y, -turn]), None, rng) for turn in turns]
        built = build_panorama(snapshots, HFOV, settings)
        width = built.panorama.shape[1]
        assert width == panorama_width(144, HFOV)
        truth = turns / (2.0 * np.pi) * width
        error = (built.columns - truth + 0.5 * width) % width - 0.5 * width
        assert np.abs(error).max() <= 0.02 * width
        # the mosaic itself lines up with the true panorama: circular shift of best correlation
        true = cv2.resize(camera.render_panorama(np.array([x, y, 0.0]), 960), (width, 116), interpolation=cv2.INTER_AREA)
        rows = slice(20, 96)
        a = built.panorama[rows].astype(float).mean(axis=0)
        b = true[rows].astype(float).mean(axis=0)
        a, b = a - a.mean(), b - b.mean()
        correlation = np.real(np.fft.ifft(np.fft.fft(a) * np.conj(np.fft.fft(b))))
        shift = int(np.argmax(correlation))
        assert min(shift, width - shift) <= 0.02 * width


# -- the topological map file ---------------------------------------------------------
def test_topomap_round_trip_and_a_missing_panorama_is_named(tmp_path: Path, true_panoramas: list[np.ndarray]) -> None:
    path = save_topomap(_topomap(true_panoramas), tmp_path / "map" / "topomap.yaml")
    loaded = load_topomap(path)
    assert loaded.names == list(PLACES)
    assert np.allclose(loaded.positions, np.array(list(PLACES.values())))
    assert np.array_equal(loaded.panoramas[1], true_panoramas[1])
    (tmp_path / "map" / "MIDDLE.png").unlink()
    with pytest.raises(MapError, match=r"MIDDLE.*panorama file .*MIDDLE\.png.* does not exist"):
        load_topomap(path)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda meta: meta.pop("hfov_deg"), "hfov_deg"),
        (lambda meta: meta["nodes"][0].pop("x"), "field 'x'"),
        (lambda meta: meta["nodes"][1].update(name="WEST"), "appears twice"),
        (lambda meta: meta["nodes"][2].update(y=float("nan")), "finite"),
        (lambda meta: meta.update(nodes=[]), "non-empty"),
    ],
)
def test_a_bad_topomap_file_is_refused_naming_the_field(tmp_path: Path, true_panoramas: list[np.ndarray], edit, message: str) -> None:
    path = save_topomap(_topomap(true_panoramas), tmp_path / "topomap.yaml")
    meta = yaml.safe_load(path.read_text())
    edit(meta)
    path.write_text(yaml.safe_dump(meta))
    with pytest.raises(MapError, match=message):
        load_topomap(path)


# -- activities (section 3.6) -------------------------------------------------------------
def _origins(xy, heading, activity, virtual=None) -> Hypotheses:
    count = len(activity)
    return Hypotheses(
        node=np.arange(count),
        xy=np.asarray(xy, dtype=float),
        heading=np.asarray(heading, dtype=float),
        activity=np.asarray(activity, dtype=float),
        virtual=np.zeros(count, bool) if virtual is None else np.asarray(virtual),
        match=np.full(count, 0.7),
    )


def test_activity_update_case_1_origins_activity_decides() -> None:
    # 3.6.1: o1 -> d1 and o2 -> d2 are mirror images; equal matches; Act(o1) > Act(o2) -> d1.
    origins = _origins([[0.0, 1.0], [0.0, -1.0]], [0.0, 0.0], [0.7, 0.3])
    destinations = np.array([[1.0, 1.0], [1.0, -1.0]])
    act = activity_update(origins, destinations, np.zeros(2), np.zeros(2, bool), np.array([0.6, 0.6]), np.array([1.0, 0.0]), 0.0)
    assert act[0] > act[1]
    assert act.sum() == pytest.approx(1.0)


def test_activity_update_case_2_distance_decides() -> None:
    # 3.6.2: one origin; d1 at the odometry position, d2 farther; equal matches and headings.
    origins = _origins([[0.0, 0.0]], [0.0], [1.0])
    destinations = np.array([[1.0, 0.0], [1.0, 1.5]])
    act = activity_update(origins, destinations, np.zeros(2), np.zeros(2, bool), np.array([0.6, 0.6]), np.array([1.0, 0.0]), 0.0)
    assert act[0] > act[1]
    # equations 3.16-3.24 by hand: sigma_l = dl_max = 1.5, dphi = 0 everywhere
    g = np.exp(-np.array([0.0, 1.5]) ** 2 / (2 * 1.5**2))
    assert act == pytest.approx(g / g.sum())


def test_activity_update_case_3_heading_decides() -> None:
    # 3.6.3: same distance and match; d2's heading disagrees with the odometry's.
    origins = _origins([[0.0, 0.0]], [0.2], [1.0])
    destinations = np.array([[1.0, 0.5], [1.0, -0.5]])
    act = activity_update(
        origins, destinations, np.array([0.3, 1.3]), np.zeros(2, bool), np.array([0.6, 0.6]), np.array([1.0, 0.0]), 0.1
    )
    assert act[0] > act[1]
    g = np.exp(-np.array([0.0, 1.0]) ** 2 / 2.0)  # dphi = 0 and 1 rad, sigma_phi = 1 rad
    assert act == pytest.approx(g / g.sum())


def test_activity_update_case_4_observation_decides() -> None:
    # 3.6.4: everything equal but MATCH(d1) > MATCH(d2): activities proportional to the matches.
    origins = _origins([[0.0, 0.0]], [0.0], [1.0])
    destinations = np.array([[1.0, 0.5], [1.0, -0.5]])
    act = activity_update(origins, destinations, np.zeros(2), np.zeros(2, bool), np.array([0.8, 0.6]), np.array([1.0, 0.0]), 0.0)
    assert act == pytest.approx([0.8 / 1.4, 0.6 / 1.4])


def test_virtual_origin_to_virtual_destination_has_no_heading_difference() -> None:
    # footnote 10: the virtual pair compares the odometry heading with itself
    origins = _origins([[0.0, 0.0], [0.0, 0.0]], [0.0, 0.5], [0.5, 0.5], virtual=[False, True])
    destinations = np.array([[1.0, 0.0], [1.0, 0.0]])
    act = activity_update(
        origins, destinations, np.array([0.0, 0.9]), np.array([False, True]), np.array([0.6, 0.6]), np.array([1.0, 0.0]), 0.0
    )
    # d1 <- o1 (dphi 0) and o2 (0.5); d2(v) <- o1 (0.9) and o2(v) (0 by footnote 10)
    sigma = 0.9
    g = lambda d: np.exp(-(d**2) / (2 * sigma**2))  # noqa: E731
    expected = np.array([0.5 * g(0.0) + 0.5 * g(0.5), 0.5 * g(0.9) + 0.5 * g(0.0)])
    assert act == pytest.approx(expected / expected.sum())


# -- the tracker (Code 3.1) ------------------------------------------------------------------
@pytest.fixture()
def tracker(true_panoramas: list[np.ndarray]) -> ImaTopoLocalizer:
    return ImaTopoLocalizer(_topomap(true_panoramas), ImaTrackerSettings())


def test_tracker_localizes_globally_and_updates_only_after_motion(tracker: ImaTopoLocalizer, camera: CameraRenderer) -> None:
    rng = np.random.default_rng(1)
    x, y = PLACES["EAST"]
    tracker.on_odometry(0.0, np.array([10.0, -3.0, 1.0]))  # odometry has its own frame
    estimate = tracker.on_image(0.0, camera.render(np.array([x, y, 2.0]), None, rng))
    assert estimate is not None and estimate.details["place"] == "EAST"
    assert np.allclose(estimate.place.xy, [x, y]) and estimate.place.node_xy.shape == (3, 2)
    assert estimate.place.name == "EAST"
    assert estimate.heading_corrected and abs(angle_difference(estimate.pose[2], 2.0)) < math.radians(3)
    assert estimate.candidates.shape[1] == 3 and estimate.candidate_weights.sum() == pytest.approx(1.0)
    # no motion: no update; 0.2 m: still none; 0.35 m or 12 degrees: an update
    assert tracker.on_image(0.5, camera.render(np.array([x, y, 2.0]), None, rng)) is None
    tracker.on_odometry(1.0, np.array([10.2, -3.0, 1.0]))
    assert tracker.on_image(1.0, camera.render(np.array([x, y, 2.0]), None, rng)) is None
    tracker.on_odometry(2.0, np.array([10.0, -3.0, 1.0 + math.radians(12.0)]))
    turned = tracker.on_image(2.0, camera.render(np.array([x, y, 2.0 + math.radians(12.0)]), None, rng))
    assert turned is not None and turned.details["place"] == "EAST"
    assert abs(angle_difference(turned.pose[2], 2.0 + math.radians(12.0))) < math.radians(3)


def test_a_black_image_gives_no_destination_only_the_odometry_guess(tracker: ImaTopoLocalizer, camera: CameraRenderer) -> None:
    x, y = PLACES["WEST"]
    tracker.on_odometry(0.0, np.zeros(3))
    first = tracker.on_image(0.0, camera.render(np.array([x, y, 0.0])))
    assert first is not None and first.details["place"] == "WEST"
    # drive 2 m east blind: the odometry guess is MIDDLE (2 m east of WEST)
    tracker.on_odometry(1.0, np.array([2.0, 0.0, 0.0]))
    blind = tracker.on_image(1.0, np.zeros((120, 160), dtype=np.uint8))
    assert blind is not None
    assert blind.details["kind"] == "supposed" and blind.details["destinations"] == 0
    assert blind.details["place"] == "MIDDLE" and blind.heading_corrected is False
    assert len(blind.candidates) == 1
    # saturated, too; and the origins were kept (no reset without destinations)
    tracker.on_odometry(2.0, np.array([2.0, 0.0, 0.5]))
    assert tracker.on_image(2.0, np.full((120, 160), 255, dtype=np.uint8)).details["kind"] == "supposed"
    assert tracker.origins.node.tolist()[0] == list(PLACES).index("WEST")


def test_a_black_image_before_any_fix_gives_no_estimate(tracker: ImaTopoLocalizer) -> None:
    assert tracker.on_image(0.0, np.zeros((120, 160), dtype=np.uint8)) is None


def test_initial_pose_and_reinitialize(tracker: ImaTopoLocalizer, camera: CameraRenderer) -> None:
    tracker.on_odometry(0.0, np.array([1.0, 1.0, 0.0]))
    tracker.set_initial_pose(np.array([3.4, 2.1, 0.5]), np.eye(3) * 0.01)
    assert tracker.origins.node.tolist() == [list(PLACES).index("MIDDLE")]
    blind = tracker.on_image(0.0, np.zeros((120, 160), dtype=np.uint8))
    assert blind.details["place"] == "MIDDLE" and blind.pose[2] == pytest.approx(0.5)
    tracker.reinitialize()
    assert len(tracker.origins) == 3 and np.allclose(tracker.origins.activity, 1.0 / 3.0)


def test_images_of_any_size_or_colour_are_used_and_bad_ones_refused(tracker: ImaTopoLocalizer, camera: CameraRenderer) -> None:
    x, y = PLACES["MIDDLE"]
    image = camera.render(np.array([x, y, 1.0]))
    big_colour = cv2.cvtColor(cv2.resize(image, (320, 240)), cv2.COLOR_GRAY2RGB)
    estimate = tracker.on_image(0.0, big_colour)
    assert estimate is not None and estimate.details["place"] == "MIDDLE"
    with pytest.raises(ImageError, match="shape"):
        tracker.on_image(1.0, np.zeros((10, 10, 2), dtype=np.uint8))
    with pytest.raises(ImageError, match="non-finite"):
        tracker.on_image(1.0, np.full((20, 20), np.nan))


# -- the odometry reset (Code 3.1 vs thesis 5.2.3 / 6.1) -------------------------------------
_WEST, _MIDDLE, _EAST = range(3)
_BLANK = np.zeros((120, 160), dtype=np.uint8)  # the scripted IMA below ignores the image


def _seen(matches: dict[int, tuple[float, int]]) -> PlaceMatch:
    """An IMA result: ``{node: (MATCH, comparison)}``, every other node 0.45 (no destination), heading 0."""
    match = np.full(len(PLACES), 0.45)
    comparison = np.zeros(len(PLACES), dtype=np.int64)
    for node, (value, which) in matches.items():
        match[node], comparison[node] = value, which
    return PlaceMatch(match, np.zeros(len(PLACES), dtype=np.int64), np.zeros(len(PLACES)), comparison)


def _drive_east(tracker: ImaTopoLocalizer, steps: list[tuple[float, PlaceMatch]]) -> list:
    """Feed odometry x [m] (heading 0, the map's +x) and a scripted IMA result per update."""
    script = iter(place for _, place in steps)
    tracker.bank.match = lambda image: next(script)  # type: ignore[method-assign]
    estimates = []
    for stamp, (odom_x, _) in enumerate(steps):
        tracker.on_odometry(float(stamp), np.array([odom_x, 0.0, 0.0]))
        estimates.append(tracker.on_image(float(stamp), _BLANK))
    return estimates


@pytest.mark.parametrize(("reset", "expected"), [("winner", "WEST"), ("place", "MIDDLE"), ("zoom", "MIDDLE")])
def test_recognising_the_last_place_half_way_resets_the_odometry_only_in_code_3_1(
    true_panoramas: list[np.ndarray], reset: str, expected: str
) -> None:
    # Thesis 5.2.3's error case: at WEST (x 1.5), 0.6 m on towards MIDDLE (x 3.5) the camera still
    # recognises WEST (through the zoomed panorama: the robot is beyond the node), then 0.6 m more
    # nothing is recognised. The robot is at x 2.7, nearest MIDDLE. Code 3.1 reset the odometry to
    # WEST's coordinates half way, so its odometry guess is x 2.1 -> WEST; without that reset it is 2.7.
    tracker = ImaTopoLocalizer(_topomap(true_panoramas), ImaTrackerSettings(odometry_reset=reset))
    first, half_way, blind = _drive_east(
        tracker, [(0.0, _seen({_WEST: (0.9, 0)})), (0.6, _seen({_WEST: (0.8, 2)})), (1.2, _seen({}))]
    )
    assert first.details["place"] == half_way.details["place"] == "WEST"
    assert half_way.details["odometry_reset"] == (reset == "winner")
    assert blind.details["kind"] == "supposed" and blind.details["place"] == expected


@pytest.mark.parametrize(
    ("reset", "zoom", "expected"), [("zoom", 1.1, "WEST"), ("place", 1.1, "MIDDLE"), ("zoom", 1.0, "MIDDLE")]
)
def test_a_match_without_zoom_re_anchors_the_odometry_at_the_node(
    true_panoramas: list[np.ndarray], reset: str, zoom: float, expected: str
) -> None:
    # The wheels slip: odometry says 0.6 m but the image matches WEST's panorama without zoom, so
    # the robot is at WEST. "zoom" re-anchors there (0.6 m more: x 2.1, WEST); "place" does not
    # (2.7, MIDDLE); with the zoom off no comparison tells "at the node" and "zoom" acts as "place".
    settings = ImaTrackerSettings(ima=ImaSettings(zoom=zoom), odometry_reset=reset)
    tracker = ImaTopoLocalizer(_topomap(true_panoramas), settings)
    _, again, blind = _drive_east(
        tracker, [(0.0, _seen({_WEST: (0.9, 0)})), (0.6, _seen({_WEST: (0.9, 0)})), (1.2, _seen({}))]
    )
    assert again.details["place"] == "WEST" and again.details["odometry_reset"] == (expected == "WEST")
    assert blind.details["place"] == expected


@pytest.mark.parametrize(("reset", "expected"), [("winner", "WEST"), ("zoom", "MIDDLE")])
def test_a_winning_virtual_destination_resets_the_odometry_only_in_code_3_1(
    true_panoramas: list[np.ndarray], reset: str, expected: str
) -> None:
    # 0.8 m east of WEST only far-away EAST is (weakly) seen: the virtual destination, the node
    # nearest the odometry (x 2.3 -> WEST), wins. Code 3.1 then resets the odometry to WEST's
    # coordinates (x 1.5), rounding 0.8 m away; 0.6 m later, blind, the robot is at x 2.9 (MIDDLE).
    tracker = ImaTopoLocalizer(_topomap(true_panoramas), ImaTrackerSettings(odometry_reset=reset))
    _, virtual, blind = _drive_east(
        tracker, [(0.0, _seen({_WEST: (0.9, 0)})), (0.8, _seen({_EAST: (0.55, 0)})), (1.4, _seen({}))]
    )
    assert virtual.details["kind"] == "virtual" and virtual.details["place"] == "WEST"
    assert virtual.details["odometry_reset"] == (reset == "winner")
    assert blind.details["place"] == expected


@pytest.mark.parametrize("estimate", ["node", "fused"])
def test_the_pose_fuses_the_odometry_with_the_recognised_places(true_panoramas: list[np.ndarray],
                                                                estimate: str) -> None:
    # WEST (x 1.5) recognised, then 0.6 m on through the zoomed panorama: the odometry says x 2.1, the place
    # says 1.5. Fused, each is weighed by its variance: the place's (half the node spacing, 1 m, squared)
    # against the position's (the place's, plus the odometry's drift over 0.6 m), so the pose lies between,
    # a little nearer the odometry. The thesis' pose is the node.
    settings = ImaTrackerSettings(pose_estimate=estimate, odometry_drift=0.05)
    tracker = ImaTopoLocalizer(_topomap(true_panoramas), settings)
    first, on = _drive_east(tracker, [(0.0, _seen({_WEST: (0.9, 0)})), (0.6, _seen({_WEST: (0.8, 2)}))])
    place_variance = (0.5 * 2.0) ** 2  # the places are 2 m (WEST-MIDDLE) and 2.2 m apart: median spacing 2 m
    predicted_variance = place_variance + (0.05 * 0.6) ** 2
    gain = predicted_variance / (predicted_variance + place_variance)
    fused_x = 2.1 + gain * (1.5 - 2.1)
    assert first.pose[:2] == pytest.approx(PLACES["WEST"])
    assert on.details["place"] == "WEST" and on.pose[1] == pytest.approx(2.0)
    assert on.pose[0] == pytest.approx(fused_x if estimate == "fused" else 1.5)
    expected_variance = (1.0 - gain) * predicted_variance if estimate == "fused" else place_variance
    assert on.covariance[0, 0] == pytest.approx(expected_variance)


def test_recognising_the_same_place_again_and_again_does_not_make_the_position_certain(
    true_panoramas: list[np.ndarray],
) -> None:
    # Six recognitions of WEST, 0.35 m apart: as independent measurements they would bring the variance down to
    # about a sixth of the place's. They are not independent (the same view errs the same way), so the
    # standard deviation stays at half the place's (1 m): variance 0.25 m^2.
    tracker = ImaTopoLocalizer(_topomap(true_panoramas), ImaTrackerSettings(pose_estimate="fused"))
    estimates = _drive_east(tracker, [(0.35 * k, _seen({_WEST: (0.9, 2)})) for k in range(6)])
    variances = [e.covariance[0, 0] for e in estimates]
    assert variances[0] == pytest.approx(1.0) and variances[1] == pytest.approx(0.5, abs=0.01)
    assert min(variances) == pytest.approx(0.25) and variances[-1] == pytest.approx(0.25)


def test_an_initial_pose_before_the_first_odometry_is_moved_only_by_the_odometry_since(
    true_panoramas: list[np.ndarray],
) -> None:
    # RViz's initial pose (x 2.1 m) comes before the odometry, whose first message reads x 5 m: the motion counts
    # from that message, so 0.6 m later the position is x 2.7 before WEST (x 1.5) is fused with it, not 7.7.
    tracker = ImaTopoLocalizer(_topomap(true_panoramas), ImaTrackerSettings(pose_estimate="fused"))
    tracker.set_initial_pose(np.array([2.1, 2.0, 0.0]), np.diag([0.01, 0.01, 0.01]))
    tracker.bank.match = lambda image: _seen({_WEST: (0.9, 2)})  # type: ignore[method-assign]
    tracker.on_odometry(0.0, np.array([5.0, 0.0, 0.0]))
    tracker.on_odometry(1.0, np.array([5.6, 0.0, 0.0]))
    estimate = tracker.on_image(1.0, _BLANK)
    predicted = 0.01 + (0.05 * 0.6) ** 2
    gain = predicted / (predicted + 1.0)  # WEST's variance: half the 2 m spacing, squared
    assert estimate is not None
    assert estimate.pose[:2] == pytest.approx([2.7 + gain * (1.5 - 2.7), 2.0])


@pytest.mark.parametrize("min_places", [1, 3])
def test_localized_waits_for_places_that_agree_since_the_position_restarted(true_panoramas: list[np.ndarray],
                                                                           min_places: int) -> None:
    # From the start, WEST, then MIDDLE 2 m on and EAST 2 m further (each where the odometry carries the fused
    # position), all matched clearly. One place may have been recognised from afar; three that agree through the
    # odometry make the position worth standing behind. Then EAST again, from far off (a kidnapping's first
    # place): the position restarts and LOCALIZED waits again. An initial pose needs no places.
    settings = ImaTrackerSettings(localized_min_places=min_places)
    tracker = ImaTopoLocalizer(_topomap(true_panoramas), settings)
    estimates = _drive_east(tracker, [(0.0, _seen({_WEST: (0.9, 0)})), (2.0, _seen({_MIDDLE: (0.9, 0)})),
                                      (4.0, _seen({_EAST: (0.9, 0)})), (-4.0, _seen({_EAST: (0.9, 0)}))])
    assert [e.details["places_since_restart"] for e in estimates] == [1, 2, 3, 1]
    assert estimates[3].details["position_restarted"]
    localized = [e.status is LocalizerStatus.LOCALIZED for e in estimates]
    assert localized == ([True] * 4 if min_places == 1 else [False, False, True, False])
    given = ImaTopoLocalizer(_topomap(true_panoramas), settings)
    given.set_initial_pose(np.array([1.5, 2.0, 0.0]), np.diag([0.01, 0.01, 0.01]))
    (first,) = _drive_east(given, [(0.0, _seen({_WEST: (0.9, 0)}))])
    assert first.status is LocalizerStatus.LOCALIZED


def test_a_place_far_beyond_the_fused_position_restarts_it_there_once_vision_names_it_clearly(
        true_panoramas: list[np.ndarray]) -> None:
    # After WEST (x 1.5), 1 m back west the odometry says x 0.5, and only EAST (x 5.5, y 3; 5.1 m away, beyond 3
    # standard deviations of the difference: 3 * sqrt(1 + 1) m) is recognised: a kidnapping or a wrong earlier
    # place. Its activity is still within ambiguity_ratio of the hypothesis carried from WEST (a near tie is no
    # relocalization: one image outside the mapped rooms can match a far place as well): the position stays and
    # that place is not fused. Seen again, EAST is named clearly and the position restarts at its node instead of
    # being averaged with the odometry, which would put the robot between the two places.
    tracker = ImaTopoLocalizer(_topomap(true_panoramas), ImaTrackerSettings(pose_estimate="fused"))
    _, tie, away = _drive_east(tracker, [(0.0, _seen({_WEST: (0.9, 0)})), (-1.0, _seen({_EAST: (0.95, 0)})),
                                         (-1.3, _seen({_EAST: (0.95, 0)}))])
    assert tie.details["activity"] < ImaTrackerSettings().ambiguity_ratio * tie.details["rival_activity"]
    assert not tie.details["position_restarted"] and tie.status is not LocalizerStatus.LOCALIZED
    assert tie.pose[0] == pytest.approx(0.5, abs=0.05)  # the odometry's, not between the places
    assert away.details["place"] == "EAST" and away.details["position_restarted"]
    assert away.pose[:2] == pytest.approx(PLACES["EAST"])


@pytest.mark.parametrize("ratio", [1.0, 1.2])
def test_two_places_seen_alike_are_ambiguous_until_one_is_told_apart(true_panoramas: list[np.ndarray],
                                                                       ratio: float) -> None:
    # Vision matches WEST and EAST alike at the start: either may be the place, so the state is AMBIGUOUS with
    # both among the candidates (with ambiguity_ratio 1.0, the thesis' winner alone: LOCALIZED at one of them).
    # 0.6 m on, only WEST matches: LOCALIZED there.
    tracker = ImaTopoLocalizer(_topomap(true_panoramas), ImaTrackerSettings(ambiguity_ratio=ratio,
                                                                           localized_min_places=1))
    tie, told = _drive_east(tracker, [(0.0, _seen({_WEST: (0.8, 0), _EAST: (0.8, 0)})), (0.6, _seen({_WEST: (0.9, 0)}))])
    places = {tuple(np.round(xy, 3)) for xy in tie.candidates[:, :2]}
    assert places == {PLACES["WEST"], PLACES["EAST"]} and tie.details["rival_activity"] == pytest.approx(0.5, abs=0.01)
    assert tie.status is (LocalizerStatus.LOCALIZED if ratio == 1.0 else LocalizerStatus.AMBIGUOUS)
    assert told.details["place"] == "WEST" and told.status is LocalizerStatus.LOCALIZED


def test_a_place_matched_below_the_heading_threshold_is_not_localized(true_panoramas: list[np.ndarray]) -> None:
    # WEST alone matches at 0.55: a destination (above eps_M 0.5), but too weak to correct the heading
    # (eps_phi 0.6), so the pose's heading is the odometry's: AMBIGUOUS. At 0.9 it is corrected: LOCALIZED.
    tracker = ImaTopoLocalizer(_topomap(true_panoramas), ImaTrackerSettings(localized_min_places=1))
    weak, strong = _drive_east(tracker, [(0.0, _seen({_WEST: (0.55, 0)})), (0.6, _seen({_WEST: (0.9, 0)}))])
    assert weak.details["kind"] == "destination" and weak.details["place"] == "WEST"
    assert not weak.heading_corrected and weak.status is LocalizerStatus.AMBIGUOUS
    assert strong.heading_corrected and strong.status is LocalizerStatus.LOCALIZED


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"slots": 0}, "slots"),
        ({"zoom": 0.9}, "zoom"),
        ({"ncc_backend": "fft"}, "ncc_backend"),
        ({"width": 3}, "width"),
    ],
)
def test_bad_ima_settings_are_refused(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ImaSettings(**kwargs)


def test_bad_tracker_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="heading_threshold"):
        ImaTrackerSettings(match_threshold=0.7, heading_threshold=0.6)
    with pytest.raises(ValueError, match="min_translation"):
        ImaTrackerSettings(min_translation=-1.0)
    with pytest.raises(ValueError, match="odometry_reset"):
        ImaTrackerSettings(odometry_reset="always")
