"""The topological map file of thesis 003 (4.1.3, Figure 4.1): places, their positions, panoramas and heading references.

Written by ``build_topomap``; read by ``ima_topo_localizer``. A missing or corrupt file or panorama is a
:class:`~..errors.MapError` naming it. Notes: docs/ima.md.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from ..errors import MapError

__all__ = ["TopoNode", "TopologicalMap", "load_topomap", "save_topomap"]


@dataclass(frozen=True)
class TopoNode:
    """One place: its name, position in the map frame [m] and panorama."""

    name: str
    x: float
    y: float
    panorama_file: str
    heading_ref: float = 0.0


@dataclass
class TopologicalMap:
    """The topological map: nodes with panoramas, and the camera field of view they were taken with.

    Attributes:
        nodes: the places.
        hfov_deg: horizontal field of view of the camera that took the snapshots [deg].
        panoramas: ``(H, W)`` grey uint8 panorama of each node.
        source: free-form provenance (scenario, settings) written by ``build_topomap``.
    """

    nodes: list[TopoNode]
    hfov_deg: float
    panoramas: list[NDArray[np.uint8]] = field(default_factory=list, repr=False)
    source: dict[str, object] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return [node.name for node in self.nodes]

    @property
    def positions(self) -> NDArray[np.float64]:
        """``(N, 2)`` node positions [m]."""
        return np.array([[node.x, node.y] for node in self.nodes], dtype=np.float64).reshape(-1, 2)

    @property
    def heading_refs(self) -> NDArray[np.float64]:
        return np.array([node.heading_ref for node in self.nodes], dtype=np.float64)

    @property
    def spacing(self) -> float:
        """Median distance from each place to its nearest other [m] (1 m with a single place)."""
        xy = self.positions
        if len(xy) < 2:
            return 1.0
        distance = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
        np.fill_diagonal(distance, math.inf)
        return float(np.median(distance.min(axis=1)))


def _topomap_field(meta: dict, name: str, path: Path, where: str = "") -> object:
    if name not in meta:
        raise MapError(f"topological map {str(path)!r}{where} has no field {name!r}")
    return meta[name]


def _finite(value: object, name: str, path: Path, where: str) -> float:
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise MapError(f"topological map {str(path)!r}{where}: field {name!r} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise MapError(f"topological map {str(path)!r}{where}: field {name!r} must be finite, got {value!r}")
    return number


def load_topomap(yaml_path: str | os.PathLike[str]) -> TopologicalMap:
    """Read a topological map YAML and its panorama images.

    The file holds ``hfov_deg``, optionally ``panorama_dir`` (the first line of
    the thesis' map file; default the YAML's folder) and ``heading_ref``, and
    ``nodes``: a list of ``{name, x, y, panorama[, heading_ref]}``.

    Raises:
        MapError: naming the file, the field and the bad value; a missing
            panorama file is named with its full path.
    """
    path = Path(yaml_path)
    if not path.is_file():
        raise MapError(f"topological map {str(path)!r} does not exist")
    try:
        meta = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise MapError(f"topological map {str(path)!r} is not valid YAML: {exc}") from exc
    if not isinstance(meta, dict):
        raise MapError(f"topological map {str(path)!r} must hold a mapping, got {type(meta).__name__}")
    hfov = _finite(_topomap_field(meta, "hfov_deg", path), "hfov_deg", path, "")
    if not 0.0 < hfov < 360.0:
        raise MapError(f"topological map {str(path)!r}: field 'hfov_deg' must be within (0, 360), got {hfov!r}")
    default_ref = _finite(meta.get("heading_ref", 0.0), "heading_ref", path, "")
    folder = (path.parent / str(meta.get("panorama_dir", "."))).resolve()
    entries = _topomap_field(meta, "nodes", path)
    if not isinstance(entries, list) or not entries:
        raise MapError(f"topological map {str(path)!r}: field 'nodes' must be a non-empty list, got {entries!r}")
    nodes, panoramas, seen = [], [], set()
    for index, entry in enumerate(entries):
        where = f" node {index}"
        if not isinstance(entry, dict):
            raise MapError(f"topological map {str(path)!r}{where} must be a mapping, got {entry!r}")
        name = str(_topomap_field(entry, "name", path, where))
        if name in seen:
            raise MapError(f"topological map {str(path)!r}: node name {name!r} appears twice")
        seen.add(name)
        where = f" node {name!r}"
        x = _finite(_topomap_field(entry, "x", path, where), "x", path, where)
        y = _finite(_topomap_field(entry, "y", path, where), "y", path, where)
        ref = _finite(entry.get("heading_ref", default_ref), "heading_ref", path, where)
        file_name = str(_topomap_field(entry, "panorama", path, where))
        image_path = folder / file_name
        if not image_path.is_file():
            raise MapError(f"topological map {str(path)!r}{where}: panorama file {str(image_path)!r} does not exist")
        pixels = cv2.imread(str(image_path), cv2.IMREAD_GRAYSCALE)
        if pixels is None or pixels.size == 0:
            raise MapError(f"topological map {str(path)!r}{where}: panorama file {str(image_path)!r} is not an image")
        nodes.append(TopoNode(name, x, y, file_name, ref))
        panoramas.append(np.asarray(pixels, dtype=np.uint8))  # IMREAD_GRAYSCALE gives uint8: no copy
    source = meta.get("source", {})
    return TopologicalMap(nodes, hfov, panoramas, source if isinstance(source, dict) else {})


def save_topomap(topomap: TopologicalMap, yaml_path: str | os.PathLike[str]) -> Path:
    """Write the YAML and one PNG per node (``<panorama_file>``) beside it."""
    path = Path(yaml_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if len(topomap.panoramas) != len(topomap.nodes):
        raise ValueError(f"{len(topomap.nodes)} nodes but {len(topomap.panoramas)} panoramas")
    for node, panorama in zip(topomap.nodes, topomap.panoramas, strict=True):
        target = path.parent / node.panorama_file
        if not cv2.imwrite(str(target), np.asarray(panorama, dtype=np.uint8)):
            raise MapError(f"could not write panorama {str(target)!r}")
    meta = {
        "hfov_deg": float(topomap.hfov_deg),
        "panorama_dir": ".",
        "source": topomap.source,
        "nodes": [
            {
                "name": node.name,
                "x": round(float(node.x), 4),
                "y": round(float(node.y), 4),
                "panorama": node.panorama_file,
                "heading_ref": round(float(node.heading_ref), 6),
            }
            for node in topomap.nodes
        ],
    }
    path.write_text(yaml.safe_dump(meta, sort_keys=False))
    return path
