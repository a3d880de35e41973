"""A simulated forward camera: grey or colour images rendered from an occupancy grid.

A column ray caster in the manner of the classic 2.5-D engines: one ray per
image column through the shared :class:`RayCaster`, the wall drawn from the
floor to ``wall_height`` with its on-screen height set by the distance
(pinhole projection), floor and ceiling filled below and above it. Every
surface is anchored to the world, as image matching (IMA, thesis 003
chapter 2) needs: walls carry crops of photographs bundled with scikit-image
chosen by a hash of the wall segment, floor and ceiling are textured at the
world point each pixel sees, and people are textured cylinders that occlude
what is behind them. Lighting variation and pixel noise are applied only when
a random generator is passed to :meth:`CameraRenderer.render`; column 0 is
the left of the image (REP 103).

Notes (textures, shading, mip levels, defaults): docs/simulator.md.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TypedDict

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..grid_map import GridMap
from ..raycast import RayCaster

__all__ = ["CameraSettings", "CameraRenderer", "ENCODINGS", "WALL_PHOTOGRAPHS", "TextureAtlas", "texture_atlas"]

ENCODINGS = ("mono8", "rgb8")

# Photographs bundled in the scikit-image wheel (no download): the wall textures.
WALL_PHOTOGRAPHS = (
    "brick",
    "camera",
    "coins",
    "text",
    "grass",
    "gravel",
    "page",
    "clock",
    "moon",
    "coffee",
    "rocket",
    "chelsea",
    "hubble_deep_field",
    "immunohistochemistry",
    "cell",
    "astronaut",
)

# Texture tiles: one tile covers texture_segment_m x wall_height of wall.
_TILE_WIDTH = 128
_TILE_HEIGHT = 320
_TILE_COUNT = 64
_MIP_LEVELS = 4
_PERSON_TILE = (256, 96)  # rows, columns
_FLOOR_TEXELS_PER_M = 64.0
_LAMP_SPACING_M = 2.0
_LAMP_SIZE_M = 0.6


@dataclass(frozen=True)
class CameraSettings:
    """What the simulated camera is and sees.

    Attributes:
        hfov_deg: horizontal field of view [deg]; default 60 (issue 8; the
            thesis' camera saw about 40, section 5.1.2).
        width, height: image size [px]; default 320 x 240 (issue 8).
        lighting_variation: 0..1, strength of the random per-image lighting
            changes (gain, gradient, diffuse term); thesis 5.2.3 notes windows
            and changing light as its hardest condition.
        texture_seed: selects the photograph crops on the walls.
        encoding: ``mono8`` or ``rgb8`` (sensor_msgs/Image encodings).
        camera_height: lens height above the floor [m]; ~1 m on the thesis'
            PeopleBot (top deck 1.115 m, appendix B).
        wall_height: floor to ceiling [m]; 2.5 m, an office.
        person_height: height of the people cylinders [m].
        noise_std: Gaussian pixel noise [grey levels] added when a generator is given.
        max_range: farthest wall drawn [m]; farther rays see darkness.
        texture_segment_m: length of wall carrying one photograph crop [m].
    """

    hfov_deg: float = 60.0
    width: int = 320
    height: int = 240
    lighting_variation: float = 0.0
    texture_seed: int = 0
    encoding: str = "mono8"
    camera_height: float = 1.0
    wall_height: float = 2.5
    person_height: float = 1.75
    noise_std: float = 2.0
    max_range: float = 40.0
    texture_segment_m: float = 1.0

    def __post_init__(self) -> None:
        if not 1.0 <= self.hfov_deg <= 170.0:
            raise ValueError(f"hfov_deg must be within [1, 170] deg, got {self.hfov_deg!r}")
        if int(self.width) != self.width or not 8 <= self.width <= 4096:
            raise ValueError(f"width must be an integer within [8, 4096] px, got {self.width!r}")
        if int(self.height) != self.height or not 8 <= self.height <= 4096:
            raise ValueError(f"height must be an integer within [8, 4096] px, got {self.height!r}")
        if not 0.0 <= self.lighting_variation <= 1.0:
            raise ValueError(f"lighting_variation must be within [0, 1], got {self.lighting_variation!r}")
        if int(self.texture_seed) != self.texture_seed or self.texture_seed < 0:
            raise ValueError(f"texture_seed must be a non-negative integer, got {self.texture_seed!r}")
        if self.encoding not in ENCODINGS:
            raise ValueError(f"encoding must be one of {ENCODINGS}, got {self.encoding!r}")
        if not 0.0 < self.camera_height < self.wall_height:
            raise ValueError(
                f"camera_height must be within (0, wall_height={self.wall_height!r}) m, got {self.camera_height!r}"
            )
        if not 0.0 < self.person_height <= self.wall_height:
            raise ValueError(f"person_height must be within (0, wall_height] m, got {self.person_height!r}")
        if not 0.0 <= self.noise_std <= 100.0:
            raise ValueError(f"noise_std must be within [0, 100] grey levels, got {self.noise_std!r}")
        if not 0.0 < self.max_range < 1e4:
            raise ValueError(f"max_range must be positive [m], got {self.max_range!r}")
        if not 0.05 <= self.texture_segment_m <= 100.0:
            raise ValueError(f"texture_segment_m must be within [0.05, 100] m, got {self.texture_segment_m!r}")

    @property
    def focal_px(self) -> float:
        """Pinhole focal length [px] (square pixels)."""
        return 0.5 * self.width / math.tan(0.5 * math.radians(self.hfov_deg))

    @property
    def channels(self) -> int:
        return 1 if self.encoding == "mono8" else 3


# -- textures ------------------------------------------------------------------------
def _photograph(name: str) -> NDArray[np.float32]:
    """A photograph of ``skimage.data`` as RGB float32 in [0, 1] (grey images replicated)."""
    import skimage.data

    pixels = np.asarray(getattr(skimage.data, name)())
    if pixels.dtype == bool:
        pixels = pixels.astype(np.uint8) * 255
    if pixels.ndim == 2:
        pixels = np.repeat(pixels[:, :, None], 3, axis=2)
    rgb = pixels[:, :, :3].astype(np.float32)
    return (rgb / 255.0).astype(np.float32, copy=False) if rgb.max() > 1.0 else rgb  # float32 already: no copy


def _pyramid(tiles: NDArray[np.float32]) -> tuple[NDArray[np.float32], ...]:
    """Mip levels of ``(K, H, W, C)`` tiles, each half the size of the previous one."""
    levels = [tiles]
    for _ in range(_MIP_LEVELS - 1):
        previous = levels[-1]
        height, width = previous.shape[1] // 2, previous.shape[2] // 2
        levels.append(
            np.stack([cv2.resize(tile, (width, height), interpolation=cv2.INTER_AREA) for tile in previous]).reshape(
                previous.shape[0], height, width, -1
            )
        )
    return tuple(levels)


class TextureAtlas(TypedDict):
    """What :func:`texture_atlas` returns: float32 RGB in [0, 1]."""

    walls: tuple[NDArray[np.float32], ...]  # mip levels of the (K, H, W, 3) wall tiles
    carpet: NDArray[np.float32]  # (H, W) floor texture
    persons: NDArray[np.float32]  # (2, H, W, 3) person tiles


@functools.lru_cache(maxsize=4)
def texture_atlas(texture_seed: int) -> TextureAtlas:
    """Wall tiles (with mip levels), the floor carpet and the person tiles for one seed.

    Wall tiles are crops of :data:`WALL_PHOTOGRAPHS` with the tile's aspect
    (1 m wide, 2.5 m tall by default), resized with area averaging, their
    albedo mapped to [0.12, 0.92]. Cached per process: the photographs are
    decoded once.
    """
    rng = np.random.default_rng(np.random.SeedSequence([texture_seed, 8008]))
    photos = [_photograph(name) for name in WALL_PHOTOGRAPHS]
    tiles = np.empty((_TILE_COUNT, _TILE_HEIGHT, _TILE_WIDTH, 3), dtype=np.float32)
    aspect = _TILE_WIDTH / _TILE_HEIGHT
    for k in range(_TILE_COUNT):
        photo = photos[k % len(photos)] if k < len(photos) else photos[int(rng.integers(len(photos)))]
        rows, cols = photo.shape[:2]
        crop_h = int(rows * rng.uniform(0.45, 1.0))
        crop_w = max(8, min(cols, int(crop_h * aspect)))
        top = int(rng.integers(0, rows - crop_h + 1))
        left = int(rng.integers(0, cols - crop_w + 1))
        crop = photo[top : top + crop_h, left : left + crop_w]
        tile = np.asarray(cv2.resize(crop, (_TILE_WIDTH, _TILE_HEIGHT), interpolation=cv2.INTER_AREA), dtype=np.float32)
        low, high = np.percentile(tile, [1.0, 99.0])
        tile = (tile - low) / max(high - low, 1e-3)
        tiles[k] = 0.12 + 0.80 * np.clip(tile, 0.0, 1.0)
    carpet = _photograph("gravel").mean(axis=2)
    carpet = 0.40 + 0.12 * (carpet - carpet.mean()) / max(float(carpet.std()), 1e-3) * 0.5
    carpet = cv2.GaussianBlur(np.clip(carpet, 0.2, 0.6), (0, 0), 1.0).astype(np.float32)
    astronaut = _photograph("astronaut")[20:500, 100:400]
    person = cv2.resize(astronaut, (_PERSON_TILE[1], _PERSON_TILE[0]), interpolation=cv2.INTER_AREA)
    persons = np.stack([person, 0.6 * person[:, ::-1, ::-1]]).astype(np.float32)
    return {"walls": _pyramid(tiles), "carpet": carpet, "persons": persons}


def _hash(*keys: NDArray[np.int64] | np.int64) -> NDArray[np.uint64]:
    """A vectorised integer hash (splitmix64 finaliser over a combination of the keys)."""
    with np.errstate(over="ignore"):
        h = np.zeros(np.broadcast_shapes(*(np.shape(k) for k in keys)), dtype=np.uint64)
        for key in keys:
            h = h * np.uint64(0x9E3779B97F4A7C15) + np.asarray(key).astype(np.int64).astype(np.uint64)
            h ^= h >> np.uint64(30)
            h *= np.uint64(0xBF58476D1CE4E5B9)
            h ^= h >> np.uint64(27)
            h *= np.uint64(0x94D049BB133111EB)
            h ^= h >> np.uint64(31)
    return h


# -- renderer ------------------------------------------------------------------------
class CameraRenderer:
    """Render camera images of ``grid_map`` from poses, with people in view.

    Args:
        grid_map: the world (occupied cells are walls; unknown cells are not drawn).
        hfov_deg, width, height, lighting_variation, texture_seed, encoding: see
            :class:`CameraSettings` (these are the scenario ``camera:`` keys).
        **extra: the other :class:`CameraSettings` fields.
    """

    def __init__(
        self,
        grid_map: GridMap,
        *,
        hfov_deg: float = 60.0,
        width: int = 320,
        height: int = 240,
        lighting_variation: float = 0.0,
        texture_seed: int = 0,
        encoding: str = "mono8",
        **extra: float,
    ) -> None:
        self.settings = CameraSettings(
            hfov_deg=float(hfov_deg),
            width=int(width),
            height=int(height),
            lighting_variation=float(lighting_variation),
            texture_seed=int(texture_seed),
            encoding=str(encoding),
            **extra,
        )
        self.grid_map = grid_map
        self._caster = RayCaster(grid_map, max_range=self.settings.max_range)
        atlas = texture_atlas(self.settings.texture_seed)
        grey = self.settings.channels == 1

        def colour(array: NDArray[np.float32]) -> NDArray[np.float32]:
            if not grey:
                return np.ascontiguousarray(array)
            luminance = array @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
            return np.ascontiguousarray(luminance[..., None])

        self._walls = tuple(colour(level) for level in atlas["walls"])
        self._persons = colour(atlas["persons"])
        self._carpet = np.asarray(atlas["carpet"], dtype=np.float32)
        s = self.settings
        self._focal = s.focal_px
        columns = np.arange(s.width) + 0.5
        self._column_angles = np.arctan((0.5 * s.width - columns) / self._focal)  # left column positive
        self._row_offsets = 0.5 * s.height - (np.arange(s.height) + 0.5)  # positive above the horizon

    @property
    def shape(self) -> tuple[int, ...]:
        s = self.settings
        return (s.height, s.width) if s.channels == 1 else (s.height, s.width, 3)

    def render(
        self,
        pose: ArrayLike,
        people: ArrayLike | None = None,
        rng: np.random.Generator | None = None,
    ) -> NDArray[np.uint8]:
        """The image seen from ``pose`` ``(3,)`` [m, m, rad].

        Args:
            pose: camera position and heading in the map frame.
            people: ``(K, 3)`` rows of ``x, y, radius`` [m] of people (may be empty or None).
            rng: when given, lighting variation and pixel noise are drawn from it;
                without it the image is the deterministic nominal one.

        Returns:
            ``(height, width)`` uint8 for mono8, ``(height, width, 3)`` for rgb8.
        """
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(pose)):
            raise ValueError(f"camera pose must be finite, got {pose.tolist()!r}")
        angles = pose[2] + self._column_angles
        return self._render(pose[:2], angles, np.cos(self._column_angles), people, rng)

    def render_panorama(
        self,
        pose: ArrayLike,
        width: int,
        people: ArrayLike | None = None,
        rng: np.random.Generator | None = None,
    ) -> NDArray[np.uint8]:
        """A 360 degree cylindrical image ``width`` columns wide, same vertical scale as :meth:`render`.

        Column 0 looks ``hfov/2`` left of the pose heading and the view turns
        clockwise to the right, so column ``c`` looks at
        ``heading + hfov/2 - 2 pi (c + 0.5) / width``: the layout of a
        panorama rebuilt from snapshots whose first one was taken at the pose
        heading (thesis 003 sections 2.2 and 2.3). Used as ground truth.
        """
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        if int(width) != width or width < 8:
            raise ValueError(f"panorama width must be an integer >= 8 px, got {width!r}")
        half = 0.5 * math.radians(self.settings.hfov_deg)
        angles = pose[2] + half - 2.0 * np.pi * (np.arange(int(width)) + 0.5) / int(width)
        return self._render(pose[:2], angles, np.ones(int(width)), people, rng)

    # -- internals ---------------------------------------------------------------------
    def _render(
        self,
        origin: NDArray[np.float64],
        angles: NDArray[np.float64],
        depth_factor: NDArray[np.float64],
        people: ArrayLike | None,
        rng: np.random.Generator | None,
    ) -> NDArray[np.uint8]:
        """Render columns looking along world ``angles``; ``depth_factor`` turns ray length into depth."""
        s = self.settings
        columns = angles.shape[0]
        channels = s.channels
        focal = self._focal
        rows = self._row_offsets  # (H,) positive above the horizon
        ray = self._caster.cast(np.array([origin[0], origin[1], 0.0]), angles).astype(np.float64)
        hit = np.isfinite(ray)
        distance = np.where(hit, ray, s.max_range)
        depth = np.maximum(distance * depth_factor, 1e-3)
        direction = np.stack([np.cos(angles), np.sin(angles)], axis=1)

        # Heights z [m] seen by each pixel at the wall's depth: z = h_cam + row * depth / f.
        z_wall = s.camera_height + rows[:, None] * depth[None, :] / focal  # (H, W)
        image: NDArray[np.float32] = np.empty((s.height, columns, channels), dtype=np.float32)

        # Floor and ceiling: the world point seen by each pixel above / below the wall.
        with np.errstate(divide="ignore", invalid="ignore"):
            ground = s.camera_height * focal / (-rows[:, None] * depth_factor[None, :])  # ray length to floor
            ceiling = (s.wall_height - s.camera_height) * focal / (rows[:, None] * depth_factor[None, :])
        floor_mask = (z_wall < 0.0) & (rows[:, None] < 0.0)
        ceiling_mask = (z_wall > s.wall_height) & (rows[:, None] > 0.0)
        image[...] = self._floor(origin, direction, ground, floor_mask)[..., None]
        ceiling_value = self._ceiling(origin, direction, ceiling, ceiling_mask)
        image[ceiling_mask] = ceiling_value[ceiling_mask][:, None]

        # Walls.
        wall_mask = ~(floor_mask | ceiling_mask) & hit[None, :]
        if wall_mask.any():
            image[wall_mask] = self._walls_at(origin, direction, distance, depth, z_wall, wall_mask)
        image[~(floor_mask | ceiling_mask) & ~hit[None, :]] = 0.02

        # People occlude what is behind them.
        if people is not None:
            self._draw_people(image, origin, direction, distance, depth_factor, np.asarray(people, dtype=np.float64))

        if rng is not None:
            image = self._vary_lighting(image, rng)
        pixels = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
        return pixels[:, :, 0] if channels == 1 else pixels

    def _floor(
        self,
        origin: NDArray[np.float64],
        direction: NDArray[np.float64],
        ground: NDArray[np.float64],
        mask: NDArray[np.bool_],
    ) -> NDArray[np.float32]:
        """Carpet albedo x distance shading for floor pixels (zero elsewhere)."""
        out = np.zeros(mask.shape, dtype=np.float32)
        if not mask.any():
            return out
        rr, cc = np.nonzero(mask)
        length = ground[rr, cc]
        x = origin[0] + length * direction[cc, 0]
        y = origin[1] + length * direction[cc, 1]
        size = self._carpet.shape[0]
        tx = np.floor(x * _FLOOR_TEXELS_PER_M).astype(np.int64) % size
        ty = np.floor(y * _FLOOR_TEXELS_PER_M).astype(np.int64) % size
        out[rr, cc] = self._carpet[ty, tx] * (0.35 + 0.65 / (1.0 + 0.25 * length))
        return out

    def _ceiling(
        self,
        origin: NDArray[np.float64],
        direction: NDArray[np.float64],
        ceiling: NDArray[np.float64],
        mask: NDArray[np.bool_],
    ) -> NDArray[np.float32]:
        """Ceiling panels with lamps on a 2 m grid, shaded by distance."""
        out = np.zeros(mask.shape, dtype=np.float32)
        if not mask.any():
            return out
        rr, cc = np.nonzero(mask)
        length = ceiling[rr, cc]
        x = origin[0] + length * direction[cc, 0]
        y = origin[1] + length * direction[cc, 1]
        lamp = (np.mod(x, _LAMP_SPACING_M) < _LAMP_SIZE_M) & (np.mod(y, _LAMP_SPACING_M) < _LAMP_SIZE_M)
        seam = (np.mod(x, 0.6) < 0.02) | (np.mod(y, 0.6) < 0.02)
        albedo = np.where(lamp, 1.0, np.where(seam, 0.45, 0.7))
        out[rr, cc] = albedo * (0.45 + 0.55 / (1.0 + 0.2 * length))
        return out

    def _walls_at(
        self,
        origin: NDArray[np.float64],
        direction: NDArray[np.float64],
        distance: NDArray[np.float64],
        depth: NDArray[np.float64],
        z_wall: NDArray[np.float64],
        wall_mask: NDArray[np.bool_],
    ) -> NDArray[np.float32]:
        """Texture values of the wall pixels in ``wall_mask`` (row-major order)."""
        s = self.settings
        gm = self.grid_map
        hit_x = origin[0] + distance * direction[:, 0]
        hit_y = origin[1] + distance * direction[:, 1]
        fx = (hit_x - gm.origin[0]) / gm.resolution
        fy = (hit_y - gm.origin[1]) / gm.resolution
        vertical = np.abs(fx - np.rint(fx)) < np.abs(fy - np.rint(fy))  # face of constant x
        line = np.where(vertical, np.rint(fx), np.rint(fy)).astype(np.int64)
        side = np.where(vertical, np.sign(direction[:, 0]), np.sign(direction[:, 1])).astype(np.int64)
        along = np.where(vertical, hit_y, hit_x)  # world coordinate along the face [m]
        segment = np.floor(along / s.texture_segment_m)
        fraction = along / s.texture_segment_m - segment
        key = _hash(vertical.astype(np.int64), line, side, segment.astype(np.int64), np.int64(s.texture_seed))
        tile = (key % np.uint64(_TILE_COUNT)).astype(np.int64)
        mirror = ((key >> np.uint64(20)) & np.uint64(1)).astype(bool) ^ (side > 0)
        fraction = np.where(mirror, 1.0 - fraction, fraction)
        # Mip level from texels per pixel.
        texels_per_pixel = (_TILE_WIDTH / s.texture_segment_m) * depth / self._focal
        level = np.clip(np.floor(np.log2(np.maximum(texels_per_pixel, 1.0))), 0, _MIP_LEVELS - 1).astype(np.int64)
        # Shading per column: orientation (a fixed sun-like light) and distance attenuation.
        shade = np.where(vertical, 0.82, 1.0) / (1.0 + 0.06 * distance)

        rr, cc = np.nonzero(wall_mask)
        z = np.clip(z_wall[rr, cc], 0.0, s.wall_height * (1.0 - 1e-9))
        out = np.empty((rr.shape[0], s.channels), dtype=np.float32)
        for lvl in range(_MIP_LEVELS):
            pick = level[cc] == lvl
            if not pick.any():
                continue
            atlas = self._walls[lvl]
            tile_h, tile_w = atlas.shape[1], atlas.shape[2]
            col = np.minimum((fraction[cc[pick]] * tile_w).astype(np.int64), tile_w - 1)
            row = np.minimum(((s.wall_height - z[pick]) / s.wall_height * tile_h).astype(np.int64), tile_h - 1)
            out[pick] = atlas[tile[cc[pick]], row, col]
        return out * shade[cc, None].astype(np.float32)

    def _draw_people(
        self,
        image: NDArray[np.float32],
        origin: NDArray[np.float64],
        direction: NDArray[np.float64],
        wall_distance: NDArray[np.float64],
        depth_factor: NDArray[np.float64],
        people: NDArray[np.float64],
    ) -> None:
        """Overwrite the columns where a person stands in front of the wall."""
        if people.size == 0:
            return
        if people.ndim != 2 or people.shape[1] != 3:
            raise ValueError(f"people must be a (K, 3) array of x, y, radius, got shape {people.shape!r}")
        people = people[np.all(np.isfinite(people), axis=1) & (people[:, 2] > 0.0)]
        if people.size == 0:
            return
        s = self.settings
        to_centre = people[None, :, :2] - origin[None, None, :]  # (1, K, 2)
        along = np.einsum("wk,nk->wn", direction, to_centre[0])  # (W, K) projection on the ray
        across = direction[:, 0:1] * to_centre[0][None, :, 1] - direction[:, 1:2] * to_centre[0][None, :, 0]
        radius = people[None, :, 2]
        inside = radius**2 - across**2
        entry = along - np.sqrt(np.maximum(inside, 0.0))
        visible = (inside > 0.0) & (entry > 0.05)
        entry = np.where(visible, entry, np.inf)
        nearest = np.argmin(entry, axis=1)
        columns = np.nonzero(np.isfinite(entry[np.arange(entry.shape[0]), nearest]))[0]
        if columns.size == 0:
            return
        who = nearest[columns]
        distance = entry[columns, who]
        in_front = distance < wall_distance[columns]
        columns, who, distance = columns[in_front], who[in_front], distance[in_front]
        if columns.size == 0:
            return
        lateral = np.clip(across[columns, who] / people[who, 2], -1.0, 1.0)  # -1 .. 1 across the body
        depth = distance * depth_factor[columns]
        z = s.camera_height + self._row_offsets[:, None] * depth[None, :] / self._focal  # (H, C)
        body = (z >= 0.0) & (z <= s.person_height)
        tile_h, tile_w = self._persons.shape[1], self._persons.shape[2]
        rr, kk = np.nonzero(body)
        col = np.minimum(((lateral[kk] + 1.0) * 0.5 * tile_w).astype(np.int64), tile_w - 1)
        row = np.minimum(((s.person_height - z[rr, kk]) / s.person_height * tile_h).astype(np.int64), tile_h - 1)
        shade = (0.55 + 0.45 * np.sqrt(np.maximum(1.0 - lateral[kk] ** 2, 0.0))) / (1.0 + 0.06 * distance[kk])
        values = self._persons[who[kk] % self._persons.shape[0], row, col] * shade[:, None].astype(np.float32)
        image[rr, columns[kk]] = values

    def _vary_lighting(self, image: NDArray[np.float32], rng: np.random.Generator) -> NDArray[np.float32]:
        """Random gain and left-right gradient scaled by ``lighting_variation``, then pixel noise."""
        s = self.settings
        variation = s.lighting_variation
        if variation > 0.0:
            gain = 1.0 + variation * rng.uniform(-0.5, 0.5)
            slope = variation * rng.uniform(-0.4, 0.4)
            ramp = 1.0 + slope * np.linspace(-1.0, 1.0, image.shape[1], dtype=np.float32)
            image = image * np.float32(gain) * ramp[None, :, None]
        if s.noise_std > 0.0:
            image = image + rng.normal(0.0, s.noise_std / 255.0, size=image.shape).astype(np.float32)
        return image
