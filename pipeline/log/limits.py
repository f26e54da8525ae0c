"""The bounds a contract-v1 log must keep, beyond the contract's own rules, in one table.

Each is wide enough for any real log (simulated, KITTI, the front-end's) and tight enough that
nothing past it can overflow, exhaust memory or break the back-end's numerics. The messages'
declarations (`messages.py`) hold their fields to these; the reader names the bound a log
breaks.
"""

from __future__ import annotations

# --- the MCAP container -----------------------------------------------------------------------
# One MCAP record (a chunk, as stored) at most: larger lengths are corruption, not data.
MAX_RECORD_BYTES = 256 * 2**20
# A chunk's uncompressed size at most (our writer makes 1 MiB chunks; one image can be more).
MAX_CHUNK_BYTES = 128 * 2**20
# Everything decompressed from a file at most: this floor plus this many times the file's size.
# Real logs inflate 3-5x (JSON of floats); a decompression bomb inflates thousands of times.
INFLATION_FLOOR_BYTES = 16 * 2**20
MAX_INFLATION = 100
# One message at most, before its JSON is parsed (images carry base64 data, so they may be more).
MAX_JSON_MESSAGE_BYTES = 16 * 2**20
MAX_IMAGE_MESSAGE_BYTES = 64 * 2**20

# --- integers ---------------------------------------------------------------------------------
# stamp_ns: int64 nanoseconds. MCAP allows uint64, but numpy's, evo's and Rerun's times are int64.
MAX_STAMP_NS = 2**63 - 1
# Poses in a log (pose indices 0 .. MAX_POSES - 1): 115 days of keyframes at 1 Hz.
MAX_POSES = 10_000_000
# Detections of one pose, summed over its /detections messages. An object detector keeps a
# few hundred boxes at most, a tag detector a few dozen; a keyframe of thousands would make the
# association's joint test and the merge checks cost minutes (mm-nh, 25,000 clutter
# detections at one keyframe of indoor-tags: over 15 min).
MAX_DETECTIONS_PER_POSE = 1000
# Semantic classes (the confusion matrix is C x C).
MAX_CLASSES = 1000
MAX_CLASS_NAME_CHARS = 256
# Landmark ids (ground truth, truth_landmark_id); truth_landmark_id -1 marks a false positive.
MAX_LANDMARK_ID = 2**63 - 1
# Image size (px).
MAX_IMAGE_SIDE_PX = 100_000

# --- floats -----------------------------------------------------------------------------------
# Length of one odometry step (m). A keyframe a kilometre from the last already asks a landmark
# seen from both to be linearised across that lever; at 10 km (stated at 1 cm) Cholesky
# refused the first update that saw one again.
MAX_ODOMETRY_STEP_M = 1e3
# A detection's range and a tag's relative-pose translation (m).
MIN_RANGE_M = 1e-3
MAX_RANGE_M = 1e4
# Ground-truth positions, |coordinate| (m): room for UTM-sized coordinates.
MAX_COORDINATE_M = 1e8
# Pixel coordinates (bounding boxes, principal point) and focal lengths, |value| (px).
MAX_PIXEL = 1e6
# Stereo baseline (m).
MAX_BASELINE_M = 100.0
# Every variance (covariance diagonal) and the condition number of every covariance: beyond
# these, iSAM2's whitening overflows or its Cholesky factorisation loses the digits it checks
# for (it refuses a pivot that lost 24 bits): a variance of 1e-12 in one detection (with the
# landmarks eliminated after the poses), or an odometry condition number of 1e12, made the
# solver fall back (tests/test_fuzz.py replays logs at these bounds).
MIN_VARIANCE = 1e-11
MAX_VARIANCE = 1e12
MAX_CONDITION = 1e10
# |norm - 1| of a quaternion.
QUATERNION_NORM_TOLERANCE = 1e-3
# Rows of the confusion matrix sum to 1 within this.
ROW_SUM_TOLERANCE = 1e-6
