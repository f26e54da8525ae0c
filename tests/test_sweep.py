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
from data_tools.sweep.config import Axis, SweepConfig, to_json
from data_tools.sweep.grid import Cell
from data_tools.sweep.report import main as report_main
from data_tools.sweep.results import COLUMNS, ResultRow, read_results, results_text
from data_tools.sweep.stats import summarise_method
from data_tools.sweep.tables import best_text, error_table
from pipeline.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
SWEEPS = ROOT / "configs" / "sweeps"
SMALL_SCENARIO = SWEEPS / "small-indoor-tags.toml"
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


# --- end to end -------------------------------------------------------------------------------


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
    for figure in ("fig_noise.png", "fig_mis.png"):
        data = (out / figure).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 10_000
    assert summary.files == (
        out / "results.csv",
        out / "tables.md",
        out / "fig_noise.png",
        out / "fig_mis.png",
        out / "run.json",
    )
    record = json.loads((out / "run.json").read_text())
    assert record["config"]["scenario"] == "indoor-tags" and record["config"]["seeds"] == [0]
    assert record["inputs"][0]["path"] == str(config)


def test_resumption_skips_finished_runs_and_gives_the_same_tables(
    tiny_sweep, tmp_path, monkeypatch
):
    config, first, _ = tiny_sweep
    out = tmp_path / "out"
    shutil.copytree(first, out)
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
    assert (out / "tables.md").read_bytes() == tables
    assert without_runtime(read_results(out / "results.csv")) == without_runtime(results)


def test_a_failed_run_is_reported_kept_out_and_retried(tiny_sweep, tmp_path, monkeypatch):
    config, first, _ = tiny_sweep
    out = tmp_path / "out"
    shutil.copytree(first, out)
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
    assert (out / "tables.md").read_bytes() == (first / "tables.md").read_bytes()


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

HAND_CONFIG = SweepConfig(
    name="hand",
    scenario="indoor-tags",
    scenario_config=None,
    backend_config=None,
    num_classes=2,
    true_covariance=False,
    seeds=(0, 1, 2),
    methods=("known", "ml", "mm-nh"),
    odom_noise_scale=1.0,
    misclassification=0.1,
    axes=(Axis("noise", "odom_noise_scale", (1.0, 4.0)),),
    fingerprint="0",
)


def hand_row(cell: Cell, seed: int, method: str, t: tuple, r: tuple, a: tuple) -> ResultRow:
    return ResultRow(
        cell=cell.name,
        odom_noise_scale=cell.odom_noise_scale,
        misclassification=cell.misclassification,
        seed=seed,
        method=method,
        translation_max=t[0],
        translation_mean=t[1],
        translation_median=t[2],
        translation_rmse=t[3],
        rotation_max=r[0],
        rotation_mean=r[1],
        rotation_median=r[2],
        rotation_rmse=r[3],
        correct=a[0],
        wrong=a[1],
        null=a[2],
        unlabelled=0,
        switches=a[3],
        num_poses=100,
        num_detections=a[0] + a[1] + a[2],
        num_landmarks=a[4],
        runtime_s=1.5,
    )


BASE, NOISY = Cell(1.0, 0.1), Cell(4.0, 0.1)
HAND_ROWS = [
    # known: translation RMSE 1, 2, 3 on the base cell
    hand_row(BASE, 0, "known", (2.0, 1.0, 0.9, 1.0), (0.02, 0.01, 0.01, 0.01), (10, 0, 0, 0, 5)),
    hand_row(BASE, 1, "known", (3.0, 1.5, 1.4, 2.0), (0.04, 0.02, 0.02, 0.02), (10, 0, 0, 0, 5)),
    hand_row(BASE, 2, "known", (4.0, 2.0, 1.9, 3.0), (0.06, 0.03, 0.03, 0.03), (10, 0, 0, 0, 5)),
    hand_row(BASE, 0, "ml", (10.0, 6.0, 5.0, 7.0), (0.3, 0.1, 0.09, 0.12), (7, 3, 0, 1, 8)),
    hand_row(BASE, 1, "ml", (20.0, 9.0, 8.0, 11.0), (0.5, 0.2, 0.19, 0.22), (8, 2, 0, 0, 7)),
    hand_row(BASE, 2, "ml", (33.0, 12.0, 11.0, 13.0), (0.7, 0.3, 0.29, 0.32), (6, 4, 0, 2, 9)),
    hand_row(BASE, 0, "mm-nh", (4.0, 2.0, 1.5, 2.5), (0.1, 0.05, 0.04, 0.06), (9, 0, 1, 3, 6)),
    hand_row(BASE, 1, "mm-nh", (5.0, 3.0, 2.5, 3.5), (0.2, 0.06, 0.05, 0.07), (9, 1, 0, 1, 6)),
    # mm-nh seed 2 is missing: its numbers are means over two runs
    hand_row(NOISY, 0, "known", (9, 9, 9, 9.0), (0.9, 0.9, 0.9, 0.9), (10, 0, 0, 0, 5)),
    hand_row(NOISY, 1, "known", (9, 9, 9, 5.0), (0.9, 0.9, 0.9, 0.5), (10, 0, 0, 0, 5)),
    hand_row(NOISY, 2, "known", (9, 9, 9, 7.0), (0.9, 0.9, 0.9, 0.7), (10, 0, 0, 0, 5)),
    hand_row(NOISY, 0, "ml", (9, 9, 9, 40.0), (0.9, 0.9, 0.9, 0.4), (10, 0, 0, 0, 5)),
    hand_row(NOISY, 1, "ml", (9, 9, 9, 20.0), (0.9, 0.9, 0.9, 0.2), (10, 0, 0, 0, 5)),
]


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


def test_shipped_configs_load():
    small = load_sweep_config(SWEEPS / "small.toml")
    assert small.scenario == "indoor-tags" and small.methods == (
        "known",
        "ml",
        "gpda",
        "mm",
        "mm-nh",
    )
    indoor = load_sweep_config(SWEEPS / "indoor-tags.toml")
    assert indoor.num_classes == 2
    factors = {a.factor: a.values for a in indoor.axes}
    assert min(factors["odom_noise_scale"]) == 0 and max(factors["odom_noise_scale"]) == 10
    assert min(factors["misclassification"]) == 0 and max(factors["misclassification"]) == 0.5
    kitti = load_sweep_config(SWEEPS / "kitti05.toml")
    assert kitti.scenario == "kitti05-cars" and not kitti.axes


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


def test_a_folder_of_another_set_up_is_refused(tiny_sweep, tmp_path):
    _, first, _ = tiny_sweep
    out = tmp_path / "out"
    shutil.copytree(first, out)
    other = write(tmp_path, TINY.replace("seeds = [0]", "seeds = [0]\nnum_classes = 3"), "b.toml")
    with pytest.raises(InputError, match="another set-up"):
        run_sweep(other, out, progress=False)
