"""rls_bench on Dask: a two-worker LocalCluster on small bags of bags/, sweeps, failures, TUM files."""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

from robot_localization_suite import registry
from robot_localization_suite.core.errors import SettingsError
from robot_localization_suite.launch.dds import loopback_profile_path
from robot_localization_suite.tools import bench
from robot_localization_suite.tools.bench import executor as bench_executor
from robot_localization_suite.tools.bench.sweeps import parse_sweeps, sweep_specs
from robot_localization_suite.tools.bench.trajectories import read_tum

pytest.importorskip("distributed")

BAGS = registry.config_dir().parent / "bags"
# Two small simulated bags: 15 s and 104 s of scans, a few seconds each in tracking mode.
SMALL_BAGS = [BAGS / "room_outliers_bounded", BAGS / "corridor_kidnap"]
# What must not depend on where a run happened (timing and memory may).
ACCURACY = ("outputs", "correct", "fine", "correct_rate", "fine_rate", "rmse_xy_m", "rmse_theta_rad",
            "time_to_first_fix_s", "kidnap_recovery_s", "localized_rate", "sweep")


def accuracy(summary: dict) -> dict:
    return {bag: {name: {k: fields.get(k) for k in ACCURACY} for name, fields in runs.items()}
            for bag, runs in summary.items()}


@pytest.fixture(scope="module")
def mcl_sweep():
    return sweep_specs("mcl_baseline", parse_sweeps(["mcl_baseline.alpha1=0.01,0.05"])["mcl_baseline"])


def test_a_sweep_gives_the_same_numbers_on_one_worker_two_workers_and_child_processes(tmp_path, mcl_sweep):
    summaries = {}
    for workers in (1, 2):
        executor = bench.DaskExecutor(workers=workers, progress=False)
        try:
            summaries[workers] = bench.run_benchmark(SMALL_BAGS, mcl_sweep, tmp_path / str(workers), mode="tracking",
                                                     plots=workers == 2, executor=executor)
            if workers == 2:
                # Every worker process keeps DDS on loopback (and so does the child it starts for a run).
                env = executor.connect().run(lambda: {k: os.environ.get(k) for k in (
                    "FASTRTPS_DEFAULT_PROFILES_FILE", "RMW_IMPLEMENTATION", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
                assert len(env) == 2
                assert all(e == {"FASTRTPS_DEFAULT_PROFILES_FILE": str(loopback_profile_path()),
                                 "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp", "ROS_AUTOMATIC_DISCOVERY_RANGE": None}
                           for e in env.values())
        finally:
            executor.close()
    sequential = bench.run_benchmark(SMALL_BAGS, mcl_sweep, tmp_path / "seq", mode="tracking", plots=False)
    assert accuracy(summaries[1]) == accuracy(summaries[2]) == accuracy(sequential)
    fields = summaries[2]["corridor_kidnap"]["mcl_baseline[alpha1=0.05]"]
    assert fields["sweep"] == {"mcl_baseline.alpha1": 0.05} and fields["outputs"] > 50
    assert 100 < fields["peak_rss_mb"] < 2000  # the run's own child process
    rows = json.loads((tmp_path / "2" / "sweep.json").read_text())["rows"]
    assert [(r["bag"], r["mcl_baseline.alpha1"]) for r in rows] == [
        ("room_outliers_bounded", 0.01), ("room_outliers_bounded", 0.05),
        ("corridor_kidnap", 0.01), ("corridor_kidnap", 0.05)]
    assert "| bag | localizer | mcl_baseline.alpha1 |" in (tmp_path / "2" / "sweep.md").read_text()
    assert (tmp_path / "2" / "plots" / "sweep_mcl_baseline.alpha1.png").stat().st_size > 0


def kill_the_worker():
    """A factory that kills the Dask worker running its task (as the OOM killer would), then itself."""
    os.kill(os.getppid(), signal.SIGKILL)
    os._exit(9)


def test_a_killed_worker_fails_its_run_and_the_others_complete(tmp_path, capsys):
    specs = [bench.LocalizerSpec("killer", kill_the_worker), bench.registry_spec("mcl_baseline")]
    executor = bench.DaskExecutor(workers=2, progress=False)
    try:
        summary = bench.run_benchmark(SMALL_BAGS[:1], specs, tmp_path, mode="tracking", plots=False,
                                      executor=executor)
    finally:
        executor.close()
    assert "rls_bench: Dask: LocalCluster of 2 process workers, dashboard http://127.0.0.1:" in capsys.readouterr().err
    runs = summary["room_outliers_bounded"]
    assert list(runs) == ["killer", "mcl_baseline"]
    assert runs["killer"]["error"].startswith("Dask worker failed: KilledWorker: Worker process ")
    assert "was killed by signal 9" in runs["killer"]["error"]
    assert runs["mcl_baseline"]["correct_rate"] == 1.0


def test_shipped_bags_are_read_from_the_workers_copy(tmp_path):
    copy = tmp_path / "bags" / "room_outliers_bounded"
    copy.mkdir(parents=True)
    for f in SMALL_BAGS[0].iterdir():
        (copy / f.name).write_bytes(f.read_bytes())
    spec = bench.registry_spec("mcl_baseline")
    expected = bench.run_benchmark([copy], [spec], tmp_path / "seq", mode="tracking", plots=False, isolate=False)
    executor = bench.DaskExecutor(workers=1, ship_bags=True, progress=False)
    try:
        reference = bench.load_reference(copy)
        executor.ship([copy])
        for f in copy.iterdir():
            f.unlink()  # the worker can only read what it was sent
        copy.rmdir()
        grid_map, _ = bench.resolve_map(reference, None)
        task = bench.run.replay_task(reference, spec, grid_map, mode="tracking", isolate=True, max_seconds=None,
                                     progress=False)
        [(_, status, record, _)] = list(executor.run([task]))
    finally:
        executor.close()
    assert status == "ok", record
    fields, _ = bench.summarize_run(record, reference)
    assert fields["rmse_xy_m"] == expected["room_outliers_bounded"]["mcl_baseline"]["rmse_xy_m"]


def test_an_unreachable_scheduler_is_one_error_naming_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(bench_executor, "CONNECT_TIMEOUT_S", 2.0)
    code = bench.main([str(SMALL_BAGS[0]), "--localizers", "mcl_baseline", "--out", str(tmp_path),
                       "--scheduler", "tcp://127.0.0.1:9"])
    err = capsys.readouterr().err
    assert code == 1
    assert "rls_bench: error: cannot reach the Dask scheduler at tcp://127.0.0.1:9" in err
    assert err.count("error") == 1 and "Traceback" not in err


def test_a_sweep_value_of_the_wrong_type_is_refused_before_anything_is_submitted(tmp_path, capsys, monkeypatch):
    submitted = []
    monkeypatch.setattr(bench.DaskExecutor, "run", lambda self, tasks: submitted.append(tasks) or iter(()))
    for bad, message in (("mcl_baseline.max_beams=30,60.5", "max_beams must be an integer, got 60.5"),
                         ("mcl_baseline.alpha1=0.01,fast", "alpha1 must be a number, got 'fast'"),
                         ("mcl_baseline.alpha1=0.01,-1", "alpha1 must be in"),
                         ("mcl_baseline.no_such=1", "has no parameter 'no_such'"),
                         ("mcl_baseline.alpha1=", "--sweep expects name.param=value")):
        assert bench.main([str(SMALL_BAGS[0]), "--out", str(tmp_path), "--sweep", bad]) == 1
        assert message in capsys.readouterr().err
    assert submitted == []
    with pytest.raises(SettingsError):
        sweep_specs("mcl_baseline", {"max_beams": [30, "60"]})


def test_the_grid_is_every_combination_named_by_its_values():
    specs = sweep_specs("mcl_baseline", parse_sweeps(["mcl_baseline.alpha1=0.01,0.02",
                                                      "mcl_baseline.max_beams=30,60,90"])["mcl_baseline"])
    assert [s.name for s in specs][:3] == ["mcl_baseline[alpha1=0.01,max_beams=30]",
                                           "mcl_baseline[alpha1=0.01,max_beams=60]",
                                           "mcl_baseline[alpha1=0.01,max_beams=90]"]
    assert len({s.name for s in specs}) == 6
    settings = [s.factory.args[1] for s in specs]
    assert [(x.alpha1, x.max_beams) for x in settings][-1] == (0.02, 90)
    assert all(v.name == s.name and v.sweep == s.sweep for s in specs for v in s.per_bag.values())


def test_tum_files_give_back_the_runs_rmse(tmp_path):
    spec = bench.registry_spec("mcl_baseline")
    summary = bench.run_benchmark(SMALL_BAGS[1:], [spec], tmp_path, mode="tracking", plots=False, isolate=False,
                                  export_tum=tmp_path / "tum")
    fields = summary["corridor_kidnap"]["mcl_baseline"]
    folder = tmp_path / "tum" / "tracking" / "corridor_kidnap"
    stamps, poses = read_tum(folder / "mcl_baseline.tum")
    assert len(stamps) == fields["outputs"]
    truth_stamps, truth = read_tum(folder / "mcl_baseline.truth.tum")
    # The kidnapping's recovery is left out of the RMSE, and so out of the truth file.
    assert fields["kidnappings"] == 2 and 0 < len(truth_stamps) < len(stamps)
    at = np.searchsorted(stamps, truth_stamps)
    assert np.array_equal(stamps[at], truth_stamps)
    rmse = float(np.sqrt(np.mean(np.sum((poses[at, :2] - truth[:, :2]) ** 2, axis=1))))
    assert rmse == pytest.approx(fields["rmse_xy_m"], abs=1e-4)
    whole, _ = read_tum(folder / "ground_truth.tum")
    assert len(whole) > len(truth_stamps)
    pytest.importorskip("evo")
    assert fields["evo_ape_rmse_m"] == pytest.approx(fields["rmse_xy_m"], abs=1e-4)


def test_global_fixes_on_two_workers_match_the_child_processes(tmp_path):
    specs = [bench.registry_spec("ir_initializer"), bench.registry_spec("mcl_baseline")]  # MCL has no global_fix
    executor = bench.DaskExecutor(workers=2, progress=False)
    try:
        on_dask = bench.run_global_fixes(SMALL_BAGS[:1], specs, tmp_path / "dask", every=10, executor=executor)
    finally:
        executor.close()
    plain = bench.run_global_fixes(SMALL_BAGS[:1], specs, tmp_path / "plain", every=10)
    assert list(on_dask["room_outliers_bounded"]) == ["ir_initializer"]
    keys = ("fixes", "global_correct_rate", "global_fine_rate", "recall_at_k")
    assert ({k: on_dask["room_outliers_bounded"]["ir_initializer"][k] for k in keys}
            == {k: plain["room_outliers_bounded"]["ir_initializer"][k] for k in keys})
    assert on_dask["room_outliers_bounded"]["ir_initializer"]["fixes"] > 0
