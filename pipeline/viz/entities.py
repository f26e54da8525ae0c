"""The entity paths of an mmslam recording: the sink writes them, the blueprint lays them out,
and the tests read them back. World frame Z-up (REP-103: x forward, y left, z up)."""

from __future__ import annotations

WORLD = "/world"
# The newest pose (Transform3D + axes); its children are in the body frame.
ROBOT = "/world/robot"
ROBOT_DETECTIONS = "/world/robot/detections"  # front-end: a keyframe's detections, body frame
ROBOT_MARKER = "/world/robot/marker"  # a dot at the pose, a fixed size on screen
ROBOT_HEADING = "/world/robot/heading"  # an arrow along the body's x axis

TRAJECTORY = "/world/trajectory/estimate"  # all poses as of the last refresh
TRAJECTORY_RECENT = "/world/trajectory/recent"  # the poses since then, every keyframe
GROUND_TRUTH_TRAJECTORY = "/world/trajectory/ground_truth"  # aligned at pose 0
ODOMETRY_TRAJECTORY = "/world/trajectory/odometry"  # dead reckoning from pose 0
GROUND_TRUTH_LANDMARKS = "/world/ground_truth/landmarks"

# One child a landmark, /world/landmarks/<id>: its point (coloured and labelled by MAP class).
LANDMARKS = "/world/landmarks"
# Every landmark's uncertainty ellipsoid, re-logged at every refresh and at the end: hidden in
# the default layout (hundreds of them hide the map); those of the landmarks a keyframe weighs
# are drawn with CANDIDATES.
UNCERTAINTY = "/world/uncertainty"

# This keyframe's detections: a line from the pose to every landmark each may be (and to its
# measured point for the null hypothesis), and the measured points themselves.
HYPOTHESES = "/world/associations/hypotheses"
# The landmarks they weighed: labelled (id, MAP class, its probability), with their ellipsoids
CANDIDATES = "/world/associations/candidates"
NULL_WINS = "/world/associations/null"  # detections the null hypothesis took this keyframe
SWITCHES = "/world/associations/switches"  # earlier detections whose landmark changed now
REJECTED = "/world/associations/rejected"  # at the end: every detection left to the null
# Where the log names each detection's true landmark: every detection whose landmark stands
# for another one now (`correctness.py`), a line from its pose to that landmark; re-logged at
# every refresh and at the end.
WRONG = "/world/associations/wrong"

# Decisions where and when they happened, each logged once at its pose and shown from pose 0 to
# the time cursor (the map view's time range for these entities): null-hypothesis decisions at
# the point the detection measured, merges as a line from the duplicate to the survivor.
NULL_DECISIONS = "/world/history/null_decisions"
MERGES = "/world/history/merges"
HISTORY = (NULL_DECISIONS, MERGES)

CAMERA = "/camera/left"
CAMERA_DETECTIONS = "/camera/left/detections"  # boxes, labelled with class and association
CAMERA_TAGS = "/camera/left/tags"  # tag outlines (front-end)

EVENTS = "/events"  # text: null-hypothesis wins and association switches
SUMMARY = "/summary"  # text: the run's counts as it goes, and its metrics at the end

# Swatches naming the map's colours, on a board below the map (static; `legend.py`)
LEGEND = "/world/legend"
LEGEND_MARKS = "/world/legend/marks"
LEGEND_LINES = "/world/legend/lines"

METRICS = "/metrics"
ERROR_ONLINE = "/metrics/translation_error/online"  # newest pose when it was added
ERROR_FINAL = "/metrics/translation_error/final"  # every pose in the final estimate
LANDMARK_COUNT = "/metrics/counts/landmarks"
SWITCH_COUNT = "/metrics/counts/switches"  # cumulative
MERGE_COUNT = "/metrics/counts/merges"  # cumulative
WRONG_COUNT = "/metrics/associations/wrong"  # detections so far whose association is wrong now
NULL_RATE = "/metrics/null_rate"  # detections associated to the null hypothesis, so far
STEP_MS = "/metrics/time/backend_ms"  # trailing median of the per-keyframe times
NOISE = "/metrics/noise"  # log10 of each noise scale in use: NOISE/odometry/yaw, ...
VIZ_MS = "/metrics/time/viz_ms"

# The front-end's own series
VO_TRAJECTORY = "/world/trajectory/visual_odometry"
VO_TRAJECTORY_RECENT = "/world/trajectory/visual_odometry_recent"
VO_INLIERS = "/metrics/frontend/vo_inliers"
TAG_COUNT = "/metrics/frontend/tags"
BOX_COUNT = "/metrics/frontend/boxes"

# Timelines
POSE_TIMELINE = "pose"
TIME_TIMELINE = "log_time"


def landmark_path(landmark_id: int) -> str:
    return f"{LANDMARKS}/{landmark_id}"
