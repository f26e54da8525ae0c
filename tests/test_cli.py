"""The command line: exit status 2 with one line on bad input, nothing written lost."""

import json
import os
import subprocess
import sys

import gtsam
import numpy as np
import pytest

from pipeline.backend.solver import Isam2Solver
from pipeline.cli import main
from tests.synthetic import Scene, square_loop, write_scene
from tests.test_log import BAD_MESSAGES, good_messages, write_raw


@pytest.fixture(scope="module")
def good_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("logs") / "good.mcap"
    landmarks = np.array([[5.0, 3.0, 0.0], [9.0, -3.0, 0.0], [3.0, 9.0, 0.0]])
    scene = Scene(square_loop(10.0, 1.0, laps=0.5), landmarks, np.array([0, 1, 0]))
    return write_scene(path, scene, seed=1)


@pytest.fixture
def earlier_run(tmp_path, good_log):
    """An output folder from an earlier good run, with its bytes and times."""
    out = tmp_path / "out"
    assert main(["replay", str(good_log), "--method", "mm-nh", "--out", str(out), "--quiet"]) == 0
    return out, snapshot(out)


def snapshot(folder):
    return {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.iterdir())}


def run_cli(capsys, *args: str) -> tuple[int, str, str]:
    status = main(list(args))
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def assert_one_line_error(status: int, err: str, *needles: str) -> None:
    assert status == 2
    assert err.count("\n") == 1 and err.endswith("\n")
    assert "Traceback" not in err
    for needle in needles:
        assert needle in err


def test_replay_writes_the_contract_outputs(tmp_path, good_log, capsys):
    status, out, _ = run_cli(
        capsys, "replay", str(good_log), "--method", "ml", "--out", str(tmp_path / "o"), "--quiet"
    )
    assert status == 0 and "ml:" in out
    names = sorted(p.name for p in (tmp_path / "o").iterdir())
    assert names == ["associations.csv", "landmarks.csv", "metrics.json", "trajectory.tum"]
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    for key in (
        "method",
        "num_poses",
        "num_detections",
        "num_landmarks",
        "runtime_s",
        "translation_error_m",
        "rotation_error_rad",
        "association",
    ):
        assert key in metrics
    assert set(metrics["translation_error_m"]) == {"max", "mean", "median", "rmse"}
    lines = (tmp_path / "o" / "trajectory.tum").read_text().splitlines()
    assert len(lines) == metrics["num_poses"] and len(lines[0].split()) == 8
    header = (tmp_path / "o" / "landmarks.csv").read_text().splitlines()[0]
    assert header == "id,x,y,z,class_id,class_probability,observations"
    rows = (tmp_path / "o" / "associations.csv").read_text().splitlines()
    assert rows[0] == "pose_index,detection_index,landmark_id,weight"
    assert len(rows) - 1 == metrics["num_detections"]


@pytest.mark.parametrize("case", sorted(BAD_MESSAGES))
def test_bad_logs_exit_2_and_leave_earlier_outputs(tmp_path, capsys, earlier_run, case):
    out, before = earlier_run
    bad = write_raw(tmp_path / "bad.mcap", BAD_MESSAGES[case][0])
    status, _, err = run_cli(capsys, "replay", str(bad), "--method", "mm-nh", "--out", str(out))
    assert_one_line_error(status, err, str(bad), BAD_MESSAGES[case][1])
    assert snapshot(out) == before


def test_truncated_log_exits_2_and_leaves_earlier_outputs(tmp_path, capsys, earlier_run):
    out, before = earlier_run
    whole = write_raw(tmp_path / "whole.mcap", good_messages() * 10).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) * 2 // 3])
    status, _, err = run_cli(capsys, "replay", str(cut), "--method", "ml", "--out", str(out))
    assert_one_line_error(status, err, "truncated")
    assert snapshot(out) == before


def test_known_without_truth_ids_exits_2(tmp_path, capsys, earlier_run):
    out, before = earlier_run
    scene = Scene(square_loop(4.0, 1.0, 0.25), np.array([[3.0, 1.0, 0.0]]), np.array([0]))
    log = write_scene(tmp_path / "no-truth.mcap", scene, truth_ids=False)
    status, _, err = run_cli(capsys, "replay", str(log), "--method", "known", "--out", str(out))
    assert_one_line_error(status, err, "truth_landmark_id", "/detections message 0")
    assert snapshot(out) == before


@pytest.mark.parametrize(
    "content,needle",
    [
        (
            "[association]\nchi2_confidence = 1.5\n",
            "'association.chi2_confidence' must be in (0, 1)",
        ),
        ("[isam2]\nrelinearize_skip = 0\n", "'isam2.relinearize_skip' must be >= 1, got 0"),
        ("[association]\nnull_wieght = 0.2\n", "unknown key 'association.null_wieght'"),
        ("[isam2]\nrelinearize_skip = 'often'\n", "'isam2.relinearize_skip' must be int"),
        ("[association\n", "not valid TOML"),
    ],
)
def test_bad_config_exits_2(tmp_path, capsys, good_log, earlier_run, content, needle):
    out, before = earlier_run
    config = tmp_path / "bad.toml"
    config.write_text(content)
    status, _, err = run_cli(
        capsys,
        "replay",
        str(good_log),
        "--method",
        "ml",
        "--out",
        str(out),
        "--config",
        str(config),
    )
    assert_one_line_error(status, err, str(config), needle)
    assert snapshot(out) == before


def test_config_overrides_defaults(tmp_path, capsys, good_log):
    config = tmp_path / "strict.toml"
    config.write_text("[association]\nchi2_confidence = 0.5\n")
    loose, strict = tmp_path / "loose", tmp_path / "strict"
    assert main(["replay", str(good_log), "--method", "ml", "--out", str(loose), "--quiet"]) == 0
    assert (
        main(
            [
                "replay",
                str(good_log),
                "--method",
                "ml",
                "--out",
                str(strict),
                "--quiet",
                "--config",
                str(config),
            ]
        )
        == 0
    )
    count = lambda p: len((p / "landmarks.csv").read_text().splitlines())  # noqa: E731
    assert count(strict) > count(loose)  # a tighter gate starts more landmarks


def test_usage_errors_exit_2_with_one_line(capsys, good_log, tmp_path):
    for args in (
        ["replay", str(good_log), "--method", "bogus", "--out", str(tmp_path)],
        ["replay", str(good_log), "--method", "ml"],
        ["frobnicate"],
    ):
        with pytest.raises(SystemExit) as info:
            main(args)
        assert info.value.code == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "error:" in err


def test_out_that_is_a_file_exits_2(tmp_path, capsys, good_log):
    target = tmp_path / "file.txt"
    target.write_text("keep me")
    status, _, err = run_cli(
        capsys, "replay", str(good_log), "--method", "ml", "--out", str(target)
    )
    assert_one_line_error(status, err, "not a directory")
    assert target.read_text() == "keep me"


def test_inspect_reports_a_good_log(capsys, good_log):
    status, out, _ = run_cli(capsys, "inspect", str(good_log), "--json")
    assert status == 0
    report = json.loads(out)
    assert report["valid"] and report["poses"] == 21
    assert report["topics"]["/odometry"]["messages"] == 20
    assert sum(report["detections_by_class"].values()) == report["detections"]
    status, out, _ = run_cli(capsys, "inspect", str(good_log))
    assert status == 0 and "valid: yes" in out


def test_inspect_exits_2_on_the_first_problem(tmp_path, capsys):
    messages, expected = BAD_MESSAGES["class outside 0..C-1"]
    bad = write_raw(tmp_path / "bad.mcap", messages)
    status, out, err = run_cli(capsys, "inspect", str(bad), "--json")
    assert_one_line_error(status, err, expected)
    report = json.loads(out)
    assert report["valid"] is False and report["topics"]["/detections"]["messages"] == 2


def test_the_installed_command_prints_no_traceback(tmp_path):
    bad = write_raw(tmp_path / "bad.mcap", BAD_MESSAGES["NaN"][0])
    exe = os.path.join(os.path.dirname(sys.executable), "mmslam")
    proc = subprocess.run(
        [exe, "replay", str(bad), "--method", "ml", "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert not (tmp_path / "o").exists()


def test_a_closed_pipe_is_not_an_error(good_log, monkeypatch):
    """`mmslam inspect LOG | head`: the reader goes away before the report is written."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    closed = os.fdopen(write_end, "w", buffering=1)
    monkeypatch.setattr(sys, "stdout", closed)
    assert main(["inspect", str(good_log)]) == 0


def test_a_solver_failure_exits_1_with_one_line_and_leaves_earlier_outputs(
    tmp_path, capsys, good_log, earlier_run, monkeypatch
):
    """iSAM2 throwing on a graph it cannot solve is not bad input, but it gets one line too."""
    out, before = earlier_run
    unsolvable = gtsam.BetweenFactorPose3(
        gtsam.symbol("z", 1), gtsam.symbol("z", 2), gtsam.Pose3(), gtsam.noiseModel.Unit.Create(6)
    )
    original = Isam2Solver.update

    def update_with_a_free_pair(self):  # two poses tied only to each other: indeterminate
        if self.num_updates == 3:
            self.add(unsolvable)
            self.insert(gtsam.symbol("z", 1), gtsam.Pose3())
            self.insert(gtsam.symbol("z", 2), gtsam.Pose3())
        return original(self)

    monkeypatch.setattr(Isam2Solver, "update", update_with_a_free_pair)
    status, _, err = run_cli(capsys, "replay", str(good_log), "--method", "ml", "--out", str(out))
    assert status == 1
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "iSAM2 update 3 failed: Indeterminate linear system" in err
    assert snapshot(out) == before
