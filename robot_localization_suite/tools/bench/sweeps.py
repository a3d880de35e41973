"""Parameter sweeps: ``--sweep name.param=v1,v2,...``, the grid of their values on every bag.

:func:`parse_sweeps` reads the options, :func:`sweep_specs` makes one :class:`LocalizerSpec`
per grid point (settings checked by the settings dataclasses before anything runs: a value
of the wrong type or out of range is a :class:`SettingsError`), :func:`write_sweep` writes
``sweep.md`` / ``sweep.json`` (the parameters as columns) and a plot per swept parameter.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ...core.settings import yaml_value
from .specs import LocalizerSpec, registry_spec
from .tables import _fmt

__all__ = ["parse_sweeps", "sweep_specs", "sweep_rows", "sweep_table", "write_sweep"]

# The figures of a sweep's table and plots: (field, column title).
_METRICS = (
    ("outputs", "outputs"),
    ("correct_rate", "correct rate"),
    ("fine_rate", "fine rate"),
    ("rmse_xy_m", "RMSE xy [m]"),
    ("evo_ape_rmse_m", "evo APE RMSE [m]"),
    ("rmse_theta_rad", "RMSE θ [rad]"),
    ("time_to_first_fix_s", "first fix [s]"),
    ("update_ms_median", "update median [ms]"),
    ("peak_rss_mb", "peak RSS [MB]"),
)
_PLOTTED = (("correct_rate", "correct rate"), ("rmse_xy_m", "RMSE xy [m]"))


def parse_sweeps(items: Sequence[str]) -> dict[str, dict[str, list[Any]]]:
    """``["mcl_baseline.alpha1=0.01,0.02", ...]`` -> ``{"mcl_baseline": {"alpha1": [0.01, 0.02]}}`` (YAML values)."""
    sweeps: dict[str, dict[str, list[Any]]] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        name, dot, param = key.partition(".")
        values = [yaml_value(v, f"--sweep {item}") for v in raw.split(",") if v.strip()]
        if not sep or not dot or not name or not param or not values:
            raise ValueError(f"--sweep expects name.param=value,value,..., got {item!r}")
        if param in sweeps.get(name, {}):
            raise ValueError(f"--sweep {name}.{param} given twice")
        sweeps.setdefault(name, {})[param] = values
    return sweeps


def _label(name: str, point: Mapping[str, Any]) -> str:
    return f"{name}[{','.join(f'{p}={v}' for p, v in point.items())}]"


def sweep_specs(
    name: str, sweep: Mapping[str, Sequence[Any]], overrides: Mapping[str, Any] | None = None,
    params_file: Path | None = None, *, declared_noise: bool = True,
) -> list[LocalizerSpec]:
    """One spec per point of the grid of ``sweep`` (param -> values), ``overrides`` beneath it.

    Each spec (and its per-bag variants) is named ``name[param=value,...]`` and carries
    ``sweep``; building it checks every value against the settings dataclass.
    """
    params = list(sweep)
    specs = []
    for values in itertools.product(*(sweep[p] for p in params)):
        point = dict(zip(params, values, strict=True))
        spec = registry_spec(name, {**(overrides or {}), **point}, params_file, declared_noise=declared_noise)
        label = _label(name, point)
        swept = {f"{name}.{p}": v for p, v in point.items()}
        per_bag = {glob: dataclasses.replace(s, name=label, sweep=swept) for glob, s in spec.per_bag.items()}
        specs.append(dataclasses.replace(spec, name=label, sweep=swept, per_bag=per_bag))
    return specs


def sweep_rows(summary: Mapping[str, Mapping[str, Mapping[str, Any]]]) -> tuple[list[str], list[dict[str, Any]]]:
    """The swept parameters (in order of first appearance) and a row per swept run (bag, localizer, values)."""
    params: list[str] = []
    rows = []
    for bag, runs in summary.items():
        for label, fields in runs.items():
            sweep = fields.get("sweep")
            if not sweep:
                continue
            params += [p for p in sweep if p not in params]
            rows.append({"bag": bag, "localizer": label.split("[", 1)[0], **sweep,
                         **{key: fields.get(key) for key, _ in _METRICS},
                         "error": fields.get("error"), "truncated": bool(fields.get("truncated"))})
    return params, rows


def sweep_table(summary: Mapping[str, Mapping[str, Mapping[str, Any]]]) -> str:
    """A markdown table: a row per (bag, localizer, grid point), the swept parameters as columns."""
    params, rows = sweep_rows(summary)
    metrics = [(key, title) for key, title in _METRICS if any(row.get(key) is not None for row in rows)]
    header = ["bag", "localizer", *params, *(title for _, title in metrics), "notes"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        notes = ([f"error: {row['error']}"] if row["error"] else []) + (["truncated"] if row["truncated"] else [])
        cells = [row["bag"], row["localizer"], *(_fmt(row.get(p)) for p in params),
                 *(_fmt(row.get(key)) for key, _ in metrics), "; ".join(notes)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_sweep(out_dir: Path, summary: Mapping[str, Mapping[str, Mapping[str, Any]]], *, mode: str,
                plots: bool = True) -> list[Path]:
    """``sweep.json`` (the rows), ``sweep.md`` (the table) and ``plots/sweep_<name.param>.png``; returns the plots."""
    out_dir = Path(out_dir)
    params, rows = sweep_rows(summary)
    (out_dir / "sweep.json").write_text(json.dumps({"mode": mode, "params": params, "rows": rows}, indent=2) + "\n")
    (out_dir / "sweep.md").write_text(f"# rls_bench sweep ({mode} mode)\n\n{sweep_table(summary)}\n")
    return _plot_sweep(out_dir / "plots", params, rows, mode) if plots and rows else []


def _plot_sweep(plot_dir: Path, params: list[str], rows: list[dict[str, Any]], mode: str) -> list[Path]:
    """Per swept parameter: each metric against its value, a line per (bag, localizer), the mean over the others."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    plot_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for param in params:
        fig, axes = plt.subplots(1, len(_PLOTTED), figsize=(5 * len(_PLOTTED), 4))
        lines = sorted({(row["bag"], row["localizer"]) for row in rows if param in row})
        for ax, (key, title) in zip(axes, _PLOTTED, strict=True):
            for bag, localizer in lines:
                own = [row for row in rows if (row["bag"], row["localizer"]) == (bag, localizer)]
                values = sorted({row[param] for row in own})
                means = [np.mean([row[key] for row in own if row[param] == v and row[key] is not None] or [np.nan])
                         for v in values]
                ax.plot(values, means, "o-", label=bag if len({b for b, _ in lines}) == len(lines)
                        else f"{bag} / {localizer}")
            ax.set_xlabel(param)
            ax.set_ylabel(title)
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=8)
        others = [p for p in params if p != param]
        fig.suptitle(f"sweep of {param} ({mode} mode)" + (f"; mean over {', '.join(others)}" if others else ""))
        written.append(plot_dir / f"sweep_{param}.png")
        fig.savefig(written[-1], dpi=110, bbox_inches="tight")
        plt.close(fig)
    return written
