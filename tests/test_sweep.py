"""Sweeps: a tiny sweep end to end (process pool and Dask), resumption, tables from a hand-made
results file against hand-computed values, and bad configs."""

from __future__ import annotations

import json
import re
import shutil
import textwrap
from dataclasses import replace
from pathlib import Path

import pytest

import pipeline.replay
from data_tools.sweep import load_sweep_config, run_sweep
from data_tools.sweep.config import SweepConfig, to_json
from data_tools.sweep.grid import cells, runs
from data_tools.sweep.report import main as report_main
from data_tools.sweep.results import COLUMNS, OPTIONAL, ResultRow, read_results, results_text
from data_tools.sweep.stats import summarise_method
from data_tools.sweep.tables import best_text, error_table
from pipeline.cli import main as cli_main
from pipeline.cli import sweep_config
from pipeline.errors import InputError
from tests.sweep_rows import HAND_CONFIG, HAND_ROWS

ROOT = Path(__file__).resolve().parents[1]
SWEEPS = ROOT / "configs" / "sweeps"
SMALL_SCENARIO = ROOT / "configs" / "scenarios" / "small-indoor-tags.toml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"

# 3 cells (the base, noise 0, misclassification 30 %) x 1 seed x 3 methods = 9 short runs.
TINY = f"""
name = "tiny"
scenario = "indoor-tags"
scenario_config = "{SMALL_SCENARIO}"
seeds = [0]
methods = ["known", "ml", "mm-nh"]
odom_noise_scale = 1.0
misclassification = 0.1

[[axes]]
name = "noise"
factor = "odom_noise_scale"
values = [0, 1]

[[axes]]
name = "mis"
factor = "misclassification"
values = [0.1, 0.3]
"""
TINY_RUNS = {
    (cell, 0, method)
    for cell in ("noise1-mis0.1", "noise0-mis0.1", "noise1-mis0.3")
    for method in ("known", "ml", "mm-nh")
}


def write(folder: Path, text: str, name: str = "sweep.toml") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(textwrap.dedent(text))
    return path


def without_runtime(rows: list[ResultRow]) -> list[ResultRow]:
    return [replace(r, runtime_s=0.0) for r in rows]


def without_times(tables: str) -> str:
    """tables.md with the mean replay times (the last column of the per-cell tables) blanked:
    a run made again takes another time."""
    lines = tables.split("\n")
    pipes = next(line.count("|") for line in lines if line.endswith("| Time (s) |"))
    return "\n".join(
        line.rsplit("|", 2)[0] + "| t |" if line.count("|") == pipes else line for line in lines
    )


def metrics_files(out: Path) -> dict[Path, int]:
    return {p: p.stat().st_mtime_ns for p in sorted(out.glob("runs/*/*/*/metrics.json"))}


@pytest.fixture(scope="module", autouse=True)
def fixed_code_version():
    """Runs record the code's `git describe`; keep it still while others commit beside us."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("data_tools.sweep.sweep.code_version", lambda: "v-test")
        yield


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory):
    """The tiny sweep run once, in a pool of two processes; (config path, output, summary)."""
    folder = tmp_path_factory.mktemp("tiny")
    config = write(folder, TINY)
    out = folder / "out"
    summary = run_sweep(config, out, workers=2, progress=False)
    return config, out, summary


@pytest.fixture
def swept(tiny_sweep, tmp_path) -> tuple[Path, Path]:
    """The tiny sweep's config, and a copy of its finished output folder for a test to change
    and sweep again."""
    config, first, _ = tiny_sweep
    out = tmp_path / "out"
    shutil.copytree(first, out)
    return config, out


# --- end to end -------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.e2e
def test_tiny_sweep_end_to_end(tiny_sweep):
    config, out, summary = tiny_sweep
    assert (summary.total, summary.new, summary.kept, summary.failed) == (9, 9, 0, ())
    rows = read_results(out / "results.csv")
    assert {(r.cell, r.seed, r.method) for r in rows} == TINY_RUNS
    assert len(rows) == 9
    # Every row is its run's metrics.json, and every run has the contract's outputs.
    for row in rows:
        run = out / "runs" / row.cell / f"seed{row.seed}" / row.method
        metrics = json.loads((run / "metrics.json").read_text())
        assert row.translation_rmse == metrics["translation_error_m"]["rmse"]
        assert row.rotation_max == metrics["rotation_error_rad"]["max"]
        assert row.correct + row.wrong + row.null == row.num_detections == metrics["num_detections"]
        assert row.translation_max >= row.translation_rmse >= row.translation_mean > 0
        one_to_one = metrics["association_one_to_one"]
        assert (row.one_to_one_wrong, row.landmarks_per_true) == (
            one_to_one["wrong"],
            one_to_one["landmarks_per_true"],
        )
        assert row.variance_scale_range == metrics["noise_scales"]["measurement"]["range"]
        assert row.variance_scale_yaw == metrics["noise_scales"]["odometry"]["yaw"]
        for name in ("trajectory.tum", "landmarks.csv", "associations.csv"):
            assert (run / name).stat().st_size > 0
    # One log per (cell, seed), shared by the methods, made with the cell's factors.
    logs = sorted(out.glob("runs/*/seed0/log.mcap"))
    assert len(logs) == 3
    from pipeline.log import read_log

    mis = read_log(out / "runs" / "noise1-mis0.3" / "seed0" / "log.mcap").metadata
    assert mis.confusion_matrix[0][0] == pytest.approx(0.7)
    # Known association with no added odometry noise beats it with noise, on the same seed.
    known = {r.cell: r for r in rows if r.method == "known"}
    assert known["noise0-mis0.1"].translation_rmse < known["noise1-mis0.1"].translation_rmse
    assert all(r.wrong == 0 for r in known.values())
    tables = (out / "tables.md").read_text()
    for heading in ("## Translation error (m)", "## Rotation error (rad)", "## Associations"):
        assert heading in tables
    assert "| Known DA |" in tables and "| MM + NH |" in tables
    assert "Runs made by mmslam v-test" in tables
    assert "### `noise1-mis0.3`: odometry noise scale 1, misclassification 30 %" in tables
    assert "| MM + NH vs | Seeds | Wins | Ties | Losses | Wilcoxon p | Sign test p |" in tables
    for figure in ("fig_noise.png", "fig_mis.png", "fig_trajectories.png"):
        data = (out / figure).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 10_000
    assert summary.files == (
        out / "results.csv",
        out / "tables.md",
        out / "fig_noise.png",
        out / "fig_mis.png",
        out / "fig_trajectories.png",
        out / "run.json",
    )
    # A line per method, over all 3 runs of each (one seed in each of 3 cells).
    assert [line.split(":")[0] for line in summary.method_lines] == ["Known DA", "ML", "MM + NH"]
    counts = re.fullmatch(
        r"MM \+ NH: translation RMSE [0-9.]+ \[[0-9.]+, [0-9.]+\] m over 3 run\(s\); "
        r"against ML on the same 3: wins (\d), ties (\d), losses (\d)",
        summary.method_lines[2],
    )
    assert counts and sum(int(n) for n in counts.groups()) == 3
    record = json.loads((out / "run.json").read_text())
    assert record["config"]["scenario"] == "indoor-tags" and record["config"]["seeds"] == [0]
    assert record["inputs"][0]["path"] == str(config)


@pytest.mark.slow
@pytest.mark.e2e
def test_resumption_skips_finished_runs_and_gives_the_same_tables(swept, monkeypatch):
    config, out = swept
    tables, results = (out / "tables.md").read_bytes(), read_results(out / "results.csv")
    replays: list[str] = []
    real_replay = pipeline.replay.replay

    def counting_replay(log_path, method, out_dir, *args, **kwargs):
        replays.append(f"{Path(out_dir).parent.parent.name}/{method}")
        return real_replay(log_path, method, out_dir, *args, **kwargs)

    monkeypatch.setattr(pipeline.replay, "replay", counting_replay)
    before = metrics_files(out)

    summary = run_sweep(config, out, workers=1, progress=False)
    assert (summary.new, summary.kept, replays) == (0, 9, [])
    assert metrics_files(out) == before  # nothing rewritten
    assert (out / "tables.md").read_bytes() == tables
    assert read_results(out / "results.csv") == results

    # A run whose metrics are gone and one whose metrics.json is cut short are not finished.
    (out / "runs/noise0-mis0.1/seed0/ml/metrics.json").unlink()
    cut = out / "runs/noise1-mis0.3/seed0/mm-nh/metrics.json"
    cut.write_text(cut.read_text()[:40])
    summary = run_sweep(config, out, workers=1, progress=False)
    assert (summary.new, summary.kept) == (2, 7)
    assert sorted(replays) == ["noise0-mis0.1/ml", "noise1-mis0.3/mm-nh"]
    assert without_times((out / "tables.md").read_text()) == without_times(tables.decode())
    assert without_runtime(read_results(out / "results.csv")) == without_runtime(results)


@pytest.mark.slow
@pytest.mark.e2e
def test_runs_from_before_the_newer_metrics_are_kept_with_empty_columns(swept):
    config, out = swept
    older = out / "runs/noise0-mis0.1/seed0/ml/metrics.json"
    metrics = json.loads(older.read_text())
    for key in ("association_one_to_one", "merges", "noise_scales", "solver_fallbacks"):
        del metrics[key]
    older.write_text(json.dumps(metrics))

    summary = run_sweep(config, out, workers=1, progress=False)
    assert (summary.new, summary.kept) == (0, 9)  # kept, not made again
    rows = {(r.cell, r.method): r for r in read_results(out / "results.csv")}
    old = rows["noise0-mis0.1", "ml"]
    assert all(getattr(old, c) is None for c in OPTIONAL)
    assert old.translation_rmse == metrics["translation_error_m"]["rmse"]
    assert all(r.one_to_one_wrong is not None for r in rows.values() if r is not old)
    section = (out / "tables.md").read_text().split("### `noise0-mis0.1`")[1].split("###")[0]
    ml = next(line for line in section.splitlines() if line.startswith("| ML | 1 |"))
    assert ml.split(" | ")[7:10] == ["-", "-", "-"]  # wrong, missed, landmarks per true one


@pytest.mark.slow
@pytest.mark.e2e
def test_seeds_override_adds_seeds_and_ends_with_a_line_per_method(swept, tmp_path, capsys):
    _, out = swept
    config = write(tmp_path, TINY.split("[[axes]]")[0])  # the base cell of the same set-up
    args = ["sweep", str(config), "--out", str(out), "--workers", "1"]  # no -q: its result lines
    assert cli_main([*args, "--seeds", "2"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("sweep tiny: 6 runs (3 new, 3 kept)")
    assert [line.split(":")[0] for line in printed[1:]] == ["Known DA", "ML", "MM + NH"]
    assert "m over 2 run(s); against ML on the same 2: wins " in printed[3]
    assert {(r.cell, r.seed) for r in read_results(out / "results.csv")} == {
        ("noise1-mis0.1", 0),
        ("noise1-mis0.1", 1),
    }
    assert json.loads((out / "sweep.json").read_text())["seeds"] == [0, 1]
    with pytest.raises(SystemExit) as raised:
        cli_main([*args, "--seeds", "0"])
    assert raised.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--seeds: must be >= 1" in err
    with pytest.raises(InputError, match="--seeds must be an integer of at least 1"):
        run_sweep(config, out, seeds=0, progress=False)


@pytest.mark.slow
@pytest.mark.e2e
def test_a_failed_run_is_reported_kept_out_and_retried(tiny_sweep, swept, monkeypatch):
    first = tiny_sweep[1]
    config, out = swept
    run = out / "runs/noise1-mis0.1/seed0/mm-nh"
    shutil.rmtree(run)
    real_replay = pipeline.replay.replay

    def failing_replay(log_path, method, out_dir, *args, **kwargs):
        if method == "mm-nh":
            raise IndexError("index 0 is out of bounds")
        return real_replay(log_path, method, out_dir, *args, **kwargs)

    monkeypatch.setattr(pipeline.replay, "replay", failing_replay)
    summary = run_sweep(config, out, workers=1, progress=False)
    assert summary.failed == ("noise1-mis0.1/seed0/mm-nh: IndexError: index 0 is out of bounds",)
    assert "1 failed" in summary.summary_line()
    assert "IndexError" in (run / "error.txt").read_text()
    assert len(read_results(out / "results.csv")) == 8

    monkeypatch.setattr(pipeline.replay, "replay", real_replay)
    summary = run_sweep(config, out, workers=1, progress=False)
    assert (summary.new, summary.failed) == (1, ())
    assert not (run / "error.txt").exists()
    tables = (out / "tables.md").read_text()
    assert without_times(tables) == without_times((first / "tables.md").read_text())


@pytest.mark.slow
@pytest.mark.e2e
def test_dask_cluster_runs_the_same_runs(tiny_sweep, tmp_path):
    distributed = pytest.importorskip("distributed")
    _, first, _ = tiny_sweep
    config = write(
        tmp_path,
        TINY.replace('["known", "ml", "mm-nh"]', '["known", "mm-nh"]').split("[[axes]]")[0],
    )
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        summary = run_sweep(config, tmp_path / "out", dask_address=cluster.scheduler_address)
    assert (summary.total, summary.new, summary.failed) == (2, 2, ())
    rows = without_runtime(read_results(tmp_path / "out" / "results.csv"))
    pool_rows = without_runtime(read_results(first / "results.csv"))
    assert rows == [r for r in pool_rows if r.cell == "noise1-mis0.1" and r.method != "ml"]
    assert (tmp_path / "out/runs/noise1-mis0.1/seed0/mm-nh/trajectory.tum").exists()


def test_a_bad_dask_address_is_an_input_error(tmp_path):
    pytest.importorskip("distributed")
    config = write(tmp_path, TINY)
    with pytest.raises(InputError, match="--dask"):
        run_sweep(config, tmp_path / "out", dask_address="nonsense")


# --- tables from a hand-made results file -----------------------------------------------------


def test_tables_from_a_hand_made_results_file_match_hand_computed_values(tmp_path):
    (tmp_path / "sweep.json").write_text(to_json(HAND_CONFIG))
    (tmp_path / "results.csv").write_text(results_text(HAND_ROWS))
    assert report_main([str(tmp_path)]) == 0
    tables = (tmp_path / "tables.md").read_text()
    # Means over seeds of each run's statistic; bold: lowest among ML and MM + NH.
    assert "| Known DA | 3.00 | 1.50 | 1.40 | 2.00 | 3 |" in tables
    assert "| ML | 21.00 | 9.00 | 8.00 | 10.33 | 3 |" in tables
    assert "| MM + NH | **4.50** | **2.50** | **2.00** | **3.00** | 2 |" in tables
    assert "| Known DA | 0.0400 | 0.0200 | 0.0200 | 0.0200 | 3 |" in tables
    assert "| ML | 0.5000 | 0.2000 | 0.1900 | 0.2200 | 3 |" in tables
    assert "| MM + NH | **0.1500** | **0.0550** | **0.0450** | **0.0650** | 2 |" in tables
    # Associations: means per run (ML: 7, 8, 6 correct; 3, 2, 4 wrong; 1, 0, 2 switches).
    assert "| ML | 7.0 | 3.0 | 0.0 | 8.0 | 1.0 |" in tables
    assert "| MM + NH | 9.0 | 0.5 | 0.5 | 6.0 | 2.0 |" in tables
    # The axis: medians over seeds of the run's RMSE at noise 1 and 4 (MM + NH: none at 4).
    assert "| Known DA | 2.00 | 7.00 |" in tables
    assert "| ML | 11.00 | 30.00 |" in tables
    assert "| MM + NH | 3.00 | - |" in tables
    assert "13 of 18 runs" in tables
    assert (tmp_path / "fig_noise.png").read_bytes().startswith(PNG_MAGIC)


def test_results_file_round_trips_and_rejects_bad_rows(tmp_path):
    path = tmp_path / "results.csv"
    path.write_text(results_text(HAND_ROWS))
    assert read_results(path) == HAND_ROWS
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0], lines[1].replace(",known,", ",known,x", 1)]) + "\n")
    with pytest.raises(InputError, match="line 2: 'translation_max' must be float"):
        read_results(path)
    path.write_text(",".join(c for c in COLUMNS if c != "switches") + "\n")
    with pytest.raises(InputError, match="missing column 'switches'"):
        read_results(path)


def test_statistics_and_bold_by_hand():
    ml = summarise_method(HAND_ROWS[:6], "ml")
    assert ml.runs == 3
    assert ml.translation["max"] == pytest.approx(21.0)
    assert ml.rotation["rmse"] == pytest.approx(0.22)
    assert summarise_method(HAND_ROWS, "gpda") is None
    assert best_text([1.004, 2.0, 1.0], ["ml", "mm", "known"], 2) == "1.00"
    assert best_text([1.0, 3.0, 0.5], ["ml", "mm", "known"], 2) == "1.00"  # known: reference
    assert best_text([1.001, 1.002], ["ml", "mm"], 2) is None  # all alike: nothing in bold
    table = error_table([ml], "translation", 1)
    assert table.splitlines()[2] == "| ML | 21.0 | 9.0 | 8.0 | 10.3 | 3 |"


# --- configs ----------------------------------------------------------------------------------


SHIPPED = ("kitti05", "kitti05-calibrated", "indoor-tags", "indoor-tags-calibrated")
METHODS = ("known", "ml", "gpda", "mm", "mm-nh")
WITH_DCSAM = (*METHODS, "dcsam")  # the plain kitti05 and indoor-tags sweeps


def builtin(name: str) -> SweepConfig:
    return load_sweep_config(sweep_config(name))  # as `mmslam sweep NAME` finds it


def axis_values(config: SweepConfig) -> dict[str, tuple[float, ...]]:
    return {a.factor: a.values for a in config.axes}


def paper_sweeps(name: str, scenario: str, num_classes: int) -> list[SweepConfig]:
    """The built-in sweep `name` (the noise drawn stated: true covariances, DC-SAM among the
    methods) and its `-calibrated` twin, checked alike, for the test of what each holds."""
    configs = []
    for variant in (name, f"{name}-calibrated"):
        config = builtin(variant)
        assert (config.name, config.scenario) == (variant, scenario)
        assert config.num_classes == num_classes
        assert len(config.seeds) >= 10
        assert config.methods == (WITH_DCSAM if variant == name else METHODS)
        assert config.true_covariance == (variant == name)
        configs.append(config)
    return configs


def test_built_in_sweeps_load_with_the_grids_intended():
    small = builtin("small")
    assert small.scenario == "indoor-tags" and small.methods == METHODS
    assert len(runs(small)) == 50  # stays small: it is the CI's sweep

    for kitti in paper_sweeps("kitti05", "kitti05-cars", 1):
        assert [c.name for c in cells(kitti)] == [f"noise{n}-mis0" for n in (3, 0, 1, 5)]

    for indoor in paper_sweeps("indoor-tags", "indoor-tags", 2):
        factors = axis_values(indoor)
        assert factors["odom_noise_scale"] == (0, 1, 2, 4, 6, 8, 10)
        assert factors["misclassification"] == (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
        assert len(cells(indoor)) == 12  # the base cell lies on both axes

    city = builtin("city-grid")
    assert (city.scenario, city.num_classes, city.misclassification) == ("city-grid", 3, 0.1)
    assert set(axis_values(city)) == {"odom_noise_scale"} and len(city.seeds) >= 10
    assert {c.misclassification for c in cells(city)} == {0.1}
    park = builtin("planar-park")
    assert (park.scenario, park.num_classes, len(cells(park))) == ("planar-park", 1, 1)
    assert len(park.seeds) >= 10
    # The calibrated and true-covariance sweeps may not share an output folder.
    assert len({builtin(n).fingerprint for n in SHIPPED}) == len(SHIPPED)


BAD_CONFIGS = {
    "not TOML": ("scenario = ", "not valid TOML"),
    "no scenario": ("seeds = 1\nmethods = ['ml']", "missing key 'scenario'"),
    "unknown scenario": ("scenario = 'mars'\nseeds = 1\nmethods = ['ml']", "unknown scenario"),
    "unknown key": ("{base}\nworkers = 2", "unknown key 'workers'"),
    "unknown method": ("scenario = 'indoor-tags'\nseeds = 1\nmethods = ['icp']", "methods[0]"),
    "no seeds": ("scenario = 'indoor-tags'\nseeds = 0\nmethods = ['ml']", "'seeds'"),
    "negative seed": ("scenario = 'indoor-tags'\nseeds = [1, -2]\nmethods = ['ml']", "seeds[1]"),
    "percentage": ("{base}\nmisclassification = 10", "'misclassification' must be in [0, 1]"),
    "negative noise": ("{base}\nodom_noise_scale = -1", "'odom_noise_scale' must be in [0, 100]"),
    "bad factor": (
        "{base}\n[[axes]]\nname = 'x'\nfactor = 'speed'\nvalues = [1]",
        "axes[0].factor",
    ),
    "bad axis value": (
        "{base}\n[[axes]]\nname = 'x'\nfactor = 'misclassification'\nvalues = [0.1, 0.6, 2]",
        "axes[0].values[2]",
    ),
    "axis without values": (
        "{base}\n[[axes]]\nname = 'x'\nfactor = 'misclassification'",
        "missing key 'axes[0].values'",
    ),
    "one class": ("{base}\nnum_classes = 1\nmisclassification = 0.2", "num_classes"),
    "no scenario file": ("{base}\nscenario_config = 'nope.toml'", "no such file"),
    "bad back-end key": ("{base}\nbackend_config = 'backend.toml'", "unknown key 'isam'"),
}


@pytest.mark.parametrize("case", BAD_CONFIGS)
def test_bad_sweep_configs_are_input_errors(tmp_path, case):
    text, message = BAD_CONFIGS[case]
    base = "scenario = 'indoor-tags'\nseeds = 1\nmethods = ['ml']"
    write(tmp_path, "[isam]\nrelinearize_skip = 1\n", "backend.toml")
    path = write(tmp_path, text.replace("{base}", base))
    with pytest.raises(InputError, match=re.escape(message)) as raised:
        run_sweep(path, tmp_path / "out", progress=False)
    assert "\n" not in str(raised.value)
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
@pytest.mark.e2e
def test_bad_output_folders_and_workers_are_input_errors(tiny_sweep, tmp_path):
    config, _, _ = tiny_sweep
    with pytest.raises(InputError, match="--workers"):
        run_sweep(config, tmp_path / "a", workers=0)
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a directory"):
        run_sweep(config, tmp_path / "file")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="not a sweep's folder"):
        run_sweep(config, tmp_path / "full")


@pytest.mark.slow
@pytest.mark.e2e
def test_a_folder_of_another_set_up_is_refused(swept, tmp_path):
    _, out = swept
    other = write(tmp_path, TINY.replace("seeds = [0]", "seeds = [0]\nnum_classes = 3"), "b.toml")
    with pytest.raises(InputError, match="another set-up"):
        run_sweep(other, out, progress=False)
