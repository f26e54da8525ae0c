"""Data that mmslam ships as package data, so that every install has it (see each folder's
README for its source and licence)."""

from pathlib import Path

# KITTI odometry sequence 05's ground truth: poses.txt and times.txt (CC BY-NC-SA 3.0).
KITTI05_DIR = Path(__file__).resolve().parent / "kitti-odometry-05"
