"""``colcon build`` of the package in a fresh workspace installs what ``ros2 run`` and ``ros2 launch`` need.

On a ROS 2 machine ``ros2 run robot_localization_suite scan_sim`` starts
``install/robot_localization_suite/lib/robot_localization_suite/scan_sim`` and
nodes find their parameter files under ``share/robot_localization_suite/config``.
This test follows the README's steps (``colcon build --packages-select``, ``source
install/setup.bash``) with the colcon packages ``make`` installs from PyPI, and runs
the installed executables with the environment ``install/setup.sh`` would set.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = "robot_localization_suite"
# Never copied into the workspace: local state that is not part of the package.
_IGNORED = (".venv", ".git", "build", "install", "log", "results", "__pycache__", "*.egg-info", ".ruff_cache",
            ".hypothesis", ".pytest_cache", ".cache")


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory, repo_root: Path) -> Path:
    ws = tmp_path_factory.mktemp("colcon_ws")
    shutil.copytree(repo_root, ws / "src" / PACKAGE, ignore=shutil.ignore_patterns(*_IGNORED))
    # The README's command, as written, with the colcon make installs (interfaces/ has a COLCON_IGNORE).
    result = subprocess.run(
        [sys.executable, "-m", "colcon", "build", "--packages-select", PACKAGE, "--event-handlers", "console_direct-"],
        cwd=ws,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, f"colcon build failed:\n{result.stdout[-4000:]}\n{result.stderr[-4000:]}"
    assert f"Finished <<< {PACKAGE}" in result.stdout + result.stderr
    return ws


def installed_environment(ws: Path) -> dict[str, str]:
    """What sourcing ``install/setup.sh`` sets for this package: PYTHONPATH first, the ament prefix."""
    prefix = ws / "install" / PACKAGE
    site = prefix / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["AMENT_PREFIX_PATH"] = os.pathsep.join([str(prefix), env.get("AMENT_PREFIX_PATH", "")]).rstrip(os.pathsep)
    return env


def test_installed_scan_sim_runs(workspace: Path, tmp_path: Path) -> None:
    executable = workspace / "install" / PACKAGE / "lib" / PACKAGE / "scan_sim"
    assert executable.is_file() and os.access(executable, os.X_OK)
    result = subprocess.run(
        [str(executable), "--help"], env=installed_environment(workspace), cwd=tmp_path,
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "usage:" in result.stdout and "scan_sim" in result.stdout


def test_every_console_script_is_installed(workspace: Path) -> None:
    from importlib.metadata import distribution

    scripts = {ep.name for ep in distribution(PACKAGE).entry_points if ep.group == "console_scripts"}
    assert {"scan_sim", "rls_run", "rls_demo", "raycast_benchmark"} <= scripts
    lib = workspace / "install" / PACKAGE / "lib" / PACKAGE
    assert sorted(path.name for path in lib.iterdir()) == sorted(scripts)


def test_share_holds_marker_manifest_config_and_bags(workspace: Path, repo_root: Path) -> None:
    prefix = workspace / "install" / PACKAGE
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()
    share = prefix / "share" / PACKAGE
    assert (share / "package.xml").read_text() == (repo_root / "package.xml").read_text()
    for folder in ("config", "bags"):
        source_files = sorted(
            path.relative_to(repo_root) for path in (repo_root / folder).rglob("*")
            if path.is_file() and "__pycache__" not in path.parts
        )
        installed = sorted(path.relative_to(share) for path in (share / folder).rglob("*") if path.is_file()) \
            if (share / folder).is_dir() else []
        assert installed == source_files, folder


def test_installed_package_finds_its_share_directory(workspace: Path, tmp_path: Path) -> None:
    probe = (
        "import robot_localization_suite, robot_localization_suite.registry as r;"
        "print(robot_localization_suite.__file__); print(r.config_dir())"
    )
    result = subprocess.run(
        [sys.executable, "-c", probe], env=installed_environment(workspace), cwd=tmp_path,
        capture_output=True, text=True, timeout=60,
    )
    assert result.returncode == 0, result.stderr
    module_file, config = result.stdout.split()
    # The installed copy is imported, not the checkout, and its config is the share directory's.
    assert Path(module_file).is_relative_to(workspace / "install")
    assert Path(config) == workspace / "install" / PACKAGE / "share" / PACKAGE / "config"


def test_sourcing_install_setup_bash_finds_the_installed_package(workspace: Path, tmp_path: Path) -> None:
    """The README's `source install/setup.bash`, then the installed package and its share directory."""
    probe = "import robot_localization_suite.registry as r; print(r.__file__); print(r.config_dir())"
    result = subprocess.run(
        ["bash", "-c", f"source {workspace / 'install' / 'setup.bash'} && {sys.executable} -c '{probe}'"],
        cwd=tmp_path, capture_output=True, text=True, timeout=60,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    module_file, config = result.stdout.split()[-2:]
    assert Path(module_file).is_relative_to(workspace / "install")
    assert Path(config) == workspace / "install" / PACKAGE / "share" / PACKAGE / "config"


def test_help_shows_the_invocation_that_works_here(workspace: Path, tmp_path: Path) -> None:
    """`ros2 run ...` only where there is a ros2; otherwise the executable as it was started."""
    import shutil

    executable = workspace / "install" / PACKAGE / "lib" / PACKAGE / "mcl_baseline"
    result = subprocess.run([str(executable), "--help"], env=installed_environment(workspace), cwd=tmp_path,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    usage = result.stdout.splitlines()[0]
    if shutil.which("ros2"):
        assert usage.startswith("usage: ros2 run robot_localization_suite mcl_baseline")
    else:
        assert usage.startswith(f"usage: {executable}") and "ros2" not in usage
