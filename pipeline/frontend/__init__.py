"""The image front-end: a stereo sequence to a contract-v1 detection log (`run.run_frontend`).

One module a stage: `stereo_vo` (visual odometry and keyframes), `apriltags` (tag point and pose
measurements), the object-box stage (`objects`, `stereo_range`); shared camera and pose math in
`geometry`; `classes` for the tag classes' names; `ground_truth` for rendered sequences;
`config` for the typed settings (configs/frontend.toml); `run` runs the stages and writes the
log.
"""
