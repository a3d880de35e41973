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
        mount: laser pose in the base frame (the adapter's mounting offset).
        skip: bag-name glob -> reason, pairs ``--all`` leaves out.
        skip_global: the same, in global mode and global fixes only.
        params: the params file the settings were read from, if not the packaged one (reported).
        per_bag: bag-name glob -> the spec to use for those bags instead (other params).
        sweep: ``name.param`` -> value of a ``--sweep`` point this spec runs (reported as columns).
    """

    name: str
    factory: Callable[[], Any]
    uses_camera: bool = False
    camera_cue: bool = False
    mount: LaserMount = field(default_factory=LaserMount)
    skip: Mapping[str, str] = field(default_factory=dict)
    skip_global: Mapping[str, str] = field(default_factory=dict)
    params: str | None = None
    per_bag: Mapping[str, LocalizerSpec] = field(default_factory=dict)
    sweep: Mapping[str, Any] = field(default_factory=dict)

    def skip_reason(self, bag_name: str, mode: str = "global") -> str | None:
        """Why ``--all`` leaves this bag out in ``mode`` (global, tracking, global_fixes), or None."""
        skips = [self.skip] + ([self.skip_global] if mode in ("global", "global_fixes") else [])
        for table in skips:
            for pattern, reason in table.items():
                if fnmatch.fnmatch(bag_name, pattern):
                    return str(reason) + (f" ({mode} mode)" if table is self.skip_global else "")
        return None

    def for_bag(self, bag_name: str) -> LocalizerSpec:
        """The spec to run on ``bag_name``: the first ``per_bag`` glob that matches, else this one."""
        for pattern, spec in self.per_bag.items():
            if fnmatch.fnmatch(bag_name, pattern):
                return spec
        return self


def bench_params_file(plugin: registry.LocalizerPlugin, bag_name: str) -> str | None:
    """The plugin's params file for ``bag_name`` (its first ``bench_params`` glob that matches), or None."""
    return next((file for pattern, file in plugin.bench_params.items() if fnmatch.fnmatch(bag_name, pattern)), None)


def _plugin_factory(name: str, settings: Any) -> Any:
    return registry.plugin(name).create(settings)


def registry_spec(
    name: str, overrides: Mapping[str, Any] | None = None, params_file: Path | None = None
) -> LocalizerSpec:
    """The spec of a packaged localizer: its settings from ``config/<name>.yaml`` and ``overrides``.

    Bags matching the plugin's ``bench_params`` globs get a spec whose settings come from that
    params file read on top of the packaged one (as a second ``--params-file``; ``overrides`` still on
    top), reached with :meth:`LocalizerSpec.for_bag`.
    ``params_file`` (``rls_bench --params-file``, ``--profile``): this file for every bag instead.

    Raises:
        SettingsError: an override names no parameter of the localizer (a typo would silently do nothing).
    """
    plugin = registry.plugin(name)
    unknown = [key for key in unknown_params(plugin.settings, dict(overrides or {}))
               if key not in {p.name for p in parameters(registry.NodeSettings)}]
    if unknown:
        raise SettingsError(f"{name} has no parameter {', '.join(map(repr, unknown))} (see {name} --help)")

    def spec(params_file: str | Path | None, layered: bool = False) -> LocalizerSpec:
        path = registry.config_dir() / params_file if params_file is not None else None
        values = dict(overrides or {})
        if layered and path is not None:  # a bag's file on top of the packaged one, as two --params-file
            values = {**read_params_file(path, name), **values}
            path = None
        node_settings, settings = plugin.load_settings(values, params_file=path)
        return LocalizerSpec(
            name=name,
            factory=functools.partial(_plugin_factory, name, settings),
            uses_camera=plugin.uses_camera,
            camera_cue=plugin.reads_camera_cue(settings),
            mount=node_settings.mount,
            skip=dict(plugin.bench_skip),
            skip_global=dict(plugin.bench_skip_global),
            params=None if params_file is None else str(params_file),
        )

    if params_file is not None:
        if not Path(params_file).is_file():
            raise SettingsError(f"{name}: params file {str(params_file)!r} not found")
        path = Path(params_file).resolve()
        shown = path.name if path.parent == registry.config_dir().resolve() else str(params_file)
        return dataclasses.replace(spec(path), params=shown)
    per_bag = {pattern: dataclasses.replace(spec(file, layered=True), params=file)
               for pattern, file in plugin.bench_params.items()}
    return dataclasses.replace(spec(None), per_bag=per_bag)
