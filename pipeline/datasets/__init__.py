"""Readers of stereo sequences, one module per layout; `layouts.open_sequence` chooses one."""

# What each layout holds, and a command that reads one: `mmslam frontend --help` shows them.
LAYOUTS = (
    (
        "KITTI odometry",
        "image_0/ image_1/ (or image_2/ image_3/), calib.txt, times.txt[, poses.txt]",
        "mmslam frontend ../shared/data/real/kitti-clip-1 --out out/clip.mcap",
    ),
    (
        "plain (mmslam's own)",
        "calibration.toml, left/, right/[, times.txt, poses.txt]",
        "mmslam frontend out/seq --out out/seq.mcap",
    ),
    (
        "EuRoC / ASL",
        "mav0/cam0/data.csv, cam0/data/*.png, cam0/sensor.yaml, the same for cam1/",
        "mmslam frontend MH_01_easy --out out/mh01.mcap",
    ),
    (
        "ROS 2 bag",
        "a bag folder (metadata.yaml; MCAP or sqlite3) or one .mcap or .db3 file",
        "mmslam frontend my_bag --out out/bag.mcap --left-topic /cam/left/image_raw "
        "--right-topic /cam/right/image_raw",
    ),
)
