"""rls_bench --cv on a tiny split of the hand-made corridor log (tools/bench/cv.py), with the echo test double."""

from __future__ import annotations

import functools
import json
import shutil

import numpy as np
import pytest
import yaml
from carmen_world import corridor_poses, write_log
from echo_localizer import EchoLocalizer

from robot_localization_suite.core import metrics
from robot_localization_suite.tools import bench
from robot_localization_suite.tools.bench import cv
from robot_localization_suite.tools.carmen_cv import split_log

SCANS, BLOCKS = 60, 3  # blocks of 20 scans, stamped 10 + i / 4 s: block 1 10-14.75 s, 2 15-19.75 s, 3 20-24.75 s


@pytest.fixture(scope="module")
def corridor_split(tmp_path_factory):
    """A 60-scan corridor log split in 3, and the ground truth of the whole log (from the block bags)."""
    work = tmp_path_factory.mktemp("cvbench")
    split = split_log(write_log(work / "corridor-corrected.log", corridor_poses(SCANS)), work / "split", BLOCKS,
                      on_warning=None)
    truths = [bench.load_reference(b.bag).ground_truth for b in split.blocks]
    truth = metrics.Trajectory(np.concatenate([t.stamps for t in truths]), np.concatenate([t.poses for t in truths]))
    return split, truth


def uneven(stamp: float):
    """1 m off from 16 s to 18 s (8 outputs of block 2); nothing after 22 s (block 3 has 8 outputs)."""
    if stamp >= 22.0 - 1e-9:
        return None
    return (1.0, 0.0, 0.0) if 16.0 - 1e-9 <= stamp < 18.0 - 1e-9 else (0.0, 0.0, 0.0)


def lost_in_block_3(stamp: float):
    """Right in blocks 1 and 2, 2 m off all through block 3: no fix there."""
    return (2.0, 0.0, 0.0) if stamp >= 20.0 - 1e-9 else (0.0, 0.0, 0.0)


def spec(truth, error, name, **kwargs):
    return bench.LocalizerSpec(name, functools.partial(EchoLocalizer, truth, error), **kwargs)


def test_pooled_rates_are_the_blocks_outputs_together_and_same_map_uses_the_whole_log_map(corridor_split, tmp_path):
    split, truth = corridor_split
    specs = [spec(truth, uneven, "uneven"), spec(truth, lost_in_block_3, "lost3"),
             spec(truth, uneven, "picky", skip={"corridor*": "not on corridors"})]
    summary = cv.run_cv([split.index], specs, tmp_path, modes=["global"], isolate=False, plots=False)
    blocks = summary["global"]["blocks"]
    names = [f"corridor_cv{k}of3" for k in (1, 2, 3)]
    assert list(blocks) == names
    for k, name in enumerate(names, start=1):
        honest, same = blocks[name]["uneven"]["honest"], blocks[name]["uneven"]["same_map"]
        assert honest["map"] == str(split.blocks[k - 1].map_yaml)  # its own map, from the other blocks
        assert same["map"] == str(split.full_map_yaml)  # the whole-log map, same bag
        assert honest["inputs"] == same["inputs"] == 20
        # The corridor's walls beyond a block's reach are only in the whole-log map.
        assert same["map_coverage_median"] >= honest["map_coverage_median"]
    assert [blocks[n]["uneven"]["honest"]["correct_rate"] for n in names] == [1.0, 0.6, 1.0]
    assert [blocks[n]["uneven"]["honest"]["outputs"] for n in names] == [20, 20, 8]
    pooled = summary["global"]["pooled"]["corridor"]
    assert pooled["uneven"]["blocks"] == 3 and pooled["uneven"]["left_out"] == {}
    for kind in cv.MAP_KINDS:
        # 40 correct of 48 outputs: pooled, not the mean of the rates (0.867).
        assert pooled["uneven"][kind]["correct_rate"] == pytest.approx(40 / 48, abs=1e-4)
        assert pooled["uneven"][kind]["outputs"] == 48
    # Block 3 never fixes: null rate there, but its 20 wrong outputs count in the pooled rate.
    assert blocks[names[2]]["lost3"]["honest"]["correct_rate"] is None
    assert pooled["lost3"]["honest"]["correct_rate"] == pytest.approx(40 / 60, abs=1e-4)
    assert pooled["lost3"]["honest"]["runs_without_fix"] == 1
    # The pooled covered rate is the concatenation of the blocks' covered outputs.
    covered = sum(blocks[n]["uneven"]["honest"]["outputs_covered"] for n in names)
    assert pooled["uneven"]["honest"]["outputs_covered"] == covered
    assert pooled["picky"] == {"skipped": "not on corridors"}
    assert blocks[names[0]]["picky"] == {"skipped": "not on corridors"}
    # Files: the JSON is the summary; the table has a pooled and a per-block part.
    assert json.loads((tmp_path / "summary.json").read_text()) == json.loads(json.dumps(summary))
    table = (tmp_path / "summary.md").read_text()
    assert "## Global mode (no prior): pooled per log" in table and "## Global mode (no prior): per block" in table
    assert "| corridor | uneven | 3 | 48 / 48 | 0.833 / 0.833 |" in table
    assert "| corridor_cv2of3 | uneven | 20 / 20 | 0.6 / 0.6 |" in table
    assert "| corridor | picky | – |" in table and "skipped: not on corridors" in table
    assert "| corridor_cv1of3 | picky |" not in table  # skipped on every block: the pooled row says it once


def test_global_fixes_pool_every_fix(corridor_split, tmp_path):
    split, truth = corridor_split
    summary = cv.run_cv([split.index.parent], [spec(truth, uneven, "uneven")], tmp_path,
                        modes=["global_fixes"], every=2, isolate=False, plots=False)
    blocks = summary["global_fixes"]["blocks"]
    fixes = [blocks[f"corridor_cv{k}of3"]["uneven"]["honest"] for k in (1, 2, 3)]
    assert [f["fixes"] for f in fixes] == [10, 10, 10]
    # Block 2: the fixes at 16, 16.5, 17 and 17.5 s are 1 m off (global_fix ignores "no output").
    assert [f["global_correct_rate"] for f in fixes] == [1.0, 0.6, 1.0]
    pooled = summary["global_fixes"]["pooled"]["corridor"]["uneven"]
    assert pooled["honest"]["fixes"] == 30
    assert pooled["honest"]["global_correct_rate"] == pytest.approx(26 / 30, abs=1e-4)
    assert pooled["same_map"]["global_correct_rate"] == pytest.approx(26 / 30, abs=1e-4)
    assert pooled["honest"]["fixes_covered"] == sum(f["fixes_covered"] for f in fixes)
    assert "Single-scan global fixes (every 2th scan, no prior): pooled per log" in (tmp_path / "summary.md").read_text()


def test_a_missing_map_or_a_short_block_is_a_skipped_row_not_a_crash(corridor_split, tmp_path, capsys):
    split, truth = corridor_split
    broken = tmp_path / "broken"
    shutil.copytree(split.index.parent, broken)
    (broken / "corridor_cv2of3.yaml").unlink()
    index = yaml.safe_load((broken / "corridor_cv.yaml").read_text())
    index["blocks"][2]["scan_count"] = 12  # as a hand-edited or older index might list it
    (broken / "corridor_cv.yaml").write_text(yaml.safe_dump(index))
    summary = cv.run_cv([broken / "corridor_cv.yaml"], [spec(truth, uneven, "uneven")], tmp_path / "out",
                        modes=["tracking"], isolate=False, plots=False)
    blocks = summary["tracking"]["blocks"]
    assert "corridor_cv2of3.yaml" in blocks["corridor_cv2of3"]["uneven"]["skipped"]
    assert "missing" in blocks["corridor_cv2of3"]["uneven"]["skipped"]
    assert blocks["corridor_cv3of3"]["uneven"]["skipped"] == "12 scans, fewer than 20"
    assert blocks["corridor_cv1of3"]["uneven"]["honest"]["correct_rate"] == 1.0
    pooled = summary["tracking"]["pooled"]["corridor"]["uneven"]
    assert pooled["blocks"] == 1 and set(pooled["left_out"]) == {"corridor_cv2of3", "corridor_cv3of3"}
    assert "skipped: 12 scans, fewer than 20" in (tmp_path / "out" / "summary.md").read_text()
    assert "corridor_cv3of3: skipped" in capsys.readouterr().err


def test_split_arguments_are_checked(tmp_path):
    with pytest.raises(cv.CvIndexError, match="does not exist"):
        cv.find_split_indexes([tmp_path / "nowhere"])
    with pytest.raises(cv.CvIndexError, match="no split index"):
        cv.find_split_indexes([tmp_path])
    (tmp_path / "x_cv.yaml").write_text("format: something else\n")
    with pytest.raises(cv.CvIndexError, match="not a 'rls-carmen-cv/1' split index"):
        cv.read_split(tmp_path / "x_cv.yaml")
    assert cv.cv_modes("global", with_tracking=True, with_global_fixes=True, global_fixes_only=False) == [
        "global", "tracking", "global_fixes"]
    assert cv.cv_modes("tracking", with_tracking=True, with_global_fixes=False, global_fixes_only=False) == [
        "tracking"]
    assert cv.cv_modes("global", with_tracking=False, with_global_fixes=False, global_fixes_only=True) == [
        "global_fixes"]


def test_command_line_runs_the_splits_after_the_bags_and_appends_their_tables(corridor_split, tmp_path, monkeypatch):
    split, _ = corridor_split
    calls = []

    def fake_replays(bags, specs, out, **kwargs):
        out.mkdir(parents=True, exist_ok=True)
        (out / "summary.md").write_text(f"# replays {kwargs['mode']}\n")
        return {}

    def fake_cv(indexes, specs, out, **kwargs):
        calls.append((indexes, [s.name for s in specs], out, kwargs))
        out.mkdir(parents=True, exist_ok=True)
        (out / "summary.md").write_text("# cv\n\n## tracking: pooled\n")
        return {"modes": []}

    monkeypatch.setattr(bench.cli, "run_benchmark", fake_replays)
    monkeypatch.setattr(bench.cli, "run_cv", fake_cv)
    argv = ["--cv", str(split.index.parent), "--mode", "tracking", "--with-global-fixes", "--no-plots",
            "--out", str(tmp_path / "a")]
    assert bench.main(argv) == 0  # --cv alone: no bag needed
    indexes, names, out, kwargs = calls[-1]
    assert indexes == [split.index] and out == tmp_path / "a" / "cv"
    assert kwargs["modes"] == ["tracking", "global_fixes"] and kwargs["honour_skips"] and not kwargs["plots"]
    assert "ima_topo_localizer" in names  # run_cv leaves camera localizers out itself
    assert not (tmp_path / "a" / "summary.md").exists()
    argv = [str(split.blocks[0].bag), "--cv", str(split.index), "--localizers", "mcl_baseline", "--out",
            str(tmp_path / "b")]
    assert bench.main(argv) == 0
    assert calls[-1][3]["modes"] == ["global"] and not calls[-1][3]["honour_skips"]  # named: run as asked
    assert (tmp_path / "b" / "summary.md").read_text() == "# replays global\n\n## cv\n\n### tracking: pooled\n"
    assert bench.main(["--cv", str(split.index), "--map", str(split.full_map_yaml), "--out", str(tmp_path)]) == 1


def test_the_splits_on_two_dask_workers_pool_as_in_this_process(corridor_split, tmp_path):
    pytest.importorskip("distributed")
    split, truth = corridor_split
    specs = [spec(truth, uneven, "uneven"), spec(truth, lost_in_block_3, "lost3")]
    modes = ["global", "global_fixes"]
    here = cv.run_cv([split.index], specs, tmp_path / "here", modes=modes, every=2, isolate=False, plots=False)
    executor = bench.DaskExecutor(workers=2, progress=False)
    try:
        on_dask = cv.run_cv([split.index], specs, tmp_path / "dask", modes=modes, every=2, plots=False,
                            executor=executor)
    finally:
        executor.close()
    for summary in (here, on_dask):  # timing and memory differ; the pooled and per-block rates may not
        for mode in modes:
            for runs in summary[mode]["blocks"].values():
                for entry in runs.values():
                    for fields in entry.values():
                        for key in [k for k in fields if k.startswith(("update_ms", "fix_ms", "peak_rss", "wall_s",
                                                                        "map_setup"))]:
                            del fields[key]
            for pooled in summary[mode]["pooled"].values():
                for entry in pooled.values():
                    for kind in ("honest", "same_map"):
                        for key in [k for k in entry[kind] if k.startswith(("update_ms", "fix_ms", "peak_rss"))]:
                            del entry[kind][key]
    assert on_dask["global"] == here["global"] and on_dask["global_fixes"] == here["global_fixes"]
    assert list(on_dask["global_fixes"]["blocks"]["corridor_cv1of3"]) == ["uneven", "lost3"]
