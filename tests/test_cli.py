"""The command line: exit status 2 with one line on bad input, nothing written lost."""

import datetime
import hashlib
import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest

import pipeline
from pipeline.backend.solver import Isam2Solver
from pipeline.cli import COMMAND_EXAMPLES, builtin_sweeps, main, sweep_config
from pipeline.settings import config_path
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


@pytest.mark.e2e
def test_replay_writes_the_contract_outputs(tmp_path, good_log, capsys):
    status, out, _ = run_cli(
        capsys, "replay", str(good_log), "--method", "ml", "--out", str(tmp_path / "o")
    )
    assert status == 0 and "ml:" in out
    names = sorted(p.name for p in (tmp_path / "o").iterdir())
    assert names == [
        "associations.csv",
        "landmarks.csv",
        "metrics.json",
        "run.json",
        "trajectory.tum",
    ]
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


@pytest.mark.e2e
@pytest.mark.parametrize("case", sorted(BAD_MESSAGES))
def test_bad_logs_exit_2_and_leave_earlier_outputs(tmp_path, capsys, earlier_run, case):
    out, before = earlier_run
    bad = write_raw(tmp_path / "bad.mcap", BAD_MESSAGES[case][0])
    status, _, err = run_cli(capsys, "replay", str(bad), "--method", "mm-nh", "--out", str(out))
    assert_one_line_error(status, err, str(bad), BAD_MESSAGES[case][1])
    assert snapshot(out) == before


@pytest.mark.e2e
def test_truncated_log_exits_2_and_leaves_earlier_outputs(tmp_path, capsys, earlier_run):
    out, before = earlier_run
    whole = write_raw(tmp_path / "whole.mcap", good_messages() * 10).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) * 2 // 3])
    status, _, err = run_cli(capsys, "replay", str(cut), "--method", "ml", "--out", str(out))
    assert_one_line_error(status, err, "truncated")
    assert snapshot(out) == before


@pytest.mark.e2e
def test_known_without_truth_ids_exits_2(tmp_path, capsys, earlier_run):
    out, before = earlier_run
    scene = Scene(square_loop(4.0, 1.0, 0.25), np.array([[3.0, 1.0, 0.0]]), np.array([0]))
    log = write_scene(tmp_path / "no-truth.mcap", scene, truth_ids=False)
    status, _, err = run_cli(capsys, "replay", str(log), "--method", "known", "--out", str(out))
    assert_one_line_error(status, err, "truth_landmark_id", "/detections message 0")
    assert snapshot(out) == before


@pytest.mark.e2e
@pytest.mark.parametrize(
    "content,needle",
    [
        (
            "[association]\nchi2_confidence = 1.5\n",
            "'association.chi2_confidence' must be in (0, 1)",
        ),
        ("[isam2]\nrelinearize_skip = 0\n", "'isam2.relinearize_skip' must be in [1, 1e6], got 0"),
        # hostile values (issue 39): GTSAM's C int overflowed, and a deque's length
        (
            "[isam2]\nrelinearize_skip = 4294967297\n",
            "'isam2.relinearize_skip' must be in [1, 1e6], got 4294967297",
        ),
        (
            "[noise]\ncontrasts = 99999999999999999999\n",
            "'noise.contrasts' must be in [1, 1e6], got 99999999999999999999",
        ),
        ("[noise]\ncontrasts = 2.5\n", "'noise.contrasts' must be int, got 2.5"),
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


@pytest.mark.parametrize(
    "content,needle",
    [
        (
            "[route]\nlength_m = 1e12\n",
            "'route.length_m' must be in (0, 100000], got 1000000000000.0",
        ),
        ("[route]\nspeed_mps = 0\n", "'route.speed_mps' must be in (0, 100], got 0"),
        ("[route]\nkeyframe_period_s = -1.0\n", "'route.keyframe_period_s' must be in (0, 3600]"),
        ("[route]\nspeed_mps = 1e-9\n", "must be <= 1000000 keyframes, got 1.08e+12"),
        ("[tags]\ncount = 1e3\n", "'tags.count' must be int, got 1000.0"),
        ("[odometry]\nadded_sigma_x_m = nan\n", "'odometry.added_sigma_x_m' must be finite"),
        (
            "[floor]\ncorridor_x_m = [0.0, 1e300]\n",
            "'floor.corridor_x_m[1]' must be in [-100000, 100000]",
        ),
    ],
)
def test_hostile_scenario_values_exit_2_and_keep_the_old_log(tmp_path, capsys, content, needle):
    """The issue's `simulate` with `[route] length_m = 1e12` ran unbounded, and "route values
    > 0" named neither key nor value."""
    out = tmp_path / "old.mcap"
    out.write_bytes(b"an earlier log")
    config = tmp_path / "hostile.toml"
    config.write_text(content)
    status, _, err = run_cli(
        capsys, "simulate", "indoor-tags", "--out", str(out), "--config", str(config)
    )
    assert_one_line_error(status, err, str(config), needle)
    assert out.read_bytes() == b"an earlier log"


@pytest.mark.e2e
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


@pytest.mark.e2e
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


# --- how a run was made, and the command line around the commands ---------------------------


@pytest.mark.e2e
def test_run_json_says_how_the_outputs_were_made(tmp_path, good_log, capsys):
    args = ["replay", str(good_log), "--method", "mm", "--out", str(tmp_path / "o"), "-q"]
    status, _, _ = run_cli(capsys, *args)
    assert status == 0
    record = json.loads((tmp_path / "o" / "run.json").read_text())
    assert record["mmslam_version"] == pipeline.__version__
    assert set(record["libraries"]) == {"gtsam", "numpy", "opencv", "rerun-sdk", "mcap"}
    assert "git_commit" in record and "git_dirty" in record
    assert record["command"] == ["mmslam", *args]
    assert record["config"]["method"] == "mm"
    assert record["config"]["backend"]["association"]["chi2_confidence"] == 0.9
    (log_input,) = record["inputs"]
    data = good_log.read_bytes()
    assert log_input["sha256"] == hashlib.sha256(data).hexdigest()
    assert log_input["size_bytes"] == len(data)
    started = datetime.datetime.fromisoformat(record["started_utc"])
    assert abs((datetime.datetime.now(datetime.UTC) - started).total_seconds()) < 600
    assert record["wall_s"] > 0


def test_version(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    first, second = capsys.readouterr().out.splitlines()
    assert first.startswith(f"mmslam {pipeline.__version__}")
    assert second.startswith("python ") and " gtsam " in second


@pytest.mark.parametrize("command", sorted(COMMAND_EXAMPLES))
def test_every_command_shows_examples(capsys, command):
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    assert f"examples:\n  mmslam {command} " in capsys.readouterr().out


@pytest.mark.e2e
@pytest.mark.parametrize("where", ["before", "after"])
def test_verbosity_goes_anywhere_and_leaves_third_party_logs_quiet(
    tmp_path, good_log, capsys, where
):
    replay = ["replay", str(good_log), "--method", "ml", "--out", str(tmp_path / "o")]
    assert main(["-v", *replay] if where == "before" else [*replay, "-v"]) == 0
    assert logging.getLogger("pipeline.replay").isEnabledFor(logging.DEBUG)
    assert not logging.getLogger("evo").isEnabledFor(logging.INFO)
    assert not logging.getLogger("matplotlib").isEnabledFor(logging.INFO)
    capsys.readouterr()
    assert main(["-q", *replay] if where == "before" else [*replay, "-q"]) == 0
    assert not logging.getLogger("pipeline.replay").isEnabledFor(logging.WARNING)
    assert "poses" not in capsys.readouterr().err  # no progress either


@pytest.mark.parametrize(
    "args,needle",
    [
        (["simulate", "indoor-tags", "--misclassification", "1.5"], "within 0..1, got 1.5"),
        (["simulate", "indoor-tags", "--odom-noise-scale", "-2"], ">= 0, got -2"),
        (["simulate", "indoor-tags", "--seed", "-1"], ">= 0, got -1"),
        (["simulate", "indoor-tags", "--num-classes", "0"], ">= 1, got 0"),
        (["simulate", "indoor-tags", "--odom-noise-scale", "nan"], "finite"),
        (["sweep", "small", "--workers", "0"], ">= 1, got 0"),
    ],
)
def test_ranges_in_the_help_are_enforced(tmp_path, capsys, args, needle):
    with pytest.raises(SystemExit) as info:
        main([*args, "--out", str(tmp_path / "x")])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("args", [["--version"], ["--help"], ["sweep", "--help"]])
def test_version_and_help_into_a_closed_pipe_say_nothing(args):
    """`mmslam --version | true`: the reader is gone before anything is written."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    exe = os.path.join(os.path.dirname(sys.executable), "mmslam")
    try:
        proc = subprocess.run([exe, *args], stdout=write_end, stderr=subprocess.PIPE, text=True)
    finally:
        os.close(write_end)
    assert (proc.returncode, proc.stderr) == (0, "")


def test_quiet_commands_print_nothing(tmp_path, capsys, good_log):
    """-q is errors only: no result lines on stdout, nothing on stderr."""
    small = config_path("scenarios/small-indoor-tags.toml")
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(
        f'scenario = "indoor-tags"\nscenario_config = "{small}"\nseeds = 1\n'
        'methods = ["known"]\nodom_noise_scale = 1.0\nmisclassification = 0.0\n'
    )
    commands = [
        ["simulate", "indoor-tags", "--out", str(tmp_path / "t.mcap"), "--config", str(small)],
        ["replay", str(good_log), "--method", "ml", "--out", str(tmp_path / "r")],
        ["compare", str(good_log), "--methods", "known,ml", "--out", str(tmp_path / "c")],
        ["export", str(good_log), "--ground-truth", str(tmp_path / "gt.tum")],
        ["sweep", str(sweep), "--out", str(tmp_path / "s"), "--workers", "1"],
    ]
    for command in commands:
        assert main([*command, "-q"]) == 0, command
        assert capsys.readouterr() == ("", ""), command
    assert main(["replay", str(good_log), "--method", "ml", "--out", str(tmp_path / "r")]) == 0
    assert "ml:" in capsys.readouterr().out  # without -q, the result line


def test_sweep_help_lists_only_sweeps(capsys):
    from data_tools.sweep.config import load_sweep_config

    with pytest.raises(SystemExit):
        main(["sweep", "--help"])
    listed = capsys.readouterr().out.split("built-in sweep:")[1].split("\n\n")[0]
    names = builtin_sweeps()
    assert "".join(listed.split()) == ",".join(names)  # argparse wraps lines at hyphens
    assert "small" in names and "kitti05" in names
    for name in names:  # a scenario's or a back-end's file among them is no sweep
        load_sweep_config(config_path(f"sweeps/{name}.toml"))


def test_sweeps_by_name(tmp_path, capsys):
    assert sweep_config("small") == config_path("sweeps/small.toml")
    assert "small" in builtin_sweeps() and "kitti05" in builtin_sweeps()
    assert sweep_config("my/own.toml") == Path("my/own.toml")
    status, _, err = run_cli(capsys, "sweep", "smal", "--out", str(tmp_path / "s"))
    assert_one_line_error(status, err, "no built-in sweep", "small")


@pytest.mark.e2e
def test_export_gives_evo_the_ground_truth_and_evo_agrees_with_the_metrics(
    tmp_path, good_log, capsys
):
    from evo.core import metrics, sync
    from evo.tools import file_interface

    run = tmp_path / "run"
    assert main(["replay", str(good_log), "--method", "mm-nh", "--out", str(run), "-q"]) == 0
    gt, landmarks = tmp_path / "gt.tum", tmp_path / "gt.csv"
    status, out, _ = run_cli(
        capsys, "export", str(good_log), "--ground-truth", str(gt), "--landmarks", str(landmarks)
    )
    assert status == 0 and f"wrote {gt}" in out
    reference = file_interface.read_tum_trajectory_file(str(gt))
    estimate = file_interface.read_tum_trajectory_file(str(run / "trajectory.tum"))
    reference, estimate = sync.associate_trajectories(reference, estimate)
    estimate.align_origin(reference)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((reference, estimate))
    ours = json.loads((run / "metrics.json").read_text())["translation_error_m"]
    assert ape.get_statistic(metrics.StatisticsType.rmse) == pytest.approx(ours["rmse"], abs=1e-6)
    assert ape.get_statistic(metrics.StatisticsType.max) == pytest.approx(ours["max"], abs=1e-6)
    rows = landmarks.read_text().splitlines()
    assert rows[0] == "id,x,y,z,class_id"
    assert rows[1:] == ["0,5.000000,3.000000,0.000000,0", "1,9.000000,-3.000000,0.000000,1",
                        "2,3.000000,9.000000,0.000000,0"]  # fmt: skip


@pytest.mark.e2e
def test_tum_files_keep_every_nanosecond_of_an_epoch_stamp(tmp_path, capsys):
    # A EuRoC stamp: as a float in seconds it would be written 1403636579.763555527.
    start = 1403636579763555584
    scene = Scene(square_loop(6.0, 1.0, laps=0.25), np.array([[3.0, 2.0, 0.0]]), np.array([0]))
    log = write_scene(tmp_path / "epoch.mcap", scene, start_ns=start)
    assert main(["replay", str(log), "--method", "known", "--out", str(tmp_path / "r")]) == 0
    assert main(["export", str(log), "--ground-truth", str(tmp_path / "gt.tum")]) == 0
    for path in (tmp_path / "r" / "trajectory.tum", tmp_path / "gt.tum"):
        stamps = [line.split()[0] for line in path.read_text().splitlines()]
        assert stamps[:2] == ["1403636579.763555584", "1403636579.863555584"], path


def test_export_without_ground_truth_exits_2_and_writes_nothing(tmp_path, capsys):
    scene = Scene(square_loop(4.0, 1.0, 0.25), np.array([[3.0, 1.0, 0.0]]), np.array([0]))
    log = write_scene(tmp_path / "no-truth.mcap", scene, ground_truth=False)
    gt = tmp_path / "gt.tum"
    status, _, err = run_cli(capsys, "export", str(log), "--ground-truth", str(gt))
    assert_one_line_error(status, err, "no /ground_truth/pose")
    assert not gt.exists()
    status, _, err = run_cli(capsys, "export", str(log))
    assert_one_line_error(status, err, "nothing to export")


@pytest.mark.e2e
def test_plot_labels_its_axes_in_metres(tmp_path, good_log, capsys):
    from data_tools.plot_runs import figure

    run = tmp_path / "run"
    assert main(["replay", str(good_log), "--method", "ml", "--out", str(run), "-q"]) == 0
    fig = figure(good_log, [run])
    assert [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes] == [("x (m)", "y (m)")]
    out = tmp_path / "plot.png"
    status, _, _ = run_cli(capsys, "plot", str(good_log), str(run), "--out", str(out))
    assert status == 0 and out.read_bytes().startswith(b"\x89PNG")
    status, _, err = run_cli(capsys, "plot", str(good_log), str(run), "--out", str(out) + ".xyz")
    assert_one_line_error(status, err, "not an image format")
    status, _, err = run_cli(capsys, "plot", str(good_log), str(tmp_path), "--out", str(out))
    assert_one_line_error(status, err, "metrics.json")


def test_the_choices_are_the_registries():
    """One registry each: the command line offers the scenarios and methods that
    data_tools.scenarios and pipeline.backend.methods name, no copy of them."""
    from data_tools.scenarios import SCENARIOS
    from pipeline.arguments import method_list
    from pipeline.backend.methods import METHODS
    from pipeline.cli import build_parser

    commands = next(a for a in build_parser()._actions if a.dest == "command").choices

    def choices(command: str, dest: str) -> tuple[str, ...]:
        action = next(a for a in commands[command]._actions if a.dest == dest)
        return tuple(action.choices)

    assert choices("simulate", "scenario") == SCENARIOS
    assert choices("replay", "method") == METHODS
    assert method_list(",".join(METHODS)) == list(METHODS)  # compare's and the tools' --methods


def test_help_imports_neither_the_scenarios_nor_the_methods():
    """`mmslam --help` stays fast: building the parser reads no registry's heavy module."""
    code = (
        "import sys; from pipeline.cli import build_parser; build_parser(); "
        "heavy = [m for m in ('data_tools.scenarios', 'gtsam', 'numpy') if m in sys.modules]; "
        "print(heavy)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
