"""The localizers this package offers, by executable name, and how to build one without a node.

Each localizer node module defines ``NODE_NAME``, ``DESCRIPTION``, ``PARAMS``,
``make_localizer(params)`` and optionally ``EXTRAS``, ``build_extras`` and
``USES_CAMERA`` (see ``nodes/localizer_node.py``). The benchmark and the demo
find them here; a localizer whose module is not importable is simply absent.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType
from typing import Any

import yaml

__all__ = ["LOCALIZER_NAMES", "available_localizers", "load_localizer_module", "localizer_params", "config_dir"]

LOCALIZER_NAMES = ("mcl_baseline", "pil_localizer", "ir_initializer", "ial_localizer", "ima_topo_localizer")


def load_localizer_module(name: str) -> ModuleType:
    if name not in LOCALIZER_NAMES:
        raise KeyError(f"unknown localizer {name!r}; known: {', '.join(LOCALIZER_NAMES)}")
    return importlib.import_module(f"robot_localization_suite.nodes.{name}")


def available_localizers() -> list[str]:
    """The localizers whose node module exists in this checkout."""
    found = []
    for name in LOCALIZER_NAMES:
        try:
            load_localizer_module(name)
        except ModuleNotFoundError:
            continue
        found.append(name)
    return found


def config_dir() -> Path:
    """``config/`` of the source tree, or ``share/robot_localization_suite/config`` once installed."""
    source = Path(__file__).resolve().parent.parent / "config"
    if source.is_dir():
        return source
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("robot_localization_suite")) / "config"
    except Exception:  # noqa: BLE001 - no ament index outside a ROS install
        return source


def localizer_params(name: str, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Parameter values of a localizer: declared defaults, then ``config/<name>.yaml``, then overrides."""
    from .nodes.localizer_node import COMMON_PARAMS

    module = load_localizer_module(name)
    params = {spec.name: spec.default for spec in (*COMMON_PARAMS, *module.PARAMS)}
    config_file = config_dir() / f"{name}.yaml"
    if config_file.is_file():
        loaded = yaml.safe_load(config_file.read_text()) or {}
        section = loaded.get(name, loaded.get("/**", {})).get("ros__parameters", {})
        params.update(section)
    params.update(overrides or {})
    return params
