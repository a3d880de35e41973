"""The one occupancy-grid map type, with nav2 map_server YAML+image I/O.

``GridMap.data`` follows ``nav_msgs/OccupancyGrid``: shape ``(height, width)``,
row 0 at the map origin (lowest y), values ``-1`` (unknown) or ``0..100``
(occupancy probability in percent). ``data[iy, ix]`` is the cell whose lower
left corner is ``origin + (ix, iy) * resolution``.

Loading follows nav2 map_server (``nav2_map_server/src/map_io.cpp``):

* ``trinary``: ``occ = (255 - pixel) / 255`` (or ``pixel / 255`` when
  ``negate``); ``occ > occupied_thresh`` -> 100, ``occ < free_thresh`` -> 0,
  otherwise -1.
* ``scale``: as trinary, but values between the thresholds are scaled
  linearly to ``0..100`` instead of unknown.
* ``raw``: the pixel value itself; values above 100 are unknown.

The image's first row is the top of the map (highest y), so it is flipped.
A rotated origin (non-zero yaw) is refused rather than silently ignored, and so is a map reaching
farther than ``MAX_COORDINATE_M`` from the origin of its frame.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from .errors import MapError

__all__ = ["GridMap", "load_map_yaml", "MAP_MODES", "MAP_IMAGE_FORMATS", "MAX_COORDINATE_M"]

MAP_MODES = ("trinary", "scale", "raw")
MAP_IMAGE_FORMATS = ("pgm", "png")
# Positions farther than this from their frame's origin [m] are refused (maps, odometry, initial poses): no
# robot travels 1,000 km, and within it float64 keeps micrometres (at 6.6e16 m, one step is 8 m).
MAX_COORDINATE_M = 1e6
# Cells finer than this [m] are refused: no laser map has them, and coordinates divided by them overflow.
MIN_RESOLUTION_M = 1e-3

# What nav2 map_saver writes for each cell class in a trinary PGM.
_PGM_OCCUPIED, _PGM_FREE, _PGM_UNKNOWN = 0, 254, 205


@dataclass(eq=False)
class GridMap:
    """Occupancy grid in the ``map`` frame.

    Attributes:
        data: ``(height, width)`` int8 occupancy, -1 unknown, 0..100 percent.
        resolution: cell size [m].
        origin: ``(x, y)`` of the lower left corner of cell (0, 0) [m].
        occupied_threshold: a cell with ``data >= occupied_threshold`` is an obstacle.
        free_threshold: a cell with ``0 <= data <= free_threshold`` is free.
    """

    data: NDArray[np.int8]
    resolution: float
    origin: tuple[float, float] = (0.0, 0.0)
    occupied_threshold: int = 65
    free_threshold: int = 19
    _cache: dict[str, Any] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        data = np.asarray(self.data)
        if data.ndim != 2 or data.size == 0:
            raise MapError(f"map data must be a non-empty 2-D array, got shape {data.shape!r}")
        if not np.isfinite(self.resolution) or self.resolution <= 0.0:
            raise MapError(f"map resolution must be positive, got {self.resolution!r}")
        if self.resolution < MIN_RESOLUTION_M:
            raise MapError(f"map resolution {self.resolution!r} m is finer than {MIN_RESOLUTION_M:g} m: no laser "
                           "map's cells (a unit mixed up?)")
        if len(self.origin) != 2 or not np.all(np.isfinite(self.origin)):
            raise MapError(f"map origin must be two finite numbers, got {self.origin!r}")
        far = np.abs(np.asarray(self.origin, dtype=np.float64)) + np.array(data.shape[::-1]) * self.resolution
        if np.any(far > MAX_COORDINATE_M):
            raise MapError(f"map with origin {self.origin!r}, {data.shape[1]} x {data.shape[0]} cells at "
                           f"{self.resolution!r} m reaches more than {MAX_COORDINATE_M:g} m from the origin")
        self.data = np.ascontiguousarray(data, dtype=np.int8)
        self.resolution = float(self.resolution)
        self.origin = (float(self.origin[0]), float(self.origin[1]))

    # -- geometry -----------------------------------------------------------------
    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` of the map area [m]."""
        x0, y0 = self.origin
        return (x0, x0 + self.width * self.resolution, y0, y0 + self.height * self.resolution)

    def world_to_cell(self, xy: ArrayLike) -> NDArray[np.int64]:
        """Cell indices ``(..., 2)`` as ``(ix, iy)`` of world points ``(..., 2)``; may be off the map."""
        xy = np.asarray(xy, dtype=np.float64)
        origin = np.asarray(self.origin)
        return np.floor((xy - origin) / self.resolution).astype(np.int64)

    def cell_to_world(self, cells: ArrayLike) -> NDArray[np.float64]:
        """World coordinates ``(..., 2)`` of the centres of cells ``(..., 2)`` given as ``(ix, iy)``."""
        cells = np.asarray(cells, dtype=np.float64)
        return (cells + 0.5) * self.resolution + np.asarray(self.origin)

    def in_bounds(self, cells: ArrayLike) -> NDArray[np.bool_]:
        cells = np.asarray(cells)
        return (
            (cells[..., 0] >= 0)
            & (cells[..., 0] < self.width)
            & (cells[..., 1] >= 0)
            & (cells[..., 1] < self.height)
        )

    # -- cell classes -------------------------------------------------------------
    @property
    def occupied_mask(self) -> NDArray[np.bool_]:
        return self.data >= self.occupied_threshold

    @property
    def free_mask(self) -> NDArray[np.bool_]:
        return (self.data >= 0) & (self.data <= self.free_threshold)

    @property
    def unknown_mask(self) -> NDArray[np.bool_]:
        return ~(self.occupied_mask | self.free_mask)

    def open_unknown(self) -> tuple[NDArray[np.bool_], bool]:
        """Unknown space a laser on the map could see into, and whether the space off the map is.

        Unknown cells count when they connect, through unknown cells (4-neighbours), to a free cell; the
        space off the map when a free or such an unknown cell lies on the map's border. Unknown space
        sealed off by obstacles, such as behind a drawn map's closed outer walls, does not.
        """
        key = "open_unknown"
        if key not in self._cache:
            from scipy import ndimage

            unknown = self.unknown_mask
            cross = ndimage.generate_binary_structure(2, 1)
            labels, count = ndimage.label(unknown, structure=cross)
            next_to_free = ndimage.binary_dilation(self.free_mask, structure=cross) & unknown
            open_labels = np.zeros(count + 1, dtype=bool)
            open_labels[np.unique(labels[next_to_free])] = True
            open_labels[0] = False  # label 0: the known cells
            mask = open_labels[labels]
            open_or_free = mask | self.free_mask
            border = np.concatenate([open_or_free[0], open_or_free[-1], open_or_free[:, 0], open_or_free[:, -1]])
            self._cache[key] = (mask, bool(border.any()))
        mask, off_map = self._cache[key]
        return mask, off_map

    def is_free(self, xy: ArrayLike) -> NDArray[np.bool_]:
        """Whether world points ``(..., 2)`` fall in free cells (off-map is not free)."""
        cells = self.world_to_cell(xy)
        inside = self.in_bounds(cells)
        out = np.zeros(inside.shape, dtype=bool)
        ix, iy = cells[..., 0][inside], cells[..., 1][inside]
        out[inside] = self.free_mask[iy, ix]
        return out

    def _free_cells(self) -> NDArray[np.int32] | NDArray[np.int64]:
        """Row-major flat indices of the free cells, 4 bytes each where they fit (a campus map: 46 MB)."""
        if "free_cells" not in self._cache:
            flat = np.flatnonzero(self.free_mask)
            self._cache["free_cells"] = flat.astype(np.int32) if self.data.size < 2**31 else flat
        return self._cache["free_cells"]

    def _flat_to_world(self, flat: NDArray[np.integer]) -> NDArray[np.float64]:
        iy, ix = np.divmod(flat.astype(np.int64), self.width)
        return self.cell_to_world(np.stack([ix, iy], axis=-1))

    def free_cell_centres(self) -> NDArray[np.float64]:
        """World coordinates ``(N, 2)`` of the centres of all free cells (made on each call: 16 bytes a cell)."""
        return self._flat_to_world(self._free_cells())

    def sample_free_poses(self, count: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """``count`` poses uniform over free space (x, y jittered inside the cell, theta uniform)."""
        free = self._free_cells()
        if len(free) == 0:
            raise MapError("the map has no free cell to sample poses from")
        picks = self._flat_to_world(free[rng.integers(0, len(free), size=count)])
        jitter = rng.uniform(-0.5, 0.5, size=(count, 2)) * self.resolution
        theta = rng.uniform(-np.pi, np.pi, size=(count, 1))
        return np.hstack([picks + jitter, theta])

    def distance_field(self, *, unknown_is_obstacle: bool = False, cache: bool = True) -> NDArray[np.float32]:
        """Euclidean distance [m] from each cell centre to the nearest obstacle cell centre.

        Cells with no obstacle on the map get the largest distance the map allows. With
        ``cache`` False a field not computed before is not kept (a large map's is 4 bytes a cell).
        """
        key = f"distance_field_{unknown_is_obstacle}"
        if key in self._cache:
            return self._cache[key]
        if unknown_is_obstacle:
            obstacles = self.data >= self.occupied_threshold
            obstacles |= self.data < 0
            obstacles |= self.data > self.free_threshold
        else:
            obstacles = self.occupied_mask
        if not obstacles.any():
            diagonal = float(np.hypot(self.width, self.height) * self.resolution)
            field_m = np.full(self.data.shape, diagonal, dtype=np.float32)
        else:
            from .edt import distance_to_marked

            field_m = distance_to_marked(obstacles)
            del obstacles
            field_m *= np.float32(self.resolution)
        if cache:
            self._cache[key] = field_m
        return field_m

    def fingerprint(self) -> str:
        """A short hash of the map content, for keying on-disk caches.

        The resolution enters at float32 precision, as nav_msgs/OccupancyGrid carries it: the same map
        from a YAML file (0.05) and from the topic (0.05000000074505806) shares one key.
        """
        import hashlib

        digest = hashlib.sha256()
        digest.update(self.data.tobytes())
        digest.update(np.array([self.resolution], dtype=np.float32).tobytes())
        digest.update(np.array(self.origin, dtype=np.float64).tobytes())
        digest.update(np.array(self.data.shape, dtype=np.int64).tobytes())
        return digest.hexdigest()[:16]

    # -- I/O ----------------------------------------------------------------------
    @classmethod
    def from_occupancy_grid(
        cls,
        *,
        width: int,
        height: int,
        resolution: float,
        origin_x: float,
        origin_y: float,
        origin_yaw: float,
        data: ArrayLike,
    ) -> GridMap:
        """Build from the fields of a ``nav_msgs/OccupancyGrid`` (row-major, row 0 at the origin)."""
        if abs(origin_yaw) > 1e-6:
            raise MapError(f"a rotated map origin is not supported: yaw {origin_yaw!r} rad")
        flat = np.asarray(data, dtype=np.int16)
        if width <= 0 or height <= 0 or flat.size != width * height:
            raise MapError(
                f"occupancy grid of {width!r} x {height!r} cells carries {flat.size} values"
            )
        if flat.size and (flat.min() < -1 or flat.max() > 100):
            raise MapError(f"occupancy values must be -1..100, got range [{flat.min()}, {flat.max()}]")
        return cls(flat.reshape(height, width).astype(np.int8), resolution, (origin_x, origin_y))

    def occupancy_grid_fields(self) -> dict[str, Any]:
        """The fields of a ``nav_msgs/OccupancyGrid`` for this map (data as a flat int8 array)."""
        return {
            "width": self.width,
            "height": self.height,
            "resolution": self.resolution,
            "origin_x": self.origin[0],
            "origin_y": self.origin[1],
            "data": self.data.reshape(-1),
        }

    def save(self, yaml_path: str | os.PathLike[str], *, image_format: str = "pgm") -> Path:
        """Write a nav2 map_server trinary map: ``<name>.yaml`` beside ``<name>.pgm`` (or ``.png``).

        PNG is lossless and a few times smaller for mostly-unknown maps; map_server reads both.
        """
        if image_format not in MAP_IMAGE_FORMATS:
            raise MapError(f"map image format must be one of {MAP_IMAGE_FORMATS}, got {image_format!r}")
        yaml_path = Path(yaml_path)
        image_path = yaml_path.with_suffix(f".{image_format}")
        image = np.full(self.data.shape, _PGM_UNKNOWN, dtype=np.uint8)
        image[self.free_mask] = _PGM_FREE
        image[self.occupied_mask] = _PGM_OCCUPIED
        yaml_path.parent.mkdir(parents=True, exist_ok=True)
        import cv2

        if not cv2.imwrite(str(image_path), np.flipud(image)):
            raise MapError(f"could not write map image {str(image_path)!r}")
        meta = {
            "image": image_path.name,
            "mode": "trinary",
            "resolution": self.resolution,
            "origin": [self.origin[0], self.origin[1], 0.0],
            "negate": 0,
            "occupied_thresh": 0.65,
            "free_thresh": 0.196,
        }
        yaml_path.write_text(yaml.safe_dump(meta, sort_keys=False))
        return yaml_path


def _field(meta: dict[str, Any], name: str, path: Path) -> Any:
    if name not in meta:
        raise MapError(f"map YAML {str(path)!r} has no field {name!r}")
    return meta[name]


def _number(meta: dict[str, Any], name: str, path: Path, default: float | None = None) -> float:
    value = meta.get(name, default) if default is not None else _field(meta, name, path)
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise MapError(f"map YAML {str(path)!r}: field {name!r} must be a number, got {value!r}") from None
    if not np.isfinite(number):
        raise MapError(f"map YAML {str(path)!r}: field {name!r} must be finite, got {value!r}")
    return number


def _occupancy_values(
    pixels: NDArray[np.float64], mode: str, negate: bool, occupied_thresh: float, free_thresh: float
) -> NDArray[np.float64]:
    """map_server's occupancy (-1 unknown, 0..100) of grey levels, as floats."""
    if mode == "raw":
        return np.where(pixels <= 100, pixels, -1.0)
    occ = pixels / 255.0 if negate else (255.0 - pixels) / 255.0
    data = np.full(pixels.shape, -1.0)
    data[occ > occupied_thresh] = 100
    data[occ < free_thresh] = 0
    if mode == "scale":
        between = (occ >= free_thresh) & (occ <= occupied_thresh)
        span = max(occupied_thresh - free_thresh, 1e-9)
        data[between] = np.rint(99.0 * (occ[between] - free_thresh) / span)
    return data


def load_map_yaml(yaml_path: str | os.PathLike[str], *, exact_resolution: bool = False) -> GridMap:
    """Load a nav2 map_server map (YAML + PGM/PNG image), its resolution at the float32 precision ``/map`` carries;
    ``exact_resolution``: as the file writes it (the simulator's world, whose scans the committed bags hold).

    Raises:
        MapError: naming the file, the field and the bad value.
    """
    path = Path(yaml_path)
    if not path.is_file():
        raise MapError(f"map YAML {str(path)!r} does not exist")
    try:
        meta = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise MapError(f"map YAML {str(path)!r} is not valid YAML: {exc}") from exc
    if not isinstance(meta, dict):
        raise MapError(f"map YAML {str(path)!r} must hold a mapping, got {type(meta).__name__}")

    image_name = _field(meta, "image", path)
    resolution = _number(meta, "resolution", path)
    if resolution <= 0.0:
        raise MapError(f"map YAML {str(path)!r}: field 'resolution' must be positive, got {resolution!r}")
    origin = _field(meta, "origin", path)
    if not isinstance(origin, (list, tuple)) or len(origin) != 3:
        raise MapError(f"map YAML {str(path)!r}: field 'origin' must be [x, y, yaw], got {origin!r}")
    try:
        origin_x, origin_y, origin_yaw = (float(v) for v in origin)
    except (TypeError, ValueError):
        raise MapError(f"map YAML {str(path)!r}: field 'origin' must be numbers, got {origin!r}") from None
    if abs(origin_yaw) > 1e-6:
        raise MapError(f"map YAML {str(path)!r}: a rotated origin is not supported, yaw {origin_yaw!r}")
    mode = str(meta.get("mode", "trinary"))
    if mode not in MAP_MODES:
        raise MapError(f"map YAML {str(path)!r}: field 'mode' must be one of {MAP_MODES}, got {mode!r}")
    negate = meta.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise MapError(f"map YAML {str(path)!r}: field 'negate' must be 0 or 1, got {negate!r}")
    occupied_thresh = _number(meta, "occupied_thresh", path, 0.65)
    free_thresh = _number(meta, "free_thresh", path, 0.196)
    if not 0.0 <= free_thresh <= occupied_thresh <= 1.0:
        raise MapError(
            f"map YAML {str(path)!r}: need 0 <= free_thresh <= occupied_thresh <= 1, "
            f"got free_thresh {free_thresh!r}, occupied_thresh {occupied_thresh!r}"
        )

    image_path = (path.parent / str(image_name)).resolve()
    if not image_path.is_file():
        raise MapError(f"map YAML {str(path)!r}: field 'image' names a missing file {str(image_path)!r}")
    pixels = _read_binary_pgm(image_path)
    if pixels is None:  # PNG, ASCII PGM, ...: OpenCV, loaded only for these
        import cv2

        pixels = cv2.imread(str(image_path), cv2.IMREAD_UNCHANGED)
    if pixels is None or pixels.size == 0:
        raise MapError(f"map image {str(image_path)!r} is corrupt or not an image")
    if pixels.ndim == 3:  # colour (and alpha) images: map_server averages the colour channels
        pixels = pixels[..., :3].mean(axis=2)
    if pixels.dtype in (np.uint8, np.uint16):
        # One occupancy value per grey level: a lookup table instead of float images (a 5,000 x 5,000
        # map would otherwise hold several 200 MB temporaries).
        lut = _occupancy_values(np.arange(int(pixels.max()) + 1, dtype=np.float64), mode, bool(negate),
                                occupied_thresh, free_thresh).astype(np.int8)
        data = lut[np.flipud(pixels)]
    else:
        data = _occupancy_values(np.flipud(pixels.astype(np.float64)), mode, bool(negate), occupied_thresh,
                                 free_thresh)
    return GridMap(
        data.astype(np.int8, copy=False),
        # At the float32 precision of nav_msgs/OccupancyGrid, as map_server publishes it: this file and the same
        # map received on /map must be one map (0.05 and 0.05000000074505806 put a point on a cell corner in
        # different cells; docs/benchmark.md, "One map from a file or from /map").
        resolution if exact_resolution else float(np.float32(resolution)),
        (origin_x, origin_y),
        # In scale mode the in-between values are graded, not obstacles nor free space.
        occupied_threshold=100 if mode == "scale" else 65,
        free_threshold=0 if mode == "scale" else 19,
    )


_PGM_HEADER = re.compile(rb"P5(?:\s|#[^\n]*\n)+(\d+)(?:\s|#[^\n]*\n)+(\d+)(?:\s|#[^\n]*\n)+(\d+)\s")


def _read_binary_pgm(path: Path) -> NDArray[Any] | None:
    """The pixels of a binary (P5) PGM, as ``cv2.imread(IMREAD_UNCHANGED)`` reads them; None for other files.

    map_server's usual format is read without OpenCV, so that a laser node never loads it.
    """
    with open(path, "rb") as stream:
        head = stream.read(512)
        match = _PGM_HEADER.match(head)
        if match is None:
            return None
        width, height, maxval = (int(group) for group in match.groups())
        if not 0 < maxval < 65536:
            return None
        stream.seek(match.end())
        dtype = np.dtype(np.uint8) if maxval < 256 else np.dtype(">u2")
        pixels = np.fromfile(stream, dtype=dtype, count=width * height)
    if pixels.size != width * height or width == 0 or height == 0:
        return None  # cut short: OpenCV reports it as a corrupt image
    return pixels.reshape(height, width).astype(dtype.newbyteorder("="), copy=False)
