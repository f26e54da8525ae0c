"""`make demo`'s own reporting: what its boxes became, and how to open the recording here."""

from __future__ import annotations

import numpy as np

from data_tools.demo import box_landmarks, viewer_command
from pipeline.cli import main
from tests.synthetic import Scene, square_loop, write_scene


def test_box_detections_are_traced_to_the_landmarks_they_made(tmp_path):
    # Every synthetic detection is a box naming its true landmark; known makes one landmark
    # of each object seen.
    landmarks = np.array([[5.0, 3.0, 0.0], [9.0, -3.0, 0.0], [3.0, 9.0, 0.0]])
    scene = Scene(square_loop(10.0, 1.0, laps=0.5), landmarks, np.array([0, 1, 0]))
    log = write_scene(tmp_path / "boxes.mcap", scene, seed=1)
    run = tmp_path / "known"
    assert main(["replay", str(log), "--method", "known", "--out", str(run), "-q"]) == 0
    detections = sum(1 for _ in scene.visible())
    seen = len({j for _, j in scene.visible()})
    assert box_landmarks(log, run) == (
        f"images -> map: {detections} box detections ({detections} on {seen} objects of the "
        f"log's ground truth, 0 on none) became {seen} landmarks in {run} "
        f"(2 class0, 1 class1)"
    )


def test_without_a_display_the_web_viewer_is_offered(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert "rerun --web-viewer out/x.rrd" in viewer_command("out/x.rrd")
    monkeypatch.setenv("DISPLAY", ":0")
    assert viewer_command("out/x.rrd") == "Open the recording with: .venv/bin/rerun out/x.rrd"
