"""GridMap (core/grid_map.py): nav2 map_server loading in every mode, corrupt files, conversions, distance field."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from robot_localization_suite.core.errors import MapError
from robot_localization_suite.core.grid_map import GridMap, load_map_yaml

# A 3 x 4 image, first row = top of the map (highest y), as map_server reads it.
# 0 = black (occupied in trinary), 254 = white (free), 205 = grey (unknown), 128 = mid grey.
IMAGE = np.array(
    [
        [0, 254, 205, 128],
        [254, 254, 254, 254],
        [100, 50, 255, 0],
    ],
    dtype=np.uint8,
)


def write_map(tmp_path: Path, pixels: np.ndarray | None = IMAGE, name: str = "map", **fields) -> Path:
    meta = {
        "image": f"{name}.pgm",
        "resolution": 0.5,
        "origin": [-1.0, 2.0, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
        "mode": "trinary",
    }
    meta.update(fields)
    meta = {k: v for k, v in meta.items() if v is not None}
    if pixels is not None:
        assert cv2.imwrite(str(tmp_path / f"{name}.pgm"), pixels)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(meta))
    return path


def top_row(grid: GridMap) -> list[int]:
    """The image's first row is the map's last row (highest y)."""
    return grid.data[-1].tolist()


def test_trinary(tmp_path: Path) -> None:
    grid = load_map_yaml(write_map(tmp_path))
    assert (grid.width, grid.height) == (4, 3)
    assert grid.resolution == 0.5
    assert grid.origin == (-1.0, 2.0)
    # occ = (255 - p) / 255: 0 -> 1.0 occupied; 254 -> 0.004 free; 205 -> 0.196 (> free_thresh 0.196) unknown;
    # 128 -> 0.498 unknown (between the thresholds).
    assert top_row(grid) == [100, 0, -1, -1]
    # Bottom image row: 100 -> 0.608 unknown; 50 -> 0.804 occupied; 255 -> 0 free; 0 -> occupied.
    assert grid.data[0].tolist() == [-1, 100, 0, 100]
    assert grid.occupied_mask.sum() == 3
    assert grid.free_mask.sum() == 6
    assert grid.unknown_mask.sum() == 3


def test_trinary_negate(tmp_path: Path) -> None:
    grid = load_map_yaml(write_map(tmp_path, negate=1))
    # occ = p / 255: 0 -> free, 254 -> occupied, 205 -> 0.804 occupied, 128 -> 0.502 unknown.
    assert top_row(grid) == [0, 100, 100, -1]
    # 100 -> 0.392 unknown; 50 -> 0.19608 (just above free_thresh) unknown; 255 -> occupied; 0 -> free.
    assert grid.data[0].tolist() == [-1, -1, 100, 0]


def test_scale(tmp_path: Path) -> None:
    grid = load_map_yaml(write_map(tmp_path, mode="scale"))
    # Between the thresholds the value is 99 * (occ - free) / (occupied - free), rounded.
    occ_128 = (255 - 128) / 255
    occ_205 = (255 - 205) / 255
    occ_100 = (255 - 100) / 255
    expected_128 = int(np.rint(99 * (occ_128 - 0.196) / (0.65 - 0.196)))  # 66
    expected_205 = int(np.rint(99 * (occ_205 - 0.196) / (0.65 - 0.196)))  # 0
    expected_100 = int(np.rint(99 * (occ_100 - 0.196) / (0.65 - 0.196)))  # 90
    assert (expected_128, expected_205, expected_100) == (66, 0, 90)
    assert top_row(grid) == [100, 0, expected_205, expected_128]
    assert grid.data[0].tolist() == [expected_100, 100, 0, 100]
    # Graded values are neither obstacles nor free space; only 100 is an obstacle.
    assert not grid.occupied_mask[-1, 3] and not grid.free_mask[-1, 3]
    assert grid.occupied_mask.sum() == 3


def test_raw(tmp_path: Path) -> None:
    image = np.array([[0, 100, 101], [50, 255, 7]], dtype=np.uint8)
    grid = load_map_yaml(write_map(tmp_path, image, mode="raw"))
    # The pixel is the occupancy value; above 100 means unknown.
    assert top_row(grid) == [0, 100, -1]
    assert grid.data[0].tolist() == [50, -1, 7]


def test_a_map_file_and_the_same_map_on_the_topic_are_one_map(tmp_path: Path) -> None:
    from robot_localization_suite.ros import conversions

    grid = load_map_yaml(write_map(tmp_path, resolution=0.05, origin=[-36.75, -19.5, 0.0]))
    received = conversions.grid_map_from_msg(conversions.grid_map_to_msg(grid, 0.0))
    assert grid.resolution == received.resolution == float(np.float32(0.05))
    assert grid.fingerprint() == received.fingerprint()
    # A point on a cell corner (PIL's tile centres are) falls in the same cell on both.
    corner = np.array([[-36.75 + 0.2 * 7, -19.5 + 0.2 * 3]])
    assert np.array_equal(grid.world_to_cell(corner), received.world_to_cell(corner))


def test_png_image_and_default_mode(tmp_path: Path) -> None:
    assert cv2.imwrite(str(tmp_path / "colour.png"), np.dstack([IMAGE] * 3))
    path = write_map(tmp_path, None, image="colour.png", mode=None)
    grid = load_map_yaml(path)
    assert top_row(grid) == [100, 0, -1, -1]


@pytest.mark.parametrize(
    ("fields", "image", "expected"),
    [
        ({"image": "nowhere.pgm"}, IMAGE, r"'image'.*nowhere\.pgm"),
        ({"resolution": -0.05}, IMAGE, r"'resolution'.*-0\.05"),
        ({"resolution": "fine"}, IMAGE, r"'resolution'.*'fine'"),
        ({"mode": "bogus"}, IMAGE, r"'mode'.*'bogus'"),
        ({"negate": 3}, IMAGE, r"'negate'.*3"),
        ({"origin": [1.0, 2.0]}, IMAGE, r"'origin'.*\[1\.0, 2\.0\]"),
        ({"origin": [0.0, 0.0, 0.5]}, IMAGE, r"rotated origin.*0\.5"),
        ({"free_thresh": 0.9}, IMAGE, r"free_thresh 0\.9"),
    ],
)
def test_bad_field_names_field_and_value(tmp_path: Path, fields: dict, image: np.ndarray, expected: str) -> None:
    with pytest.raises(MapError, match=expected):
        load_map_yaml(write_map(tmp_path, image, **fields))


@pytest.mark.parametrize("missing", ["image", "resolution", "origin"])
def test_missing_field_is_named(tmp_path: Path, missing: str) -> None:
    path = write_map(tmp_path)
    meta = yaml.safe_load(path.read_text())
    del meta[missing]
    path.write_text(yaml.safe_dump(meta))
    with pytest.raises(MapError, match=rf"no field '{missing}'"):
        load_map_yaml(path)


def test_image_that_is_not_an_image(tmp_path: Path) -> None:
    path = write_map(tmp_path, None)
    (tmp_path / "map.pgm").write_text("this is not a PGM file\n")
    with pytest.raises(MapError, match=r"map\.pgm.*corrupt or not an image"):
        load_map_yaml(path)


def test_yaml_that_is_not_a_map(tmp_path: Path) -> None:
    missing = tmp_path / "absent.yaml"
    with pytest.raises(MapError, match="does not exist"):
        load_map_yaml(missing)
    broken = tmp_path / "broken.yaml"
    broken.write_text("image: [unclosed\n")
    with pytest.raises(MapError, match="not valid YAML"):
        load_map_yaml(broken)
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text("42\n")
    with pytest.raises(MapError, match="must hold a mapping, got int"):
        load_map_yaml(scalar)


def test_save_then_load_round_trip(tmp_path: Path) -> None:
    data = np.full((5, 7), -1, dtype=np.int8)
    data[1:4, 1:6] = 0
    data[2, 3] = 100
    grid = GridMap(data, 0.1, (3.0, -4.0))
    loaded = load_map_yaml(grid.save(tmp_path / "saved.yaml"))
    np.testing.assert_array_equal(loaded.data, grid.data)
    assert loaded.resolution == pytest.approx(0.1)
    assert loaded.origin == pytest.approx((3.0, -4.0))
    assert loaded.fingerprint() == grid.fingerprint()


def test_save_as_png_round_trip_and_bad_format(tmp_path: Path) -> None:
    data = np.full((5, 7), -1, dtype=np.int8)
    data[1:4, 1:6] = 0
    data[2, 3] = 100
    grid = GridMap(data, 0.1, (3.0, -4.0))
    yaml_path = grid.save(tmp_path / "saved.yaml", image_format="png")
    assert (tmp_path / "saved.png").is_file() and not (tmp_path / "saved.pgm").exists()
    assert yaml.safe_load(yaml_path.read_text())["image"] == "saved.png"
    assert load_map_yaml(yaml_path).fingerprint() == grid.fingerprint()
    with pytest.raises(MapError, match="image format must be one of .*'jpg'"):
        grid.save(tmp_path / "lossy.yaml", image_format="jpg")


def test_occupancy_grid_message_round_trip() -> None:
    from robot_localization_suite.ros.conversions import grid_map_from_msg, grid_map_to_msg

    rng = np.random.default_rng(3)
    data = rng.choice(np.array([-1, 0, 30, 100], dtype=np.int8), size=(6, 9))
    grid = GridMap(data, 0.05, (-2.5, 1.25))
    msg = grid_map_to_msg(grid, 12.5)
    assert (msg.info.width, msg.info.height) == (9, 6)
    assert msg.header.frame_id == "map"
    # Row-major, row 0 at the origin: the message's first value is cell (ix=0, iy=0).
    assert msg.data[0] == data[0, 0] and msg.data[9] == data[1, 0]
    back = grid_map_from_msg(msg)
    np.testing.assert_array_equal(back.data, data)
    assert back.resolution == pytest.approx(0.05)
    assert back.origin == pytest.approx((-2.5, 1.25))


def test_occupancy_grid_fields_are_checked() -> None:
    with pytest.raises(MapError, match="3 x 2 cells carries 5 values"):
        GridMap.from_occupancy_grid(width=3, height=2, resolution=1.0, origin_x=0, origin_y=0, origin_yaw=0, data=[0] * 5)
    with pytest.raises(MapError, match=r"-1\.\.100.*\[-1, 101\]"):
        GridMap.from_occupancy_grid(width=2, height=1, resolution=1.0, origin_x=0, origin_y=0, origin_yaw=0, data=[-1, 101])
    with pytest.raises(MapError, match="rotated map origin.*0.3"):
        GridMap.from_occupancy_grid(width=1, height=1, resolution=1.0, origin_x=0, origin_y=0, origin_yaw=0.3, data=[0])
    with pytest.raises(MapError, match="resolution must be positive.*-1"):
        GridMap(np.zeros((2, 2), np.int8), -1.0)
    with pytest.raises(MapError, match="resolution 1e-30 m is finer than 0.001 m"):
        GridMap(np.zeros((2, 2), np.int8), 1e-30)  # world_to_cell overflowed on it


def test_world_cell_conversions() -> None:
    grid = GridMap(np.zeros((4, 6), np.int8), 0.5, (-1.0, 2.0))
    # World (0.1, 3.2) is 1.1 m right of and 1.2 m above the origin: cell (2, 2).
    assert grid.world_to_cell([0.1, 3.2]).tolist() == [2, 2]
    assert grid.world_to_cell([-1.01, 2.0]).tolist() == [-1, 0]
    np.testing.assert_allclose(grid.cell_to_world([2, 2]), [0.25, 3.25])
    cells = np.array([[0, 0], [5, 3], [6, 0], [0, -1]])
    assert grid.in_bounds(cells).tolist() == [True, True, False, False]
    assert grid.is_free(np.array([[0.1, 3.2], [10.0, 10.0]])).tolist() == [True, False]
    assert grid.extent == pytest.approx((-1.0, 2.0, 2.0, 4.0))


def test_sample_free_poses_lie_in_free_cells() -> None:
    data = np.full((20, 20), 100, dtype=np.int8)
    data[5:10, 2:18] = 0
    grid = GridMap(data, 0.1)
    poses = grid.sample_free_poses(500, np.random.default_rng(0))
    assert poses.shape == (500, 3)
    assert grid.is_free(poses[:, :2]).all()
    assert np.all((poses[:, 2] >= -np.pi) & (poses[:, 2] <= np.pi))
    with pytest.raises(MapError, match="no free cell"):
        GridMap(np.full((3, 3), 100, np.int8), 0.1).sample_free_poses(1, np.random.default_rng(0))


def test_distance_field_values() -> None:
    data = np.zeros((21, 31), dtype=np.int8)
    data[10, 15] = 100  # one obstacle cell
    data[0, 0] = -1  # unknown corner
    grid = GridMap(data, 0.1)
    field = grid.distance_field()
    assert field.dtype == np.float32 and field.shape == (21, 31)
    iy, ix = np.mgrid[0:21, 0:31]
    expected = np.hypot(ix - 15, iy - 10) * 0.1  # Euclidean distance between cell centres [m]
    np.testing.assert_allclose(field, expected, atol=1e-3)
    # Counting unknown cells as obstacles: the corner cell is at distance 0 and its neighbour at one cell.
    with_unknown = grid.distance_field(unknown_is_obstacle=True)
    assert with_unknown[0, 0] == 0.0
    assert with_unknown[0, 1] == pytest.approx(0.1, abs=1e-3)
    assert with_unknown[10, 14] == pytest.approx(0.1, abs=1e-3)
    # Cached: the same array comes back.
    assert grid.distance_field() is field


def test_distance_field_without_obstacles_is_the_map_diagonal() -> None:
    grid = GridMap(np.zeros((3, 4), np.int8), 0.5)
    np.testing.assert_allclose(grid.distance_field(), np.hypot(3, 4) * 0.5)


def test_the_fingerprint_ignores_float32_noise_in_the_resolution_but_not_the_content() -> None:
    data = np.zeros((10, 12), dtype=np.int8)
    data[3, 4] = 100
    from_yaml = GridMap(data, 0.05, (1.0, -2.0))
    from_topic = GridMap(data.copy(), float(np.float32(0.05)), (1.0, -2.0))  # 0.05000000074505806
    assert from_topic.resolution != from_yaml.resolution
    assert from_topic.fingerprint() == from_yaml.fingerprint()
    assert GridMap(data, 0.1, (1.0, -2.0)).fingerprint() != from_yaml.fingerprint()
    assert GridMap(data, 0.05, (1.0, -2.05)).fingerprint() != from_yaml.fingerprint()
    moved = data.copy()
    moved[3, 5] = 100
    assert GridMap(moved, 0.05, (1.0, -2.0)).fingerprint() != from_yaml.fingerprint()


def test_open_unknown_is_the_unknown_space_a_laser_could_see_into() -> None:
    data = np.full((12, 12), -1, dtype=np.int8)
    data[2:10, 2:10] = 100  # a closed room: walls 2 cells thick...
    data[4:8, 4:8] = 0  # ...around free floor
    data[5, 5] = -1  # an unexplored cell on the floor
    closed = GridMap(data, 0.1, (0.0, 0.0))
    mask, off_map = closed.open_unknown()
    assert mask[5, 5] and mask.sum() == 1  # behind the closed walls is not open, nor off the map
    assert not off_map
    opened = data.copy()
    opened[5, 2:4] = -1  # a gap in the wall: the outside is seen through it
    mask, off_map = GridMap(opened, 0.1, (0.0, 0.0)).open_unknown()
    assert mask[0, 0] and mask[5, 2] and off_map
    assert not mask[opened == 100].any() and not mask[4, 4]  # known cells never count


def test_a_map_reaching_beyond_a_thousand_kilometres_is_refused() -> None:
    GridMap(np.zeros((10, 10), np.int8), 0.05, (-999_999.0, 999_999.0))  # within 1e6 m: fine
    for origin, resolution in (((6.6e16, 0.0), 0.05), ((0.0, -2e6), 0.05), ((0.0, 0.0), 3.4e38)):
        with pytest.raises(MapError, match="reaches more than 1e\\+06 m from the origin"):
            GridMap(np.zeros((10, 10), np.int8), resolution, origin)


def test_the_distance_transform_equals_opencvs_exact_one() -> None:
    """core/edt.py replaces cv2.distanceTransform(DIST_L2, DIST_MASK_PRECISE): same distances."""
    from robot_localization_suite.core.edt import distance_to_marked

    rng = np.random.default_rng(7)
    for shape, density in [((1, 1), 1.0), ((1, 9), 0.3), ((11, 1), 0.3), ((40, 70), 0.01), ((120, 90), 0.002),
                           ((33, 33), 0.6)]:
        marked = rng.random(shape) < density
        marked.flat[rng.integers(marked.size)] = True
        expected = cv2.distanceTransform(np.where(marked, 0, 255).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        ours = distance_to_marked(marked)
        assert ours.dtype == np.float32 and ours.shape == shape
        np.testing.assert_allclose(ours, expected, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("pixels", [IMAGE, np.array([[0, 65535, 1000], [300, 7, 40000]], dtype=np.uint16)])
def test_binary_pgm_is_read_as_opencv_reads_it(tmp_path: Path, pixels: np.ndarray) -> None:
    from robot_localization_suite.core.grid_map import _read_binary_pgm

    path = tmp_path / "image.pgm"
    assert cv2.imwrite(str(path), pixels)
    ours = _read_binary_pgm(path)
    assert ours is not None and ours.dtype == pixels.dtype
    np.testing.assert_array_equal(ours, cv2.imread(str(path), cv2.IMREAD_UNCHANGED))
    # A comment in the header, as GIMP writes one, and a file cut short.
    path.write_bytes(b"P5\n# made by hand\n2 1\n255\n\x00\xfe")
    np.testing.assert_array_equal(_read_binary_pgm(path), [[0, 254]])
    path.write_bytes(b"P5\n2 2\n255\n\x00\xfe")
    assert _read_binary_pgm(path) is None
    path.write_bytes(b"P2\n2 1\n255\n0 254\n")
    assert _read_binary_pgm(path) is None
