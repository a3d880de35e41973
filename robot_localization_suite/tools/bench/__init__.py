"""``rls_bench``: every localizer on the same bags, measured the same way.

Each bag is replayed through each localizer with the deterministic replay and the
adapter the nodes use, one child process per run (on a Dask cluster by default:
``executor.py``), and scored against ``/ground_truth``
(``core/metrics.py``). :class:`LocalizerSpec` is the injection point for other
localizers; :func:`run_benchmark`, :func:`run_global_fixes` and :func:`run_cv` (honest
maps: cross-validation splits) take specs. Importing this package loads no rclpy and no
message package: the modules that read bags import them when a bag is read. How it works
and what each field means: ``docs/benchmark.md``.
"""

from __future__ import annotations

from .cli import default_bags_dir, discover_bags, main
from .cv import find_split_indexes, read_split, run_cv
from .executor import DaskExecutor, SequentialExecutor, Task
from .global_fixes import GlobalFixRecord, global_fix_localizer
from .reference import BagReference, load_reference, map_candidates, resolve_map
from .replay import RunRecord, replay_localizer
from .run import run_benchmark, run_global_fixes
from .specs import LocalizerSpec, registry_spec
from .summary import summarize_global_fixes, summarize_run
from .tables import summary_table, write_summary

__all__ = [
    "LocalizerSpec",
    "Task",
    "SequentialExecutor",
    "DaskExecutor",
    "BagReference",
    "RunRecord",
    "GlobalFixRecord",
    "registry_spec",
    "load_reference",
    "map_candidates",
    "resolve_map",
    "replay_localizer",
    "global_fix_localizer",
    "summarize_run",
    "summarize_global_fixes",
    "run_benchmark",
    "run_global_fixes",
    "run_cv",
    "find_split_indexes",
    "read_split",
    "summary_table",
    "write_summary",
    "discover_bags",
    "default_bags_dir",
    "main",
]
