"""The package's metadata agrees with its code: what a ROS 2 user installs is what the code needs.

* every ROS package the code imports is an ``exec_depend`` of package.xml;
* every other third-party import is pinned in setup.py and has a rosdep key in package.xml
  (or is one of the pip-only dependencies the README lists);
* every node module starts with ``python -m`` (how ``rls_run`` starts it) and answers ``--help``;
* every ``config/<node>.yaml`` sets only parameters its node declares, with the declared type
  (ROS 2 refuses an integer for a double parameter at start-up, and ignores unknown names).
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from importlib.metadata import distribution, packages_distributions
from pathlib import Path

import pytest
import yaml

from robot_localization_suite.core.settings import flatten_params

PACKAGE = "robot_localization_suite"
ROOT = Path(__file__).resolve().parent.parent
SOURCE = ROOT / PACKAGE

# Distribution (as in setup.py) -> its rosdep key in package.xml; None: pip only (see README).
ROSDEP_KEYS = {
    "numpy": "python3-numpy",
    "opencv-python-headless": "python3-opencv",
    "scipy": "python3-scipy",
    "PyYAML": "python3-yaml",
    "matplotlib": "python3-matplotlib",
    "tqdm": "python3-tqdm",
    "numba": "python3-numba",
    "scikit-image": "python3-skimage",
    "psutil": "python3-psutil",
    "rosbags": None,
    "mcap": None,
    "zstandard": None,
    "foxglove-sdk": None,
    # Optional extras (scale, evo), pip only.
    "dask": None,
    "distributed": None,
    "evo": None,
}


def manifest() -> ET.Element:
    return ET.parse(ROOT / "package.xml").getroot()


def exec_depends() -> set[str]:
    return {element.text.strip() for element in manifest().iter("exec_depend")}


def top_level_imports() -> dict[str, set[str]]:
    """Top-level module name -> files of the package importing it (absolute imports only)."""
    found: dict[str, set[str]] = {}
    for path in SOURCE.rglob("*.py"):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                found.setdefault(name.split(".")[0], set()).add(str(path.relative_to(ROOT)))
    return found


def is_ros_package(name: str) -> bool:
    if name in ("rclpy", "ament_index_python", "rosidl_runtime_py"):
        return True
    try:
        return any(importlib.util.find_spec(f"{name}.{kind}") is not None for kind in ("msg", "srv"))
    except (ImportError, ValueError):
        return False


def third_party(name: str) -> bool:
    return name != PACKAGE and name not in sys.stdlib_module_names and name != "__future__"


def test_manifest_matches_setup() -> None:
    root = manifest()
    assert root.get("format") == "3"
    assert root.findtext("name") == PACKAGE
    dist = distribution(PACKAGE)
    assert root.findtext("version") == dist.version
    assert root.find("export/build_type").text == "ament_python"
    assert (ROOT / "resource" / PACKAGE).is_file()


def test_every_imported_ros_package_is_an_exec_depend() -> None:
    ros = {name: files for name, files in top_level_imports().items() if third_party(name) and is_ros_package(name)}
    assert "rclpy" in ros
    missing = {name: sorted(files) for name, files in ros.items() if name not in exec_depends()}
    assert not missing, f"add <exec_depend> to package.xml for: {missing}"


def test_every_other_import_is_pinned_and_has_a_rosdep_key() -> None:
    requirements = distribution(PACKAGE).requires or []
    # The distribution's name, without its own extras ("dask[distributed]==..." pins dask).
    pinned = {re.split(r"[\[=;<>~! ]", req, maxsplit=1)[0].lower() for req in requirements}
    # Optional tools may import what only an extra installs (e.g. codac for ial_benchmark --codac).
    optional = {re.split(r"[\[=;<>~! ]", req, maxsplit=1)[0].lower() for req in requirements if "extra ==" in req}
    owners = packages_distributions()
    depends = exec_depends()
    problems = []
    for name, files in sorted(top_level_imports().items()):
        if not third_party(name) or is_ros_package(name):
            continue
        dists = owners.get(name, [])
        if not dists and name.lower() in optional:
            continue
        if not dists:
            problems.append(f"{name} (imported by {sorted(files)}) is not installed")
            continue
        dist = dists[0]
        if dist.lower() not in pinned:
            problems.append(f"{name}: distribution {dist} is not in setup.py (imported by {sorted(files)})")
        elif dist not in ROSDEP_KEYS:
            problems.append(f"{name}: add the rosdep key of {dist} to package.xml and to ROSDEP_KEYS here")
        elif ROSDEP_KEYS[dist] is not None and ROSDEP_KEYS[dist] not in depends:
            problems.append(f"{name}: package.xml lacks <exec_depend>{ROSDEP_KEYS[dist]}</exec_depend>")
    assert not problems, "\n".join(problems)


def node_modules() -> list[str]:
    """Node modules behind console scripts that exist in this checkout."""
    names = []
    for entry_point in distribution(PACKAGE).entry_points:
        module = entry_point.value.split(":")[0]
        if entry_point.group == "console_scripts" and module.startswith(f"{PACKAGE}.nodes."):
            if importlib.util.find_spec(module) is not None:
                names.append(module.rsplit(".", 1)[1])
    return sorted(names)


def test_the_console_scripts_and_the_registry_list_the_same_executables() -> None:
    from robot_localization_suite.registry import PLUGINS

    scripts = {ep.name: ep.value for ep in distribution(PACKAGE).entry_points if ep.group == "console_scripts"}
    assert set(node_modules()) == {*PLUGINS, "scan_sim"}
    for name in PLUGINS:
        assert scripts[name] == f"{PACKAGE}.nodes.{name}:main", name


def test_node_modules_start_with_python_m_and_answer_help() -> None:
    modules = node_modules()
    if not modules:
        pytest.skip("no node module in this checkout yet")
    runs = {
        name: subprocess.Popen(
            [sys.executable, "-m", f"{PACKAGE}.nodes.{name}", "--help"],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for name in modules
    }
    failures = {}
    for name, process in runs.items():
        output, _ = process.communicate(timeout=120)
        if process.returncode != 0 or "usage:" not in output or name not in output:
            failures[name] = f"exit {process.returncode}: {output[-600:]}"
    assert not failures, failures


def declared_parameters(name: str) -> dict[str, object]:
    """The parameters a node declares, from the settings classes that define them."""
    from robot_localization_suite.core.settings import parameters
    from robot_localization_suite.core.sim.settings import ScanSimSettings
    from robot_localization_suite.registry import PLUGINS, NodeSettings

    classes = (ScanSimSettings,) if name == "scan_sim" else (NodeSettings, PLUGINS[name].settings)
    return {p.name: p.default for cls in classes for p in parameters(cls)}


def _type_matches(default: object, value: object) -> bool:
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, float)
    return isinstance(value, str)


def test_config_files_set_declared_parameters_with_their_types() -> None:
    checked = 0
    problems = []
    for name in node_modules():
        config = ROOT / "config" / f"{name}.yaml"
        if not config.is_file():
            continue
        declared = declared_parameters(name)
        content = yaml.safe_load(config.read_text()) or {}
        sections = {str(key).lstrip("/"): value for key, value in content.items()}
        section = sections.get(name, sections.get("**"))
        if not isinstance(section, dict) or "ros__parameters" not in section:
            problems.append(f"{config.name}: no '{name}:' or '/**:' section with ros__parameters")
            continue
        for key, value in flatten_params(section["ros__parameters"] or {}).items():
            if key not in declared:
                problems.append(f"{config.name}: {key!r} is not a parameter of {name}")
            elif not _type_matches(declared[key], value):
                problems.append(
                    f"{config.name}: {key}: {value!r} is a {type(value).__name__}, "
                    f"the node declares {type(declared[key]).__name__} (default {declared[key]!r})"
                )
        checked += 1
    assert checked == 7  # scan_sim and the six localizers
    assert not problems, "\n".join(problems)
