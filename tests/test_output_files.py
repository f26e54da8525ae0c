"""The output files read back against what was written (the formats of ../shared/CONTRACT.md:
a trajectory in evo's TUM format, the landmarks and associations as CSV), and an output folder
replaced as a set: the old set's other files kept, stale ones dropped, new files made as any
new file is, other targets' temporaries left alone, names that are not file names refused."""

from __future__ import annotations

import csv
import io
import os

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline import outputs
from pipeline.errors import InputError


def test_a_trajectory_reads_back_in_tum_order_to_the_nanometre():
    rng = np.random.default_rng(3)
    # integer nanoseconds since the epoch, as a log's stamps are: each written exactly
    stamps = 1_700_000_000_000_000_000 + np.cumsum(rng.integers(50_000_000, 200_000_000, 5))
    poses = []
    for _ in stamps:
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
        T[:3, 3] = rng.normal(size=3) * 100
        poses.append(T)
    rows = [line.split() for line in outputs.trajectory_tum(stamps, poses).splitlines()]
    assert len(rows) == len(poses)
    for row, stamp, T in zip(rows, stamps, poses, strict=True):
        seconds, fraction = row[0].split(".")
        assert int(seconds) * 10**9 + int(fraction.ljust(9, "0")) == stamp
        values = np.array([float(v) for v in row])
        np.testing.assert_allclose(values[1:4], T[:3, 3], atol=1e-8)
        q = values[4:]  # qx qy qz qw, as scipy gives them (up to sign)
        expected = Rotation.from_matrix(T[:3, :3]).as_quat()
        assert min(np.abs(q - expected).max(), np.abs(q + expected).max()) < 1e-8


def test_landmarks_and_associations_read_back_by_column():
    landmarks = outputs.landmarks_csv([(4, np.array([1.25, -2.5, 3.75]), 2, 0.8765432, 7)])
    (row,) = csv.DictReader(io.StringIO(landmarks))
    assert {k: float(v) for k, v in row.items()} == pytest.approx(
        {"id": 4, "x": 1.25, "y": -2.5, "z": 3.75, "class_id": 2, "class_probability": 0.876543,
         "observations": 7}
    )  # fmt: skip
    associations = outputs.associations_csv([(3, 1, -1, 0.123456789), (3, 2, 5, 0.5)])
    rows = list(csv.DictReader(io.StringIO(associations)))
    assert [(r["pose_index"], r["detection_index"], r["landmark_id"]) for r in rows] == [
        ("3", "1", "-1"),
        ("3", "2", "5"),
    ]
    assert float(rows[0]["weight"]) == pytest.approx(0.123457, abs=1e-9)


def test_a_folder_is_replaced_as_a_set(tmp_path):
    out = tmp_path / "out"
    outputs.write_outputs(out, {"a.csv": "old a\n", "b.csv": "old b\n", "notes.txt": "mine\n"})
    outputs.write_outputs(out, {"a.csv": "new a\n"}, stale=["b.csv"])
    assert sorted(os.listdir(out)) == ["a.csv", "notes.txt"]  # b stale, notes carried over
    assert (out / "a.csv").read_text() == "new a\n"
    assert (out / "notes.txt").read_text() == "mine\n"
    umask = os.umask(0)
    os.umask(umask)
    assert (out / "a.csv").stat().st_mode & 0o777 == 0o666 & ~umask
    with pytest.raises(ValueError, match="not a file name"):
        outputs.write_outputs(out, {"sub/a.csv": "x"})
    assert sorted(os.listdir(out)) == ["a.csv", "notes.txt"]  # nothing changed
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="exists and is not a directory"):
        outputs.write_outputs(tmp_path / "file", {"a.csv": "x"})


def test_a_file_is_made_as_any_new_file_and_others_temporaries_stay(tmp_path):
    others = [tmp_path / ".b.txt.x1.part", tmp_path / ".ab.txt.x2.part"]
    for path in others:
        path.write_text("another target's writer")
    dead = tmp_path / ".a.txt.x3.part"
    dead.write_text("a dead writer of a.txt")
    outputs.write_text(tmp_path / "a.txt", "hello")
    assert (tmp_path / "a.txt").read_text() == "hello"
    assert not dead.exists()
    assert all(path.exists() for path in others)
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o666 & ~umask
