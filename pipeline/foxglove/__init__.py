"""Foxglove's well-known schemas beside the contract's topics, so that logs and results open in
Foxglove with something to see (its 3D, Image and Log panels draw these; `mmslam.*` they do
not). The schemas and their encoding come from Foxglove's own SDK (`foxglove-sdk`): protobuf,
the schema written into each MCAP channel as Foxglove reads it.

- `messages`: pure conversions, our messages and results to Foxglove messages;
- `channels`: writing them into an MCAP file;
- `log_topics`: what a detection log holds, mirrored as the log is written (front-end and
  `simulate`, given to `LogWriter` as its mirror);
- `replay_file`: the estimate of a replay (`mmslam replay --mcap FILE`).

Frames: `world` (pose 0's body frame), `body` (the log's odometry, dead-reckoned), and
`camera_left` (the calibration's `body_from_camera`).
"""
