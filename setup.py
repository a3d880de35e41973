"""robot_localization_suite: five published localization methods and a simulator, side by side."""

import os

from setuptools import find_packages, setup

package_name = "robot_localization_suite"


def data_dirs(root: str) -> list[tuple[str, list[str]]]:
    """One data_files entry per folder under ``root``, so the share/ tree mirrors the source."""
    entries = []
    for folder, _dirs, files in os.walk(root):
        if files:
            entries.append((f"share/{package_name}/{folder}", [os.path.join(folder, f) for f in sorted(files)]))
    return entries


setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{package_name}"]),
        (f"share/{package_name}", ["package.xml"]),
        *data_dirs("config"),
        *data_dirs("bags"),
    ],
    python_requires=">=3.10",
    install_requires=[
        "numpy==2.2.6",
        "opencv-python-headless==4.12.0.88",
        "rosbags==0.11.9",
        "mcap==1.6.0",
        # Damaged bags: zstd chunks cut short are decoded block by block (ros/bag_recovery.py).
        "zstandard==0.25.0",
        # The hot loops (ray casting, interval contraction) are compiled.
        "numba==0.62.1",
        # Nearest-neighbour queries and sparse indexes (IR), Gaussian filters.
        "scipy==1.16.3",
        "PyYAML==6.0.3",
        # Benchmark plots and progress bars on long precomputations.
        "matplotlib==3.10.7",
        "tqdm==4.67.1",
        # Real photographs for the simulated camera's wall textures (skimage.data).
        "scikit-image==0.25.2",
        "psutil==7.2.2",
    ],
    extras_require={
        # A robot with ROS 2 Jazzy installed keeps its own rclpy; elsewhere these wheels provide it.
        "ros": [
            "ros-jazzy-rclpy==7.1.6",
            "ros-jazzy-common-interfaces==5.3.6",
            "ros-jazzy-rmw-fastrtps-cpp==8.4.3",
        ],
        # What `make` needs to build interfaces/ (tf2_msgs, nav2_msgs: no wheels on PyPI) with colcon.
        "interfaces": [
            "ros-jazzy-ament-cmake==2.5.4",
            "ros-jazzy-ament-package==0.16.4",
            "ros-jazzy-ament-cmake-include-directories==2.5.4",
            "ros-jazzy-ament-cmake-ros==0.12.0",
            "ros-jazzy-ament-cmake-gmock==2.5.4",
            "ros-jazzy-ament-cmake-gtest==2.5.4",
            "ros-jazzy-ament-cmake-pytest==2.5.4",
            "ros-jazzy-gmock-vendor==1.14.9000",
            "ros-jazzy-gtest-vendor==1.14.9000",
            "ros-jazzy-domain-coordinator==0.12.0",
            "ros-jazzy-python-cmake-module==0.11.1",
            "ros-jazzy-rosidl-core-generators==0.2.0",
            "colcon-core==0.21.3",
            "colcon-ros==0.5.0",
            "colcon-cmake==0.2.30",
        ],
        # rls_demo --foxglove: the run served live over the Foxglove WebSocket protocol (ros/foxglove_live.py).
        "viz": ["foxglove-sdk==0.30.3"],
        # rls_bench on a Dask cluster (tools/bench/executor.py): a LocalCluster here, or --scheduler;
        # diagnostics brings bokeh, without which the scheduler serves no dashboard.
        "scale": ["dask[distributed,diagnostics]==2026.8.0", "distributed==2026.8.0"],
        # Optional: rls_bench --export-tum also reports evo's APE RMSE (tools/bench/trajectories.py).
        "evo": ["evo==1.38.1"],
        # Only for tools/ial_benchmark.py --codac: the measured comparison behind core/ial.py's choice of numba.
        "compare": ["codac==2.1.2"],
        "test": [
            "pytest==9.2.0",
            "hypothesis==6.170.15",
            "ruff==0.17.6",
            "mypy==2.4.1",
            "types-PyYAML==6.0.12.20261122",
            "colcon-core==0.21.3",
            "colcon-ros==0.5.0",
            "colcon-python-setup-py==0.2.9",
            # The README's `colcon build --packages-select ...` and `source install/setup.bash`.
            "colcon-package-selection==0.2.10",
            "colcon-bash==0.5.0",
            # The WebSocket client of test_foxglove_live.py.
            "websockets==17.4",
        ],
    },
    zip_safe=False,
    maintainer="robot_localization_suite developers",
    maintainer_email="rls@example.org",
    description="Five published mobile-robot localization methods and a simulator, measured by one benchmark.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "scan_sim = robot_localization_suite.nodes.scan_sim:main",
            "mcl_baseline = robot_localization_suite.nodes.mcl_baseline:main",
            "pil_localizer = robot_localization_suite.nodes.pil_localizer:main",
            "ir_initializer = robot_localization_suite.nodes.ir_initializer:main",
            "ial_localizer = robot_localization_suite.nodes.ial_localizer:main",
            "ima_topo_localizer = robot_localization_suite.nodes.ima_topo_localizer:main",
            "hybrid_localizer = robot_localization_suite.nodes.hybrid_localizer:main",
            "rls_run = robot_localization_suite.launch.runner:main",
            "rls_demo = robot_localization_suite.launch.demo:main",
            "rls_bench = robot_localization_suite.tools.bench:main",
            "rls_soak = robot_localization_suite.tools.soak:main",
            "rls_footprint = robot_localization_suite.tools.footprint:main",
            "rls_bag_repair = robot_localization_suite.tools.bag_repair:main",
            "carmen_to_bag = robot_localization_suite.tools.carmen_to_bag:main",
            "build_topomap = robot_localization_suite.tools.build_topomap:main",
            "raycast_benchmark = robot_localization_suite.tools.raycast_benchmark:main",
        ],
    },
)
