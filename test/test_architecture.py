"""The house keeps its shape: core without ROS, nothing but the node executables imports nodes/, caches outside the tree."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "robot_localization_suite"


def _imported_modules(path: Path) -> set[str]:
    """Absolute names of the modules a file imports (relative imports resolved), wherever in the file."""
    module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
    package = module.rsplit(".", 1)[0] if path.name != "__init__.py" else module.removesuffix(".__init__")
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package.split(".")
            if node.level:
                base = base[: len(base) - (node.level - 1)]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            found.add(name)
            found.update(f"{name}.{alias.name}" for alias in node.names)
    return found


def test_tools_launch_registry_and_core_never_import_nodes() -> None:
    offenders = []
    files = [PACKAGE / "registry.py", *(PACKAGE / "tools").rglob("*.py"), *(PACKAGE / "launch").rglob("*.py"),
             *(PACKAGE / "core").rglob("*.py"), *(PACKAGE / "ros").rglob("*.py")]
    for path in files:
        if any(name.startswith("robot_localization_suite.nodes") for name in _imported_modules(path)):
            offenders.append(str(path.relative_to(ROOT)))
    assert len(files) > 40
    assert not offenders, offenders


def test_core_and_the_registry_never_import_rclpy_or_ros_messages() -> None:
    ros_roots = {"rclpy", "rcl_interfaces", "sensor_msgs", "nav_msgs", "geometry_msgs", "std_msgs", "std_srvs",
                 "diagnostic_msgs", "visualization_msgs", "builtin_interfaces", "tf2_msgs", "nav2_msgs"}
    offenders = []
    for path in [PACKAGE / "registry.py", *(PACKAGE / "core").rglob("*.py")]:
        roots = {name.split(".")[0] for name in _imported_modules(path)}
        if roots & ros_roots:
            offenders.append(f"{path.relative_to(ROOT)}: {sorted(roots & ros_roots)}")
    assert not offenders, offenders


_NO_ROS = """
import importlib.abc, sys
class NoRos(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split('.')[0] in {'rclpy', 'sensor_msgs', 'nav_msgs', 'geometry_msgs', 'rcl_interfaces'}:
            raise ImportError(f'{name} is not importable in this test')
        return None
sys.meta_path.insert(0, NoRos())
import pkgutil, importlib
import robot_localization_suite.core as core
names = [m.name for m in pkgutil.walk_packages(core.__path__, 'robot_localization_suite.core.')]
for name in names:
    importlib.import_module(name)
import robot_localization_suite.registry as registry
for plugin in registry.PLUGINS.values():
    if not plugin.uses_camera:
        plugin.create()
print(len(names))
"""


def test_core_and_every_laser_plugin_work_with_rclpy_unimportable() -> None:
    result = subprocess.run([sys.executable, "-c", _NO_ROS], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-2000:]
    assert int(result.stdout.split()[-1]) > 30  # every module of core/ was imported


def test_the_registry_imports_no_method_code_and_no_numba() -> None:
    code = ("import sys, robot_localization_suite.registry as r; "
            "heavy = [m for m in ('numba', 'cv2', 'scipy', 'robot_localization_suite.core.mcl.localizer') "
            "if m in sys.modules]; print(heavy)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip() == "[]"


def test_numba_kernels_are_cached_under_the_cache_directory_not_in_the_tree(tmp_path: Path) -> None:
    code = ("import numpy as np; from robot_localization_suite.core.grid_map import GridMap; "
            "from robot_localization_suite.core.raycast import RayCaster; "
            "data = np.zeros((20, 20), np.int8); data[:, 15:] = 100; "
            "print(RayCaster(GridMap(data, 0.1, (0.0, 0.0)), max_range=5.0).cast(np.array([0.55, 1.05, 0.0]), "
            "np.zeros(1))[0].round(2))")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["RLS_CACHE_DIR"] = str(tmp_path)
    before = {p: p.stat().st_mtime for p in PACKAGE.rglob("*.nbi")}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT, env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.split()[-1] == "0.95"  # from x = 0.55 m to the wall at x = 1.5 m
    assert list((tmp_path / "numba").rglob("*.nbi")), "no numba index under the cache directory"
    after = {p: p.stat().st_mtime for p in PACKAGE.rglob("*.nbi")}
    assert after == before, "numba wrote into the source tree"


_LOADED = ("import sys, importlib; importlib.import_module(sys.argv[1]); "
           "print(sorted(m for m in ('cv2', 'matplotlib', 'robot_localization_suite.tools') if m in sys.modules))")


def test_a_node_module_loads_opencv_only_for_a_camera_method_and_never_plotting_or_the_benchmark() -> None:
    from robot_localization_suite.registry import PLUGINS

    for name, plugin in PLUGINS.items():
        result = subprocess.run([sys.executable, "-c", _LOADED, f"robot_localization_suite.nodes.{name}"],
                                capture_output=True, text=True, timeout=120, cwd=ROOT)
        assert result.returncode == 0, result.stderr[-2000:]
        loaded = eval(result.stdout.strip())  # noqa: S307 - a list literal printed by the child
        assert "matplotlib" not in loaded and "robot_localization_suite.tools" not in loaded, (name, loaded)
        if not plugin.uses_camera:
            assert "cv2" not in loaded, f"importing the {name} node loads OpenCV"


_LASER_SETUP = """
import sys
from robot_localization_suite.core.grid_map import load_map_yaml
from robot_localization_suite.registry import PLUGINS
for plugin in PLUGINS.values():
    if not plugin.uses_camera:
        plugin.create(plugin.load_settings()[1]).set_map(load_map_yaml('config/maps/office.yaml'))
print('cv2' in sys.modules)
"""


def test_no_laser_method_loads_opencv_to_set_up_a_map() -> None:
    """Map image, distance field, clearance codes, IAL's erosion: what configure does, without OpenCV."""
    result = subprocess.run([sys.executable, "-c", _LASER_SETUP], capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.split()[-1] == "False"


_COMPILE = ("import logging, numpy as np; logging.basicConfig(level=logging.INFO); "
            "from robot_localization_suite.core.cache import log_kernel_compilations; log_kernel_compilations(); "
            "from robot_localization_suite.core.edt import distance_to_marked; "
            "print(distance_to_marked(np.eye(3, dtype=bool))[0, 1])")


def test_a_cold_kernel_cache_says_what_it_compiles_and_a_warm_one_does_not(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["RLS_CACHE_DIR"] = str(tmp_path)
    runs = [subprocess.run([sys.executable, "-c", _COMPILE], capture_output=True, text=True, timeout=300, cwd=ROOT,
                           env=env) for _ in range(2)]
    for run in runs:
        assert run.returncode == 0, run.stderr[-2000:]
        assert float(run.stdout.split()[-1]) == 1.0
    assert "compiling core.edt._squared_distances" in runs[0].stderr
    assert "compiled core.edt._squared_distances in" in runs[0].stderr
    assert "compiling" not in runs[1].stderr
