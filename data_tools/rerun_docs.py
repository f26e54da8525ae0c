"""`make docs`: the README's and docs' Rerun pictures, made again from the current code.

Runs the logs and replays the pictures show (images to map on `make demo`'s rendered drive,
the README's indoor session, a KITTI-05-length log), checks every recording with `rerun rrd
verify`, takes the screenshots headless (`data_tools/screenshots.py`: Xvfb, software Vulkan,
the Rerun viewer) at each run's last pose (the demo's: the keyframe with the most boxes), and
writes `docs/rerun/README.md`: the commit they were made at, the commands, the recordings'
sizes, what each picture shows.

Usage: python -m data_tools.rerun_docs [--out docs/rerun] [--work out/docs]
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger("mmslam.rerun_docs")

REPO = Path(__file__).resolve().parents[1]
# The README's session: the paper's indoor run, noisy odometry, misclassified tags.
INDOOR = ["indoor-tags", "--seed", "2", "--odom-noise-scale", "4", "--misclassification", "0.1",
          "--true-covariance"]  # fmt: skip
# KITTI 05's path at three times the paper's odometry noise: where maximum likelihood breaks.
KITTI = ["kitti05-cars", "--seed", "1", "--odom-noise-scale", "3"]
COLOURS = 256  # the pictures are reduced to this many colours: a tenth of the bytes


@dataclass(frozen=True)
class Picture:
    name: str  # file name in the output folder
    recording: str  # its recording, in the work folder
    maximised: str | None  # a view shown alone, or the whole layout
    says: str  # what it shows, for docs/rerun/README.md


PICTURES = [
    Picture("demo-mm-nh.png", "demo-mm-nh.rrd", None,
            "Images to map: make demo's rendered drive through the front-end (visual "
            "odometry, AprilTags, yolov3-tiny boxes with stereo range) and mm-nh, at the "
            "keyframe with the most boxes: each box over the camera image with its class, "
            "score, range and the landmark it went to; the tags and cars in the map."),
    Picture("indoor-mm-nh.png", "indoor-mm-nh.rrd", None,
            "The indoor run with mm-nh at its last pose: the whole layout."),
    Picture("indoor-ml.png", "indoor-ml.rrd", None,
            "The same log with maximum likelihood: its wrong associations in red in the map, "
            "counted in the plot beside the error."),
    Picture("indoor-ml-map.png", "indoor-ml.rrd", "Map",
            "The ML run's map maximised: the legend is in the map, so it stays."),
    Picture("kitti05-mm-nh.png", "kitti05-mm-nh.rrd", None,
            "A KITTI-05-length run (mmslam simulate kitti05-cars, odometry noise x3), mm-nh: "
            "the plots over the whole run of 2,761 poses."),
    Picture("kitti05-compare.png", "kitti05-compare.rrd", None,
            "mmslam compare on that log, known, ml and mm-nh: the maps side by side with one "
            "legend, a line a method in each plot, the table of results."),
]  # fmt: skip


def _mmslam(*args: str) -> None:
    command = [sys.executable, "-m", "pipeline.cli", "-q", *args]
    log.info("$ mmslam %s", " ".join(args))
    subprocess.run(command, check=True, cwd=REPO)


def _commit() -> str:
    """The commit the pictures are made at, and whether the tree had changes."""

    def git(*args: str) -> str:
        done = subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True)
        done.check_returncode()
        return done.stdout.strip()

    try:
        head = git("rev-parse", "HEAD")
        changes = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return head + (" with uncommitted changes" if changes else "")


def make_runs(work: Path) -> dict[str, list[str]]:
    """The logs and recordings the pictures show; the commands that made them."""
    from data_tools.render import render_sequence

    work.mkdir(parents=True, exist_ok=True)
    indoor, kitti = str(work / "indoor.mcap"), str(work / "kitti05.mcap")
    sequence, demo = work / "sequence", str(work / "demo.mcap")
    if not (sequence / "render.json").exists():
        log.info("rendering the demo sequence into %s", sequence)
        render_sequence("demo", sequence)
    commands = {
        "images to a log": ["frontend", str(sequence), "--out", demo, "--images"],
        "images to map": ["replay", demo, "--method", "mm-nh", "--out",
                          str(work / "demo-mm-nh"), "--rrd", str(work / "demo-mm-nh.rrd")],
        "indoor log": ["simulate", *INDOOR[:1], "--out", indoor, *INDOOR[1:]],
        "indoor mm-nh": ["replay", indoor, "--method", "mm-nh", "--out",
                         str(work / "indoor-mm-nh"), "--rrd", str(work / "indoor-mm-nh.rrd")],
        "indoor ml": ["replay", indoor, "--method", "ml", "--out", str(work / "indoor-ml"),
                      "--rrd", str(work / "indoor-ml.rrd")],
        "KITTI-05-length log": ["simulate", *KITTI[:1], "--out", kitti, *KITTI[1:]],
        "KITTI-05-length mm-nh": ["replay", kitti, "--method", "mm-nh", "--out",
                                  str(work / "kitti05-mm-nh"), "--rrd",
                                  str(work / "kitti05-mm-nh.rrd")],
        "KITTI-05-length comparison": ["compare", kitti, "--methods", "known,ml,mm-nh",
                                       "--out", str(work / "kitti05-runs"), "--rrd",
                                       str(work / "kitti05-compare.rrd"), "--workers", "2"],
    }  # fmt: skip
    for args in commands.values():
        _mmslam(*args)
    made = {name: ["mmslam", *args] for name, args in commands.items()}
    (work / "commands.json").write_text(json.dumps(made, indent=1))
    return made


def verify(recordings: list[Path]) -> None:
    from pipeline.viz.stream import rerun_executable

    executable = rerun_executable()
    if executable is None:
        raise SystemExit("make docs: no `rerun` executable to verify the recordings with")
    subprocess.run([executable, "rrd", "verify", *map(str, recordings)], check=True)


def last_pose(recording: Path) -> int:
    """The last pose a recording reaches."""
    import rerun.chunk as rerun_chunk

    last = 0
    for chunk in rerun_chunk.RrdReader(recording).stream():
        batch = chunk.to_record_batch()
        if "pose" in batch.schema.names:
            poses = [p for p in batch.column("pose").to_pylist() if p is not None]
            last = max([last, *poses])
    return last


def most_boxes_pose(log_path: Path) -> int:
    """The pose whose keyframe has the most box detections (the first of them)."""
    from pipeline.log import read_log

    counts = [
        (sum(d.source == "bbox" for d in m.detections), -m.pose_index)
        for m in read_log(log_path).detections
    ]
    return -max(counts)[1]


def reduce_colours(path: Path) -> None:
    from PIL import Image

    with Image.open(path) as image:
        reduced = image.convert("RGB").quantize(COLOURS, dither=Image.Dither.NONE)
    reduced.save(path, optimize=True)


def write_readme(out: Path, work: Path, commands: dict[str, list[str]], commit: str) -> None:
    import rerun

    def relative(word: str) -> str:
        return word.replace(str(work), "out/docs")

    sizes = sorted({p.recording for p in PICTURES})
    lines = [
        "# The Rerun pictures",
        "",
        "Made by `make docs` (`python -m data_tools.rerun_docs`): do not edit, run it again.",
        "",
        f"- commit: {commit}",
        f"- Rerun {rerun.__version__}, the viewer at 1600×1000 on Mesa's software Vulkan under "
        "Xvfb; every picture at its recording's last pose (the demo's: the keyframe with the most "
        "boxes), reduced to 256 colours",
        f"- made: {datetime.date.today().isoformat()}",
        "",
        "The demo's sequence: `python -m data_tools.render demo --out out/docs/sequence` "
        "(as `make demo` renders it).",
        "",
        "| picture | what it shows |",
        "|---|---|",
        *[f"| [{p.name}]({p.name}) | {p.says} |" for p in PICTURES],
        "",
        "Recordings (each passes `rerun rrd verify`):",
        "",
        "| recording | size (MB) |",
        "|---|---|",
        *[f"| `{name}` | {(work / name).stat().st_size / 1e6:.1f} |" for name in sizes],
        "",
        "Commands:",
        "",
        "```sh",
        *[" ".join(relative(w) for w in command) for command in commands.values()],
        "```",
        "",
    ]
    (out / "README.md").write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "rerun")
    parser.add_argument("--work", type=Path, default=REPO / "out" / "docs")
    parser.add_argument(
        "--pictures-only", action="store_true", help="use the recordings already in --work"
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")

    from data_tools.screenshots import ScreenshotError, Shot, required_programs, take

    missing = required_programs()
    if missing:
        packages = "xvfb mesa-vulkan-drivers libgl1-mesa-dri libegl1 libvulkan1"
        print(f"make docs: {', '.join(missing)} not found; on Debian: apt-get install {packages}",
              file=sys.stderr)  # fmt: skip
        return 2
    commit = _commit()
    if args.pictures_only:
        commands = json.loads((args.work / "commands.json").read_text())
    else:
        commands = make_runs(args.work)
    recordings = sorted({args.work / p.recording for p in PICTURES})
    verify(recordings)
    args.out.mkdir(parents=True, exist_ok=True)
    try:
        for recording in recordings:
            demo = recording.name.startswith("demo")
            pose = most_boxes_pose(args.work / "demo.mcap") if demo else last_pose(recording)
            shots = [
                Shot(args.out / p.name, pose, p.maximised)
                for p in PICTURES
                if args.work / p.recording == recording
            ]
            take(recording, shots)
    except ScreenshotError as exc:
        print(f"make docs: {exc}", file=sys.stderr)
        return 1
    for picture in PICTURES:
        reduce_colours(args.out / picture.name)
    write_readme(args.out, args.work, commands, commit)
    log.info("wrote %s at %s", args.out, commit)
    return 0


if __name__ == "__main__":
    sys.exit(main())
