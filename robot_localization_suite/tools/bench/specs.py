"""What is benchmarked: a :class:`LocalizerSpec` per localizer.

A spec names a localizer and holds a factory that builds a fresh core localizer; it is
the injection point for localizers from elsewhere (the tests' echo double).
:func:`registry_spec` makes the spec of a packaged localizer from its registry plugin.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ... import registry
from ...core.errors import SettingsError
from ...core.scan import LaserMount
from ...core.settings import parameters, read_params_file, unknown_params

__all__ = ["LocalizerSpec", "bench_params_file", "registry_spec"]


@dataclass(frozen=True)
class LocalizerSpec:
    """A localizer as the benchmark sees it.

    Attributes:
        name: column name in the tables.
        factory: builds a fresh core localizer (must be picklable for child processes,
            e.g. a module-level function or ``functools.partial`` of one).
        uses_camera: fed ``/camera/image_raw`` instead of ``/scan``.
        camera_cue: fed ``/camera/image_raw`` besides ``/scan`` (the hybrid with a ``camera_topomap``).
        mount: laser pose in the base frame (the adapter's mounting offset): the parameters', or the bag's
            ``/tf_static`` (:meth:`for_bag`, as a node reads it).
        base_frame: the localizer's ``base_frame_id`` (where the bag's ``/tf_static`` is asked for the mount).
        mount_from_bag: :attr:`mount` is the bag's ``/tf_static``, not the parameters' (reported).
        odom_frame: the localizer's ``odom_frame_id``.
        odometry_from_tf: ``odom_source: tf``: the replay reads odometry from ``/tf`` (``odom_frame ->
            base_frame``), as also for a bag without ``/odom``.
        skip: bag-name glob -> reason, pairs ``--all`` leaves out.
        skip_global: the same, in global mode and global fixes only.
        params: the params file the settings were read from, if not the packaged one (reported).
        per_bag: bag-name glob -> the spec to use for those bags instead (other params).
        sweep: ``name.param`` -> value of a ``--sweep`` point this spec runs (reported as columns).
        source: how a packaged localizer's settings were read (None for others): lets :meth:`for_bag` read them
            again with the odometry noise a bag declares.
        odometry_noise: parameter -> value this spec took from the bag's declared odometry noise (reported).
    """

    name: str
    factory: Callable[[], Any]
    uses_camera: bool = False
    camera_cue: bool = False
    mount: LaserMount = field(default_factory=LaserMount)
    base_frame: str = "base_footprint"
    mount_from_bag: bool = False
    odom_frame: str = "odom"
    odometry_from_tf: bool = False
    skip: Mapping[str, str] = field(default_factory=dict)
    skip_global: Mapping[str, str] = field(default_factory=dict)
    params: str | None = None
    per_bag: Mapping[str, LocalizerSpec] = field(default_factory=dict)
    sweep: Mapping[str, Any] = field(default_factory=dict)
    source: SettingsSource | None = None
    odometry_noise: Mapping[str, float] = field(default_factory=dict)

    def skip_reason(self, bag_name: str, mode: str = "global") -> str | None:
        """Why ``--all`` leaves this bag out in ``mode`` (global, tracking, global_fixes), or None."""
        skips = [self.skip] + ([self.skip_global] if mode in ("global", "global_fixes") else [])
        for table in skips:
            for pattern, reason in table.items():
                if fnmatch.fnmatch(bag_name, pattern):
                    return str(reason) + (f" ({mode} mode)" if table is self.skip_global else "")
        return None

    def for_bag(self, bag_name: str, odometry_noise: Mapping[str, float] | None = None,
                laser_mounts: Mapping[str, LaserMount] | None = None) -> LocalizerSpec:
        """The spec to run on ``bag_name``: the first ``per_bag`` glob that matches, else this one; with the
        bag's declared ``odometry_noise`` (``alpha1``..``alpha4``) as the motion noise of a localizer that has
        one, unless ``--set`` or ``--odometry-noise params`` said otherwise (docs/benchmark.md); and with the
        laser mount the bag's ``/tf_static`` gives under its ``base_frame`` (``laser_mounts``: frame -> mount),
        as a node takes it before its ``laser_x/y/yaw``."""
        chosen = next((spec for pattern, spec in self.per_bag.items() if fnmatch.fnmatch(bag_name, pattern)), self)
        source = chosen.source
        taken = {} if not odometry_noise or source is None or not source.declared_noise else {
            param: float(odometry_noise[name])
            for name, param in registry.plugin(source.name).odometry_noise_params.items()
            if name in odometry_noise and param not in source.overrides}
        if taken:
            assert source is not None
            rebuilt = _spec(dataclasses.replace(source, overrides={**taken, **source.overrides}))
            chosen = dataclasses.replace(rebuilt, name=chosen.name, skip=chosen.skip, skip_global=chosen.skip_global,
                                         params=chosen.params, sweep=chosen.sweep, odometry_noise=taken)
        mount = (laser_mounts or {}).get(chosen.base_frame)
        if mount is None or chosen.uses_camera or mount == chosen.mount:
            return chosen
        return dataclasses.replace(chosen, mount=mount, mount_from_bag=True)


@dataclass(frozen=True)
class SettingsSource:
    """What a packaged localizer's settings are read from: ``overrides`` on top of ``params_file``, which is
    read on top of the packaged file when ``layered`` (a bag's file), else instead of it (None: the packaged
    one). ``declared_noise``: a bag's declared odometry noise may set the motion noise."""

    name: str
    overrides: Mapping[str, Any]
    params_file: Path | None = None
    layered: bool = False
    declared_noise: bool = True


def _spec(source: SettingsSource) -> LocalizerSpec:
    plugin = registry.plugin(source.name)
    path, values = source.params_file, dict(source.overrides)
    if source.layered and path is not None:  # a bag's file on top of the packaged one, as two --params-file
        values, path = {**read_params_file(path, source.name), **values}, None
    node_settings, settings = plugin.load_settings(values, params_file=path)
    return LocalizerSpec(
        name=source.name,
        factory=functools.partial(_plugin_factory, source.name, settings),
        uses_camera=plugin.uses_camera,
        camera_cue=plugin.reads_camera_cue(settings),
        mount=node_settings.mount,
        base_frame=node_settings.base_frame_id,
        odom_frame=node_settings.odom_frame_id,
        odometry_from_tf=node_settings.odom_source == "tf",
        skip=dict(plugin.bench_skip),
        skip_global=dict(plugin.bench_skip_global),
        source=source,
    )


def bench_params_file(plugin: registry.LocalizerPlugin, bag_name: str) -> str | None:
    """The plugin's params file for ``bag_name`` (its first ``bench_params`` glob that matches), or None."""
    return next((file for pattern, file in plugin.bench_params.items() if fnmatch.fnmatch(bag_name, pattern)), None)


def _plugin_factory(name: str, settings: Any) -> Any:
    return registry.plugin(name).create(settings)


def registry_spec(
    name: str, overrides: Mapping[str, Any] | None = None, params_file: Path | None = None, *,
    declared_noise: bool = True,
) -> LocalizerSpec:
    """The spec of a packaged localizer: its settings from ``config/<name>.yaml`` and ``overrides``.

    Bags matching the plugin's ``bench_params`` globs get a spec whose settings come from that
    params file read on top of the packaged one (as a second ``--params-file``; ``overrides`` still on
    top), reached with :meth:`LocalizerSpec.for_bag`.
    ``params_file`` (``rls_bench --params-file``, ``--profile``): this file for every bag instead.
    ``declared_noise`` False (``--odometry-noise params``): the motion noise stays the params file's on every bag.

    Raises:
        SettingsError: an override names no parameter of the localizer (a typo would silently do nothing).
    """
    plugin = registry.plugin(name)
    unknown = [key for key in unknown_params(plugin.settings, dict(overrides or {}))
               if key not in {p.name for p in parameters(registry.NodeSettings)}]
    if unknown:
        raise SettingsError(f"{name} has no parameter {', '.join(map(repr, unknown))} (see {name} --help)")

    def spec(file: str | Path | None, layered: bool = False) -> LocalizerSpec:
        path = registry.config_dir() / file if file is not None else None
        made = _spec(SettingsSource(name, dict(overrides or {}), path, layered, declared_noise))
        return dataclasses.replace(made, params=None if file is None else str(file))

    if params_file is not None:
        if not Path(params_file).is_file():
            raise SettingsError(f"{name}: params file {str(params_file)!r} not found")
        path = Path(params_file).resolve()
        shown = path.name if path.parent == registry.config_dir().resolve() else str(params_file)
        return dataclasses.replace(spec(path), params=shown)
    per_bag = {pattern: dataclasses.replace(spec(file, layered=True), params=file)
               for pattern, file in plugin.bench_params.items()}
    return dataclasses.replace(spec(None), per_bag=per_bag)
