"""Generate the three simulated maps of ``config/maps`` reproducibly (no randomness).

    python -m robot_localization_suite.tools.make_maps [--out config/maps] [--resolution 0.05]

Writes nav2 map_server trinary maps (``<name>.yaml`` + ``<name>.pgm``) with :meth:`GridMap.save`:
``office`` (20 m x 20 m, with two identical offices side by side), ``office_changed`` (the same
office later: two doors closed, furniture moved; a scenario's map change), ``floor`` (30 m x 11 m, the PIL
paper's kidnapping floor, 002 section 3) and ``corridor`` (26 m x 4 m, the IAL paper's symmetric
corridor, 004 section 4.3, broken by one cabinet). Their layout and why: docs/simulator.md, "Maps".
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from ..core.grid_map import MIN_RESOLUTION_M, GridMap

__all__ = ["build_office", "build_office_changed", "build_floor", "build_corridor", "MAP_BUILDERS", "main"]

OCCUPIED, FREE = 100, 0
# Coarsest --resolution [m]: the 4 m corridor is then 8 cells across, its 0.15 m walls a cell each.
MAX_RESOLUTION_M = 0.5


class _Canvas:
    """A free rectangle of ``width_m`` x ``height_m`` on which obstacles are drawn in metres."""

    def __init__(self, width_m: float, height_m: float, resolution: float) -> None:
        self.resolution = resolution
        self.width = int(round(width_m / resolution))
        self.height = int(round(height_m / resolution))
        self.data = np.full((self.height, self.width), FREE, dtype=np.int8)

    def _cells(self, low: float, high: float, size: int) -> slice:
        start = max(0, int(math.floor(low / self.resolution + 1e-9)))
        stop = min(size, int(math.ceil(high / self.resolution - 1e-9)))
        return slice(start, max(start, stop))

    def box(self, x0: float, y0: float, x1: float, y1: float, value: int = OCCUPIED) -> None:
        """Fill every cell the rectangle ``[x0, x1] x [y0, y1]`` touches."""
        self.data[self._cells(y0, y1, self.height), self._cells(x0, x1, self.width)] = value

    def clear(self, x0: float, y0: float, x1: float, y1: float) -> None:
        """Make a rectangle free (door openings, niches)."""
        self.box(x0, y0, x1, y1, FREE)

    def disc(self, cx: float, cy: float, radius: float) -> None:
        """Fill every cell whose centre lies within ``radius`` of ``(cx, cy)`` (pillars, round tables)."""
        ys = (np.arange(self.height) + 0.5) * self.resolution
        xs = (np.arange(self.width) + 0.5) * self.resolution
        inside = (xs[None, :] - cx) ** 2 + (ys[:, None] - cy) ** 2 <= radius**2
        self.data[inside] = OCCUPIED

    def outer_walls(self, thickness: float) -> None:
        w, h = self.width * self.resolution, self.height * self.resolution
        self.box(0.0, 0.0, w, thickness)
        self.box(0.0, h - thickness, w, h)
        self.box(0.0, 0.0, thickness, h)
        self.box(w - thickness, 0.0, w, h)

    def grid_map(self) -> GridMap:
        return GridMap(self.data.copy(), self.resolution, (0.0, 0.0))


WALL = 0.15


def _twin_room(canvas: _Canvas, x0: float) -> None:
    """One of the two identical offices: interior x0 + [0, 4.85], y 0.15..7.85, door north."""
    canvas.box(x0 + 0.0, 1.0, x0 + 0.7, 2.6)  # desk along the west wall
    canvas.box(x0 + 1.85, 0.0, x0 + 3.45, 0.7)  # desk along the south wall
    canvas.box(x0 + 4.2, 5.0, x0 + 4.85, 6.5)  # filing cabinet in the east corner
    canvas.disc(x0 + 2.35, 4.4, 0.45)  # round table


def build_office(resolution: float = 0.05) -> GridMap:
    """20 m x 20 m office floor (see the module docstring)."""
    return _office(resolution).grid_map()


def build_office_changed(resolution: float = 0.05) -> GridMap:
    """The office floor some days later (a map change, docs/simulator.md): the meeting room and kitchen
    doors closed, the west desk island of the open plan 0.8 m further west, the corridor bench moved from
    the east to the west end, a cabinet against the corridor wall between the twin offices' doors."""
    c = _office(resolution)
    c.box(5.5, 10.0, 6.4, 10.15)  # meeting room door closed
    c.box(8.9, 10.0, 9.8, 10.15)  # kitchen door closed
    c.clear(12.0, 4.8, 13.6, 6.2)
    c.box(11.2, 4.8, 12.8, 6.2)  # desk island moved west
    c.clear(13.5, 9.6, 15.0, 10.0)
    c.box(3.5, 9.6, 5.0, 10.0)  # corridor bench moved west
    c.box(6.0, 8.0, 7.2, 8.35)  # new cabinet in the corridor
    return c.grid_map()


def _office(resolution: float) -> _Canvas:
    c = _Canvas(20.0, 20.0, resolution)
    c.outer_walls(WALL)
    # Corridor y 8.0..10.0 across the whole floor.
    c.box(0.0, 7.85, 20.0, 8.0)
    c.box(0.0, 10.0, 20.0, 10.15)
    # South block: two twin offices, then an open-plan area.
    c.box(5.0, 0.0, 5.15, 8.0)
    c.box(10.0, 0.0, 10.15, 8.0)
    for x0 in (0.15, 5.15):
        _twin_room(c, x0)
        c.clear(x0 + 3.35, 7.85, x0 + 4.25, 8.0)  # door 0.9 m
    c.clear(11.0, 7.85, 13.0, 8.0)  # wide opening into the open plan
    c.clear(17.5, 7.85, 18.4, 8.0)  # second door of the open plan
    c.box(12.0, 2.0, 15.2, 3.4)  # desk island
    c.box(12.0, 4.8, 13.6, 6.2)  # desk island
    c.box(16.6, 4.2, 19.85, 5.0)  # low shelf from the east wall
    c.box(16.8, 0.15, 19.85, 1.1)  # cupboards along the south wall
    c.disc(15.6, 6.6, 0.3)  # pillar
    # North block: meeting room, kitchen, storage, lab.
    c.box(7.0, 10.0, 7.15, 20.0)
    c.box(11.0, 10.0, 11.15, 20.0)
    c.box(7.0, 15.0, 11.15, 15.15)
    c.clear(5.5, 10.0, 6.4, 10.15)  # meeting room door
    c.box(2.0, 13.5, 5.0, 16.0)  # meeting table
    c.box(0.15, 18.9, 2.4, 19.85)  # sideboard
    c.clear(8.9, 10.0, 9.8, 10.15)  # kitchen door
    c.box(10.4, 10.15, 11.0, 14.0)  # kitchen counter along the east wall
    c.box(7.15, 12.5, 7.9, 13.3)  # fridge
    c.clear(7.5, 15.0, 8.4, 15.15)  # storage door from the kitchen
    c.box(9.0, 17.0, 10.95, 19.85)  # storage shelves
    c.clear(16.0, 10.0, 17.5, 10.15)  # lab door (1.5 m)
    c.box(15.0, 14.0, 15.15, 20.0)  # lab partition, open to the south
    c.disc(13.5, 16.5, 0.25)  # lab pillar
    c.box(11.15, 11.6, 12.3, 13.6)  # lab bench
    c.box(17.0, 13.0, 19.85, 13.8)  # lab bench from the east wall
    c.box(16.2, 17.2, 18.4, 18.2)  # lab machine
    # Corridor details (asymmetric).
    c.box(2.2, 9.75, 3.0, 10.0)  # water fountain
    c.box(13.5, 9.6, 15.0, 10.0)  # bench
    return c


def build_floor(resolution: float = 0.05) -> GridMap:
    """30 m x 11 m building floor after the PIL paper, section 3 (see the module docstring)."""
    c = _Canvas(30.0, 11.0, resolution)
    c.outer_walls(WALL)
    # Main corridor y 4.5..6.5 along the whole floor.
    c.box(0.0, 4.35, 30.0, 4.5)
    c.box(8.0, 6.5, 30.0, 6.65)  # north wall from x = 8: west of it the hall is open
    # South rooms.
    for x in (5.0, 9.0, 23.0):
        c.box(x, 0.0, x + WALL, 4.5)
    c.clear(3.5, 4.35, 4.4, 4.5)  # R1 door
    c.clear(6.0, 4.35, 6.9, 4.5)  # R2 door
    c.clear(11.0, 4.35, 11.9, 4.5)  # R3 (lab) door
    c.clear(26.0, 4.35, 26.9, 4.5)  # R4 door
    c.box(0.15, 0.15, 1.0, 2.5)  # R1 cupboard
    c.box(2.5, 1.5, 3.7, 2.3)  # R1 desk
    c.box(7.5, 0.15, 8.85, 1.2)  # R2 desk
    for x in (10.5, 14.0, 17.5):  # R3 lab benches
        c.box(x, 1.2, x + 2.2, 2.0)
    c.box(21.0, 0.15, 22.85, 3.2)  # R3 machine
    c.disc(25.5, 2.0, 0.4)  # R4 round table
    c.box(28.6, 0.15, 29.85, 1.8)  # R4 cupboard
    # North side: open hall (x < 8), a long room, the corridor stub and two rooms.
    c.disc(3.0, 8.7, 0.35)  # hall pillar
    c.box(5.0, 9.6, 7.0, 10.85)  # hall reception desk
    c.box(0.15, 6.5, 0.9, 7.7)  # hall plant box
    c.box(22.0, 6.5, 22.15, 11.0)  # long room east wall
    c.clear(20.1, 6.5, 21.0, 6.65)  # long room door
    c.box(9.5, 8.5, 13.5, 9.3)  # long room table
    c.box(16.0, 10.0, 21.85, 10.85)  # long room shelves
    c.box(24.0, 6.5, 24.15, 11.0)  # corridor stub x 24.15..26
    c.box(26.0, 6.5, 26.15, 11.0)
    c.clear(24.15, 6.5, 26.0, 6.65)  # the stub opens onto the corridor
    c.clear(24.0, 8.0, 24.15, 8.9)  # door from the stub into N3
    c.clear(26.0, 9.2, 26.15, 10.1)  # door from the stub into N4
    c.box(22.15, 9.8, 23.2, 10.85)  # N3 cupboard
    c.box(27.5, 7.5, 29.85, 8.3)  # N4 desk
    return c.grid_map()


def build_corridor(resolution: float = 0.05) -> GridMap:
    """26 m x 4 m nearly symmetric corridor after the IAL paper, section 4.3 (see the module docstring)."""
    c = _Canvas(26.0, 4.0, resolution)
    wall = 0.3
    c.outer_walls(wall)
    south_niches = (2.5, 7.0, 11.0, 17.5, 21.0)  # left edges of 1 m door niches, 0.2 m deep
    for a in south_niches:
        c.clear(a, 0.1, a + 1.0, wall)
        c.clear(26.0 - a - 1.0, 4.0 - wall, 26.0 - a, 3.9)  # the twin on the north wall
    pillars = ((5.0, 0.3, 5.3, 0.6), (14.5, 0.3, 14.8, 0.6))  # wall pillars 0.3 x 0.3
    for x0, y0, x1, y1 in pillars:
        c.box(x0, y0, x1, y1)
        c.box(26.0 - x1, 4.0 - y1, 26.0 - x0, 4.0 - y0)
    c.box(9.0, 0.3, 10.2, 0.55)  # bench along the south wall, and its twin
    c.box(15.8, 3.45, 17.0, 3.7)
    # The one asymmetric object: a cabinet in the westmost south niche.
    c.box(2.65, 0.1, 3.35, 0.5)
    return c.grid_map()


MAP_BUILDERS = {"office": build_office, "office_changed": build_office_changed, "floor": build_floor, "corridor": build_corridor}


def _resolution(text: str) -> float:
    """``--resolution``: a cell size [m] within ``[MIN_RESOLUTION_M, MAX_RESOLUTION_M]``."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not MIN_RESOLUTION_M <= value <= MAX_RESOLUTION_M:  # NaN too
        raise argparse.ArgumentTypeError(f"must be within [{MIN_RESOLUTION_M:g}, {MAX_RESOLUTION_M:g}] m, got {text!r}")
    return value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="config/maps", help="output folder (default: config/maps)")
    parser.add_argument(
        "--resolution", type=_resolution, default=0.05,
        help=f"cell size [m], {MIN_RESOLUTION_M:g}..{MAX_RESOLUTION_M:g} (default 0.05)",
    )
    parser.add_argument("names", nargs="*", default=list(MAP_BUILDERS), help="maps to write (default: all)")
    options = parser.parse_args(argv)
    out = Path(options.out)
    blocked = next((path for path in (out, *out.parents) if path.exists() and not path.is_dir()), None)
    if blocked is not None:
        parser.error(f"--out {options.out!r}: {str(blocked)!r} is a file, not a folder")
    for name in options.names:
        if name not in MAP_BUILDERS:
            parser.error(f"unknown map {name!r}; choose from {sorted(MAP_BUILDERS)}")
        grid_map = MAP_BUILDERS[name](options.resolution)
        path = grid_map.save(out / f"{name}.yaml")
        occupied = float(grid_map.occupied_mask.mean())
        print(f"{path}: {grid_map.width} x {grid_map.height} cells, {occupied:.1%} occupied")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
