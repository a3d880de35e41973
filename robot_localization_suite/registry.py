"""The localizers this package offers: one typed plugin record each, and nothing heavy to import.

A :class:`LocalizerPlugin` says what a localizer is: its name (also its executable and
default node name), its settings class (the single definition of its parameters), a
factory that builds the core localizer from settings, the sensor it reads and the bags
the benchmark leaves out. The shared node (``nodes/localizer_node.py``), the benchmark
and the demo all read :data:`PLUGINS`; nothing here imports rclpy, a node module or a
method's algorithm code (factories import it when called). Adding a localizer: README,
section "Adding a localizer".
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .core.errors import SettingsError
from .core.filter.odometry_gate import TIME_JUMP_RESET_S
from .core.hybrid.settings import HybridSettings
from .core.ial.settings import IALSettings
from .core.ima.settings import ImaTrackerSettings
from .core.ir.settings import IRSettings
from .core.mcl.settings import MclSettings
from .core.pil.settings import PilSettings
from .core.scan import MAX_MOUNT_OFFSET_M, LaserMount
from .core.settings import Settings, from_params, read_params_file, setting

__all__ = [
    "SensorKind",
    "NodeSettings",
    "ODOM_SOURCES",
    "LocalizerPlugin",
    "PLUGINS",
    "LOCALIZER_NAMES",
    "plugin",
    "config_dir",
    "resolve_config_path",
    "resolve_scenario_path",
]


class SensorKind(enum.Enum):
    """What a localizer reads besides odometry."""

    LASER = "laser"
    CAMERA = "camera"


_BIG = 1e6
ODOM_SOURCES = ("topic", "tf")


@dataclass(frozen=True)
class NodeSettings(Settings):
    """Parameters every localizer node has besides its method's own (nav2_amcl's names where nav2 has them).

    Every one can change at run time (``ros2 param set``) except the ``read_only`` ones; a change of
    the laser mount, like a change of a method parameter, rebuilds the method around its last pose.
    """

    map_yaml: str = setting("", "nav2 map_server YAML loaded at configure; empty: wait for the map topic", read_only=True)
    first_map_only: bool = setting(False, "use the first map received and ignore later ones (nav2)")
    laser_x: float = setting(0.0, "laser position in the base frame, x, when /tf_static has no base -> laser transform",
                             unit="m", low=-MAX_MOUNT_OFFSET_M, high=MAX_MOUNT_OFFSET_M)
    laser_y: float = setting(0.0, "laser position in the base frame, y (fallback as laser_x)", unit="m",
                             low=-MAX_MOUNT_OFFSET_M, high=MAX_MOUNT_OFFSET_M)
    laser_yaw: float = setting(0.0, "laser heading in the base frame (fallback as laser_x)", unit="rad",
                               low=-3.1416, high=3.1416)
    laser_upside_down: bool = setting(False, "the laser is mounted upside down, its beam angles turning clockwise "
                                      "seen from above (fallback as laser_x; /tf_static says so by a roll or pitch "
                                      "of pi)")
    tf_broadcast: bool = setting(True, "publish map -> odom on /tf (nav2)")
    global_frame_id: str = setting("map", "frame of the map, of the estimates and of accepted initial poses (nav2)")
    odom_frame_id: str = setting("odom", "odometry frame (nav2)")
    base_frame_id: str = setting("base_footprint", "robot base frame (nav2)")
    transform_tolerance: float = setting(
        1.0, "map -> odom is stamped this far after its scan (valid until then), and /tf input older than "
        "this behind its frame's newest is dropped (nav2)", unit="s", low=0.0, high=3600.0)
    odom_source: str = setting("topic", "odometry from the odom topic (nav_msgs/Odometry) or from /tf "
                               "(odom_frame_id -> base_frame_id, as nav2)", choices=ODOM_SOURCES, read_only=True)
    scan_timeout: float = setting(5.0, "once active, warn when no scan (image) or odometry has arrived for this long",
                                  unit="s", low=0.0, low_open=True, high=3600.0)
    set_initial_pose: bool = setting(False, "on activation, start around initial_pose.* (nav2)")
    initial_pose_x: float = setting(0.0, "initial pose x in global_frame_id (nav2)", unit="m", low=-_BIG, high=_BIG,
                                    ros_name="initial_pose.x")
    initial_pose_y: float = setting(0.0, "initial pose y in global_frame_id (nav2)", unit="m", low=-_BIG, high=_BIG,
                                    ros_name="initial_pose.y")
    initial_pose_yaw: float = setting(0.0, "initial pose heading in global_frame_id (nav2)", unit="rad",
                                      low=-7.0, high=7.0, ros_name="initial_pose.yaw")
    always_reset_initial_pose: bool = setting(
        False, "after a reset (cleanup, configure, activate) wait for a new initial pose (or initial_pose.*) instead "
        "of starting from the last known pose (nav2)")
    max_published_candidates: int = setting(2000, "cap on the poses in ~/candidates and ~/particle_cloud",
                                            low=0, high=1_000_000)
    max_future_s: float = setting(1.0, "an input stamped more than this ahead of the newest one is dropped and does not "
                                  "move the node's time", unit="s", low=0.0, high=3600.0)
    time_jump_reset_s: float = setting(TIME_JUMP_RESET_S, "an input stamped more than this before its stream's last "
                                       "one starts a new timeline (a bag looped, a simulator restarted)", unit="s",
                                       low=0.0, low_open=True, high=3600.0)

    def validate(self) -> None:
        """The three frames are names tf2 takes (``odom``, not ``/odom``), and three different frames."""
        frames = {"global_frame_id": self.global_frame_id, "odom_frame_id": self.odom_frame_id,
                  "base_frame_id": self.base_frame_id}
        for name, frame in frames.items():
            if not frame or frame.startswith("/") or any(c.isspace() for c in frame):
                raise SettingsError(f"parameter {name} must be a frame name as tf2 takes it (not empty, no spaces, "
                                    f"no leading '/'), got {frame!r}")
        stripped = list(frames.values())
        if len(set(stripped)) < 3:
            raise SettingsError(f"global_frame_id, odom_frame_id and base_frame_id must be three different frames, "
                                f"got {stripped[0]!r}, {stripped[1]!r}, {stripped[2]!r}")

    @property
    def mount(self) -> LaserMount:
        """The laser mount of the parameters (the fallback when /tf_static has none)."""
        return LaserMount(self.laser_x, self.laser_y, self.laser_yaw, self.laser_upside_down)

    @property
    def initial_pose(self) -> tuple[float, float, float]:
        return self.initial_pose_x, self.initial_pose_y, self.initial_pose_yaw


@dataclass(frozen=True)
class LocalizerPlugin:
    """One localizer as the nodes, the benchmark and the demo see it.

    Attributes:
        name: executable, default node name and benchmark column.
        description: one paragraph for ``--help``.
        settings: the method's settings class (its fields define its ROS parameters).
        factory: builds the core localizer (a ``Localizer`` or ``CameraLocalizer``) from settings;
            a module-level function that imports the method when called.
        sensor: laser scans or camera images.
        bench_skip: bag-name glob -> reason, pairs ``rls_bench --all`` leaves out.
        bench_skip_global: bag-name glob -> reason, pairs ``rls_bench --all`` leaves out in global mode
            and single-scan global fixes only (tracking mode runs them).
        bench_params: bag-name glob -> params file in ``config/``, read for those bags on top of
            ``config/<name>.yaml``, as a second ``--params-file`` (the first matching glob wins).
        outputs: extra output topics, for ``--help`` (``"~/boxes (visualization_msgs/MarkerArray)"``).
        camera_cue: a laser method that also reads camera images when its settings name a ``camera_topomap``.
        odometry_noise_params: declared name (``alpha1``..``alpha4`` of the odometry motion model) -> the
            parameter that takes it, where the benchmark gives the noise a bag declares for its odometry.
    """

    name: str
    description: str
    settings: type[Settings]
    factory: Callable[[Any], Any]
    sensor: SensorKind = SensorKind.LASER
    bench_skip: Mapping[str, str] = field(default_factory=dict)
    bench_skip_global: Mapping[str, str] = field(default_factory=dict)
    bench_params: Mapping[str, str] = field(default_factory=dict)
    outputs: tuple[str, ...] = ()
    camera_cue: bool = False
    odometry_noise_params: Mapping[str, str] = field(default_factory=dict)

    @property
    def uses_camera(self) -> bool:
        return self.sensor is SensorKind.CAMERA

    def reads_camera_cue(self, settings: Settings) -> bool:
        """Whether a laser method with these settings also reads camera images (its ``camera_topomap``)."""
        return self.camera_cue and bool(getattr(settings, "camera_topomap", ""))

    def create(self, settings: Settings | None = None) -> Any:
        """A fresh core localizer with these settings (default: the class defaults)."""
        return self.factory(settings if settings is not None else self.settings())

    def params_file(self) -> Path:
        """The packaged parameter file, ``config/<name>.yaml``."""
        return config_dir() / f"{self.name}.yaml"

    def load_settings(
        self, overrides: Mapping[str, Any] | None = None, params_file: str | Path | None = None
    ) -> tuple[NodeSettings, Settings]:
        """Node and method settings: defaults, then the params file (default: the packaged one), then overrides.

        Raises:
            SettingsError: a bad value or file, naming it.
        """
        path = Path(params_file) if params_file is not None else self.params_file()
        values = read_params_file(path, self.name) if params_file is not None or path.is_file() else {}
        values.update(overrides or {})
        return from_params(NodeSettings, values), from_params(self.settings, values)


def _create_mcl(settings: MclSettings) -> Any:
    from .core.mcl.localizer import MonteCarloLocalizer

    return MonteCarloLocalizer(settings)


def _create_pil(settings: PilSettings) -> Any:
    from .core.pil.localizer import PilLocalizer

    return PilLocalizer(settings)


def _create_ir(settings: IRSettings) -> Any:
    from .core.ir.localizer import IRLocalizer

    return IRLocalizer(settings)


def _create_ial(settings: IALSettings) -> Any:
    from .core.ial.localizer import IntervalLocalizer

    return IntervalLocalizer(settings)


def _create_hybrid(settings: HybridSettings) -> Any:
    from .core.hybrid.localizer import HybridLocalizer

    if not settings.camera_topomap:
        return HybridLocalizer(settings)
    from .core.ima.topomap import load_topomap  # OpenCV: only a hybrid with a camera loads it

    return HybridLocalizer(settings, topomap=load_topomap(resolve_config_path(settings.camera_topomap, "topomap")))


def _create_ima(settings: ImaTrackerSettings) -> Any:
    from .core.ima.topomap import load_topomap
    from .core.ima.tracking import ImaTopoLocalizer

    return ImaTopoLocalizer(load_topomap(resolve_config_path(settings.topomap, "topomap")), settings)


# SLAM maps of the real logs are mostly unknown space: from the whole map IAL's box list
# saturates and never fixes. Tracking works there with the SLAM parameters (docs/ial.md).
_IAL_REAL_LOG = "real 180-degree log with a mostly unknown SLAM map: global boxes saturate, no fix (docs/ial.md)"
_IAL_SLAM_PARAMS = "ial_localizer_slam.yaml"
# The MCL filter's motion noise, which the benchmark sets to the noise a bag declares for its odometry.
_ALPHAS = {f"alpha{i}": f"tracking_alpha{i}" for i in range(1, 5)}

PLUGINS: dict[str, LocalizerPlugin] = {
    p.name: p
    for p in (
        LocalizerPlugin(
            "mcl_baseline",
            "Adaptive Monte Carlo localization as nav2_amcl does it (odometry motion model, likelihood-field or "
            "beam laser model, KLD-sampling, Augmented-MCL recovery, estimate from the heaviest particle cluster), "
            "with nav2_amcl's parameter names.",
            MclSettings,
            _create_mcl,
            odometry_noise_params=_ALPHAS,
        ),
        LocalizerPlugin(
            "pil_localizer",
            "Pseudo Image Localization (Lambert et al. 2020): learns range pseudo-images of every tile of the map, "
            "then finds (x, y) from orientation-free level functions and theta by profile correlation, from each "
            "scan alone (global localization and kidnapping recovery, no odometry needed).",
            PilSettings,
            _create_pil,
        ),
        LocalizerPlugin(
            "ir_initializer",
            "Global localization by information retrieval (Aycard & Brouard): expected scans precomputed over the "
            "map, patterns and a two-level hit -> pattern -> position index, idf-ranked poses, then a small "
            "particle filter with an end-point sensor model that reinitialises itself when lost.",
            IRSettings,
            _create_ir,
        ),
        LocalizerPlugin(
            "ial_localizer",
            "Guaranteed localization by interval analysis (Guyonneau et al., Advanced Robotics 2014): boxes of "
            "poses predicted with bounded odometry, contracted by every beam against the grid map with a relaxed "
            "intersection that tolerates max_outliers readings, bisected down to min_box_width; under the stated "
            "bounds the true pose is inside the published boxes, and an empty list (kidnapping) restarts over "
            "the whole map.",
            IALSettings,
            _create_ial,
            bench_skip_global={"intel*": _IAL_REAL_LOG, "fr101*": _IAL_REAL_LOG, "orebro*": _IAL_REAL_LOG},
            bench_params={"intel*": _IAL_SLAM_PARAMS, "fr101*": _IAL_SLAM_PARAMS, "orebro*": _IAL_SLAM_PARAMS},
            outputs=("~/boxes (visualization_msgs/MarkerArray: each box, its heading range and the hull)",),
        ),
        LocalizerPlugin(
            "hybrid_localizer",
            "The MCL filter of mcl_baseline tracks; PIL's global fix (in the update) and IR's (in a worker thread, "
            "never in the update) propose ranked poses from each scan: the filter starts around the best ones, "
            "gets particles injected around one that explains the scan clearly better for consecutive updates "
            "(a kidnapping), and is AMBIGUOUS while a candidate elsewhere explains the scan as well. With a "
            "camera_topomap, camera images (IMA place recognition, thesis 003) tell look-alike places apart. "
            "Parameters of the methods are nested under mcl., pil., ir., ial. and ima.",
            HybridSettings,
            _create_hybrid,
            bench_params={"office_twins_camera*": "hybrid_localizer_office_twins.yaml"},
            camera_cue=True,
            odometry_noise_params={name: f"mcl.{param}" for name, param in _ALPHAS.items()},
        ),
        LocalizerPlugin(
            "ima_topo_localizer",
            "Camera topological localization (thesis 003): IMA slot matching with NCC against the panoramas of a "
            "topological map (digital zoom, heading from the panorama), and multi-hypothesis tracking of the "
            "places with odometry (Code 3.1).",
            ImaTrackerSettings,
            _create_ima,
            sensor=SensorKind.CAMERA,
            bench_params={"office_twins_camera*": "ima_topo_localizer_office_twins.yaml"},
            outputs=("~/place (std_msgs/String: the name of the estimated place)",),
        ),
    )
}
LOCALIZER_NAMES = tuple(PLUGINS)


def plugin(name: str) -> LocalizerPlugin:
    """The plugin of a localizer.

    Raises:
        KeyError: naming the unknown localizer and the known ones.
    """
    try:
        return PLUGINS[name]
    except KeyError:
        raise KeyError(f"unknown localizer {name!r}; known: {', '.join(PLUGINS)}") from None


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


def resolve_config_path(path: str, what: str) -> Path:
    """A file as given (absolute, or relative to the working directory), else relative to ``config/``.

    Raises:
        MapError: an empty path, naming the parameter.
    """
    from .core.errors import MapError

    if not path:
        raise MapError(f"parameter {what!r} is empty")
    candidate = Path(path).expanduser()
    if candidate.is_file() or candidate.is_absolute():
        return candidate
    packaged = config_dir() / candidate
    return packaged if packaged.is_file() else candidate


def resolve_scenario_path(name: str) -> Path | None:
    """A scenario path as given, else ``config/scenarios/<name>[.yaml]`` of the package; None when empty.

    Raises:
        ScenarioError: naming a scenario that is neither.
    """
    from .core.errors import ScenarioError

    if not name:
        return None
    path = Path(name)
    if path.is_file():
        return path
    for candidate in (config_dir() / "scenarios" / name, config_dir() / "scenarios" / f"{name}.yaml"):
        if candidate.is_file():
            return candidate
    raise ScenarioError(f"scenario {name!r} is neither a file nor a name in {str(config_dir() / 'scenarios')!r}")
