"""The ``rls_bench`` command line: arguments to specs, bags and runs.

    rls_bench BAG... --localizers NAMES --out DIR [--map MAP_YAML] [--mode global|tracking]
              [--set name.param=value ...] [--params-file NAME=PATH ...] [--profile paper]
              [--max-seconds S] [--no-plots] [--sweep name.param=v1,v2,...] [--export-tum DIR]
              [--workers N | --scheduler tcp://HOST:PORT [--ship-bags]]
    rls_bench --global-fixes [--every N] BAG... [--localizers NAMES] --out DIR
    rls_bench --all [--with-global-fixes] [--out results]
    rls_bench --cv SPLIT... [--localizers NAMES] [--mode M] [--with-tracking] [--with-global-fixes] --out DIR

Options: ``rls_bench --help``; what a run does: ``docs/benchmark.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ... import registry
from ...core.errors import BagError, LocalizationSuiteError
from ...core.settings import yaml_value
from .cv import cv_modes, find_split_indexes, run_cv
from .cv_tables import append_cv_section, cv_tables
from .executor import DaskExecutor, Executor, SequentialExecutor, dask_available
from .reference import BENCH_TOPICS
from .run import run_benchmark, run_global_fixes
from .specs import registry_spec
from .sweeps import parse_sweeps, sweep_specs
from .tables import append_section, comparison_tables, summary_table

__all__ = ["main", "discover_bags", "default_bags_dir"]


def _parse_overrides(items: Sequence[str]) -> dict[str, dict[str, Any]]:
    overrides: dict[str, dict[str, Any]] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        name, dot, param = key.partition(".")
        if not sep or not dot or not name or not param:
            raise ValueError(f"--set expects name.param=value, got {item!r}")
        overrides.setdefault(name, {})[param] = yaml_value(raw, f"--set {item}")
    return overrides


def _at_least_one(text: str) -> int:
    """An argparse type: an integer of at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _positive_seconds(text: str) -> float:
    """An argparse type: a finite number of seconds above 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not (value > 0.0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number of seconds above 0, got {text!r}")
    return value


def _name_and_path(item: str, option: str, form: str) -> tuple[str, Path]:
    """``NAME=PATH`` of ``option``, both parts non-empty."""
    name, sep, path = item.partition("=")
    if not sep or not name or not path:
        raise ValueError(f"{option} expects {form}, got {item!r}")
    return name, Path(path)


def _parse_params_files(items: Sequence[str]) -> dict[str, Path]:
    return dict(_name_and_path(item, "--params-file", "NAME=PATH") for item in items)


def _read_comparison(value: str) -> tuple[str, dict[str, Any]]:
    """``LABEL=DIR`` -> the label and DIR/summary.json (read before the runs, so a wrong path fails at once)."""
    label, directory = _name_and_path(value, "--compare-with", "LABEL=DIR")
    path = directory / "summary.json"
    try:
        return label, json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"--compare-with {value}: cannot read {path}: {exc}") from exc


def _profile_file(name: str, profile: str) -> Path:
    path = registry.config_dir() / f"{name}_{profile}.yaml"
    if not path.is_file():
        raise ValueError(f"--profile {profile}: {name} has no {path.name} in {registry.config_dir()}")
    return path


def _parse_skips(items: Sequence[str]) -> dict[str, dict[str, str]]:
    skips: dict[str, dict[str, str]] = {}
    for item in items:
        name, sep, pattern = item.partition(":")
        if not sep or not name or not pattern:
            raise ValueError(f"--skip expects NAME:BAG_GLOB, got {item!r}")
        skips.setdefault(name, {})[pattern] = "skipped on the command line"
    return skips


def _parse_remaps(items: Sequence[str]) -> dict[str, str]:
    """``FROM:=TO`` items (``ros2 bag play --remap``'s form; a missing leading slash is added) as bag topic -> name."""
    remap: dict[str, str] = {}
    for item in items:
        source, sep, name = item.partition(":=")
        source, name = (("/" + t.strip().lstrip("/")) if t.strip() else "" for t in (source, name))
        if not sep or not source or not name:
            raise ValueError(f"--remap expects FROM:=TO (e.g. /base_scan:=/scan), got {item!r}")
        if name not in BENCH_TOPICS:
            raise ValueError(f"--remap {item}: the benchmark reads no {name}; it reads {', '.join(BENCH_TOPICS)}")
        if source in remap and remap[source] != name:
            raise ValueError(f"--remap gives {source} two names: {remap[source]} and {name}")
        remap[source] = name
    return remap


def _split_names(values: Sequence[str] | None) -> list[str]:
    return [n for v in values or () for n in v.split(",") if n]


def default_bags_dir() -> Path:
    return registry.config_dir().parent / "bags"


def discover_bags(bags_dir: Path) -> list[Path]:
    """Bag directories (with ``metadata.yaml``) under ``bags_dir``, by name."""
    if not bags_dir.is_dir():
        return []
    return sorted(p for p in bags_dir.iterdir() if (p / "metadata.yaml").is_file())



def _executor(args: argparse.Namespace) -> Executor:
    """Where the replays run: Dask (default when installed, ``--workers``, ``--scheduler``) or one after another."""
    dask_asked = args.scheduler is not None or args.ship_bags or (args.workers or 0) > 0
    if args.workers is not None and args.workers < 0:
        raise ValueError(f"--workers must be 0 or more, got {args.workers}")
    if args.scheduler is not None and args.workers is not None:
        raise ValueError("--workers starts a local cluster; an existing one (--scheduler) has its own workers")
    if args.in_process or args.workers == 0:
        if dask_asked:
            raise ValueError("--workers N, --scheduler and --ship-bags run on Dask: not with --in-process or --workers 0")
        return SequentialExecutor(isolate=not args.in_process, max_seconds=args.max_seconds,
                                  child_progress=args.verbose)
    if not dask_available():
        if dask_asked:
            raise ValueError("Dask is not installed: pip install -e '.[scale]' (or run without --workers, "
                             "--scheduler, --ship-bags)")
        print("rls_bench: dask.distributed is not installed (the 'scale' extra): one child process after another",
              file=sys.stderr)
        return SequentialExecutor(isolate=True, max_seconds=args.max_seconds, child_progress=args.verbose)
    return DaskExecutor(scheduler=args.scheduler, workers=args.workers, ship_bags=args.ship_bags,
                        max_seconds=args.max_seconds, child_progress=args.verbose)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rls_bench",
        description="Replay bags through localizers in-process and measure them against /ground_truth.",
    )
    parser.add_argument("bags", nargs="*", type=Path, help="rosbag2 bag directories")
    parser.add_argument("--localizers", nargs="+", help="names (comma or space separated); default: all available")
    parser.add_argument("--out", type=Path, default=Path("results"), help="output directory (default: results)")
    parser.add_argument("--map", type=Path, default=None, help="map YAML for every bag (default: the bag's /map, "
                        "else config/maps/<bag or prefix>.yaml)")
    parser.add_argument("--remap", action="append", default=[], metavar="FROM:=TO",
                        help="read the bags' topic FROM as TO (as ros2 bag play --remap), e.g. /base_scan:=/scan; "
                        f"TO is one of {', '.join(BENCH_TOPICS)}")
    parser.add_argument("--mode", choices=("global", "tracking"), default="global",
                        help="global (default): no prior; tracking: the first ground-truth pose on initialpose")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="NAME.PARAM=VALUE",
                        help="override a localizer parameter (YAML value)")
    parser.add_argument("--odometry-noise", choices=("declared", "params"), default="declared",
                        help="declared (default): a bag that declares the noise of its /odom (carmen_to_bag writes it "
                        "into the metadata) gives it to every localizer with an odometry motion model (mcl_baseline's "
                        "tracking_alpha1..4, the hybrid's mcl.tracking_alpha1..4) unless --set names them; params: "
                        "the params files' values")
    parser.add_argument("--params-file", dest="params_files", action="append", default=[], metavar="NAME=PATH",
                        help="read NAME's parameters from PATH for every bag instead of config/NAME.yaml (and of its "
                        "per-bag files); --set still applies on top")
    parser.add_argument("--profile", choices=("paper",), default=None,
                        help="paper: every localizer reads config/<name>_paper.yaml (the method as its paper "
                        "describes it; docs/<method>.md), unless --params-file names another file")
    parser.add_argument("--compare-with", default=None, metavar="LABEL=DIR",
                        help="after the replays, also write OUT/comparison.md: a table per localizer, a row per bag "
                        "for this run (labelled by --profile, else 'this run') and for the run in DIR (its "
                        "summary.json, labelled LABEL), e.g. --profile paper --compare-with ours=results")
    parser.add_argument("--all", action="store_true", help="every available localizer over every bag in bags/")
    parser.add_argument("--bags-dir", type=Path, default=None, help="where --all looks for bags (default: bags/)")
    parser.add_argument("--skip", action="append", default=[], metavar="NAME:BAG_GLOB",
                        help="with --all, leave this localizer out on matching bags")
    parser.add_argument("--global-fixes", action="store_true", help="single-scan global fixes instead of replays")
    parser.add_argument("--every", type=_at_least_one, default=10, help="with --global-fixes: use every N-th scan (default: 10)")
    parser.add_argument("--with-global-fixes", action="store_true",
                        help="after the replays, also run --global-fixes into OUT/global_fixes and append its "
                        "table to OUT/summary.md")
    parser.add_argument("--with-tracking", action="store_true",
                        help="after global-mode replays, also replay in tracking mode into OUT/tracking and append "
                        "its table to OUT/summary.md")
    parser.add_argument("--cv", nargs="+", type=Path, default=None, metavar="SPLIT",
                        help="cross-validation: every laser localizer over every block of these splits (an index "
                        "<name>_cv.yaml of carmen_to_bag --blocks, or a directory of them), on the block's honest map "
                        "and on the whole-log map, in the modes the other options ask for; into OUT/cv (appended to "
                        "OUT/summary.md when bags run too)")
    parser.add_argument("--max-seconds", type=_positive_seconds, default=None, help="stop each run after this wall time [s] (default: no limit)")
    parser.add_argument("--in-process", action="store_true", help="run in this process, one after another, not one "
                        "child per run (no Dask)")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="the runs (replays, global fixes, --cv) are tasks of a local Dask cluster of N "
                        "process workers, one thread each "
                        "(default: as many as CPUs, when dask[distributed] is installed: the 'scale' extra); each "
                        "task still runs in its own child process. 0: no Dask, one child process after another")
    parser.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                        help="submit the runs to the existing Dask cluster of this scheduler. Its workers need "
                        "this package installed, must not be daemons (DASK_DISTRIBUTED__WORKER__DAEMON=False) and "
                        "read each bag at the path given here (a shared file system) unless --ship-bags; maps and "
                        "settings go with each task")
    parser.add_argument("--ship-bags", action="store_true",
                        help="with Dask: send each bag directory from here to the workers (unpacked once per worker "
                        "host in its temp directory) instead of having them read it at the same path")
    parser.add_argument("--sweep", action="append", default=[], metavar="NAME.PARAM=V1,V2,...",
                        help="run the grid of these parameter values (YAML values, repeat for more parameters) on "
                        "every bag; OUT/sweep.md and sweep.json hold a row per point with the parameters as columns, "
                        "OUT/plots/sweep_NAME.PARAM.png the metrics against each. Without --localizers only the "
                        "swept localizers run")
    parser.add_argument("--export-tum", type=Path, default=None, metavar="DIR",
                        help="write each replay's estimates and the ground truth in TUM format into "
                        "DIR/<mode>/<bag>/ (for evo_ape, evo_rpe); with evo installed also report its APE RMSE")
    parser.add_argument("--record", type=Path, default=None, metavar="DIR",
                        help="also record each replay as one MCAP that Foxglove opens (the bag's messages, the "
                        "localizer's outputs as its node publishes them, each output's error): "
                        "DIR/<bag>_<localizer>_<mode>/ (docs/demo.md; config/foxglove_demo_layout.json shows it)")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log the localizers' warnings and show their precomputation progress bars")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.ERROR, format="%(name)s: %(message)s")
    executor: Executor | None = None
    replays = None  # the replays in --mode, which --compare-with sets beside the other run's
    try:
        if args.out.exists() and not args.out.is_dir():
            raise ValueError(f"--out {str(args.out)!r} is a file, not a directory")
        overrides = _parse_overrides(args.overrides)
        params_files = _parse_params_files(args.params_files)
        skips = _parse_skips(args.skip)
        remap = _parse_remaps(args.remap)
        compare = _read_comparison(args.compare_with) if args.compare_with else None
        if compare is not None and args.global_fixes:
            raise ValueError("--compare-with compares replays, not --global-fixes")
        bags = list(args.bags)
        if args.all:
            bags += [b for b in discover_bags(args.bags_dir or default_bags_dir()) if b not in bags]
        cv_indexes = find_split_indexes(args.cv) if args.cv else []
        if not bags and not cv_indexes:
            raise ValueError("no bag given (pass BAG..., --all or --cv SPLIT)")
        if cv_indexes and args.map is not None:
            raise ValueError("--map does not apply to --cv: each block runs on its own map and the whole-log map")
        sweeps = parse_sweeps(args.sweep)
        available = list(registry.PLUGINS)
        names = _split_names(args.localizers) or [n for n in available if n in sweeps] or available
        unknown = [n for n in names if n not in available]
        misnamed = sorted(set(overrides) - set(available))
        if misnamed:  # a typo would silently leave the value out
            raise ValueError(f"--set names no localizer: {', '.join(misnamed)}; available: {', '.join(available)}")
        if unknown:
            raise ValueError(f"localizer(s) {', '.join(unknown)} not available; available: {', '.join(available) or 'none'}")
        if not names:
            raise ValueError("no localizer is available in this checkout")
        if set(params_files) - set(names):
            raise ValueError(f"--params-file names a localizer not run: {', '.join(sorted(set(params_files) - set(names)))}")
        if set(sweeps) - set(names):
            raise ValueError(f"--sweep names a localizer not run: {', '.join(sorted(set(sweeps) - set(names)))}")
        specs = []
        for name in names:
            params_file = params_files.get(name)
            if params_file is None and args.profile:
                params_file = _profile_file(name, args.profile)
            # Every grid point's settings are built (and checked) here, before anything is submitted.
            declared = args.odometry_noise == "declared"
            own = (sweep_specs(name, sweeps[name], overrides.get(name), params_file, declared_noise=declared)
                   if name in sweeps else [registry_spec(name, overrides.get(name), params_file, declared_noise=declared)])
            specs += [dataclasses.replace(spec, skip={**spec.skip, **skips[name]}) if name in skips else spec
                      for spec in own]
        executor = _executor(args)
        summary = None
        if bags and args.global_fixes:
            summary = run_global_fixes(bags, specs, args.out, every=args.every, map_yaml=args.map,
                                       isolate=not args.in_process, max_seconds=args.max_seconds,
                                       honour_skips=args.all, child_progress=args.verbose, executor=executor,
                                       remap=remap)
        elif bags:
            summary = run_benchmark(bags, specs, args.out, mode=args.mode, map_yaml=args.map,
                                    isolate=not args.in_process, max_seconds=args.max_seconds,
                                    plots=not args.no_plots, honour_skips=args.all, progress=True,
                                    child_progress=args.verbose, executor=executor, export_tum=args.export_tum,
                                    record=args.record, remap=remap)
            replays = summary
            if args.with_tracking and args.mode == "global":
                print(summary_table(summary))
                summary = run_benchmark(bags, specs, args.out / "tracking", mode="tracking", map_yaml=args.map,
                                        isolate=not args.in_process, max_seconds=args.max_seconds,
                                        plots=not args.no_plots, honour_skips=args.all, progress=True,
                                        child_progress=args.verbose, executor=executor,
                                        export_tum=args.export_tum, record=args.record, remap=remap)
                append_section(args.out, "tracking")
            if args.with_global_fixes:
                print(summary_table(summary))
                summary = run_global_fixes(bags, specs, args.out / "global_fixes", every=args.every,
                                           map_yaml=args.map, isolate=not args.in_process,
                                           max_seconds=args.max_seconds, honour_skips=args.all,
                                           child_progress=args.verbose, executor=executor, remap=remap)
                append_section(args.out, "global_fixes")
        cv_summary = None
        if cv_indexes:
            if summary is not None:
                print(summary_table(summary))
            modes = cv_modes(args.mode, with_tracking=args.with_tracking, with_global_fixes=args.with_global_fixes,
                             global_fixes_only=args.global_fixes)
            cv_summary = run_cv(cv_indexes, specs, args.out / "cv", modes=modes, every=args.every,
                                isolate=not args.in_process, max_seconds=args.max_seconds, plots=not args.no_plots,
                                honour_skips=args.all or not args.localizers, progress=True,
                                child_progress=args.verbose, executor=executor)
            if bags:
                append_cv_section(args.out)
    except (ValueError, KeyError, LocalizationSuiteError, BagError) as exc:
        print(f"rls_bench: error: {exc}", file=sys.stderr)
        return 1
    finally:
        if isinstance(executor, DaskExecutor):
            executor.close()  # stops the LocalCluster started for these runs
    if cv_summary is not None:
        print(cv_tables(cv_summary))
        print(f"written: {args.out / 'cv' / 'summary.json'}, {args.out / 'cv' / 'summary.md'}")
    if summary is not None:
        if cv_summary is None:
            print(summary_table(summary))
        print(f"\nwritten: {args.out / 'summary.json'}, {args.out / 'summary.md'}")
    if replays is not None and compare is not None:
        label, other = compare
        text = comparison_tables({args.profile or "this run": replays, label: other})
        (args.out / "comparison.md").write_text(f"# {args.profile or 'this run'} and {label}\n\n{text}\n")
        print(f"written: {args.out / 'comparison.md'}")
    return 0

