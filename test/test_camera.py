"""The simulated camera: deterministic, wall textures anchored to the world, people occlude, settings checked."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.sim.camera import CameraRenderer, CameraSettings


def _room() -> GridMap:
    """8 m x 6 m room at 5 cm, walls 10 cm thick, a 1 m x 1 m box near the middle."""
    data = np.zeros((120, 160), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    data[50:70, 90:110] = 100  # box x 4.5-5.5, y 2.5-3.5
    return GridMap(data, 0.05, (0.0, 0.0))


@pytest.fixture(scope="module")
def room() -> GridMap:
    return _room()


def test_render_is_deterministic_without_and_with_a_seeded_generator(room: GridMap) -> None:
    camera = CameraRenderer(room, lighting_variation=0.4, texture_seed=2)
    pose = np.array([2.0, 3.0, 0.3])
    first = camera.render(pose, np.empty((0, 3)))
    assert first.shape == (240, 320) and first.dtype == np.uint8
    assert np.array_equal(first, camera.render(pose, None))
    noisy_a = camera.render(pose, None, np.random.default_rng(5))
    noisy_b = camera.render(pose, None, np.random.default_rng(5))
    assert np.array_equal(noisy_a, noisy_b)
    # the generator's lighting and noise change the image, but not beyond the variation allowed
    difference = np.abs(noisy_a.astype(float) - first.astype(float))
    assert difference.mean() > 1.0
    assert difference.mean() < 0.4 * 255


def test_texture_seed_changes_the_walls(room: GridMap) -> None:
    pose = np.array([2.0, 3.0, 0.0])
    a = CameraRenderer(room, texture_seed=0).render(pose)
    b = CameraRenderer(room, texture_seed=1).render(pose)
    assert np.abs(a.astype(float) - b.astype(float)).mean() > 5.0


def test_a_wall_looks_the_same_from_two_poses(room: GridMap) -> None:
    # A point on the box's west face (x = 4.5), seen head-on-ish from two poses at the same
    # distance but different bearings: the centre column hits that point in both images.
    camera = CameraRenderer(room, width=161, height=121, texture_seed=4)
    target = np.array([4.5, 3.12])  # off the cell corners (x = 4.5 is a cell boundary, y = 3.12 is not)
    distance = 2.0
    columns = []
    for bearing in (math.radians(20.0), math.radians(-25.0)):
        position = target - distance * np.array([math.cos(bearing), math.sin(bearing)])
        image = camera.render(np.array([*position, bearing]))
        # the rows of the wall at that depth: z from 0 to 2.5 m, seen at depth d cos(0) = d
        columns.append(image[:, 80].astype(int))
    depth = distance
    focal = camera.settings.focal_px
    rows = np.arange(121) + 0.5 - 60.5
    z = camera.settings.camera_height - rows * depth / focal
    wall_rows = (z > 0.05) & (z < camera.settings.wall_height - 0.05)
    # same texels, same shading (same distance, same face): identical pixels on the wall
    assert wall_rows.sum() > 60
    assert np.array_equal(columns[0][wall_rows], columns[1][wall_rows])
    # while the same column 0.4 m further along the face is a different part of the texture
    other = camera.render(np.array([*(target + [0.0, 0.4] - distance * np.array([math.cos(0.35), math.sin(0.35)])), 0.35]))
    assert np.abs(other[:, 80].astype(int)[wall_rows] - columns[0][wall_rows]).mean() > 3.0


def test_a_person_occludes_only_the_columns_in_its_direction(room: GridMap) -> None:
    camera = CameraRenderer(room, texture_seed=1)
    pose = np.array([1.5, 3.0, 0.0])
    empty = camera.render(pose)
    person = np.array([[3.0, 3.0, 0.25]])  # 1.5 m ahead, on the optical axis
    occluded = camera.render(pose, person)
    changed = np.nonzero(np.abs(occluded.astype(int) - empty.astype(int)).max(axis=0) > 0)[0]
    # the person spans atan(0.25 / 1.5) = 9.5 deg either side of the axis: ~52 columns of 320
    half_width = camera.settings.focal_px * math.tan(math.asin(0.25 / 1.5))
    assert changed.size > 0
    assert changed.min() >= 160 - half_width - 2 and changed.max() <= 160 + half_width + 2
    # a person behind the camera or inside a wall changes nothing
    assert np.array_equal(camera.render(pose, np.array([[0.6, 3.0, 0.2]])), empty)


def test_encodings_and_panorama_shapes(room: GridMap) -> None:
    colour = CameraRenderer(room, encoding="rgb8", width=64, height=48)
    image = colour.render(np.array([2.0, 2.0, 1.0]))
    assert image.shape == (48, 64, 3) and image.dtype == np.uint8
    assert np.abs(image[..., 0].astype(int) - image[..., 2].astype(int)).max() > 10  # real colours
    grey = CameraRenderer(room, width=64, height=48)
    panorama = grey.render_panorama(np.array([2.0, 2.0, 0.0]), 384)
    assert panorama.shape == (48, 384)
    # column 0 of the panorama looks hfov/2 left of the heading: like the left column of an image
    snapshot = grey.render(np.array([2.0, 2.0, 0.0]))
    assert np.abs(panorama[:, 1].astype(int) - snapshot[:, 0].astype(int)).mean() < 12.0


@pytest.mark.parametrize(
    ("field", "value"),
    [("hfov_deg", 0.0), ("width", 4), ("lighting_variation", 1.5), ("encoding", "bgr16"), ("camera_height", 3.0)],
)
def test_bad_settings_are_refused_naming_the_value(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field):
        CameraSettings(**{field: value})


def test_bad_pose_or_people_are_refused(room: GridMap) -> None:
    camera = CameraRenderer(room, width=32, height=24)
    with pytest.raises(ValueError, match="finite"):
        camera.render(np.array([np.nan, 1.0, 0.0]))
    with pytest.raises(ValueError, match="people"):
        camera.render(np.array([2.0, 2.0, 0.0]), np.zeros((2, 2)))
