"""A synthetic stereo renderer: textured streets or corridors, AprilTags and boxes, exact truth.

`data_tools.render.render_sequence` (or `python -m data_tools.render PRESET --out DIR`) writes
a sequence in the KITTI odometry layout, read back by `pipeline.datasets.kitti.KittiSequence`:

    DIR/image_0/000000.png ...   left images, 8-bit grey, rectified
    DIR/image_1/000000.png ...   right images (same intrinsics, baseline along the left x axis)
    DIR/calib.txt                P0..P3 (KITTI); P1[0, 3] = -fx * baseline
    DIR/times.txt                seconds from the first frame, one a line
    DIR/poses.txt                left camera poses (x right, y down, z forward), 3x4 row-major,
                                 in the frame of the first left camera (the first is identity)
    DIR/landmarks.json           ground truth of the landmarks (below)
    DIR/visibility.json          what each left image shows of each landmark (below)
    DIR/render.json              preset, seed and frame count that made the sequence

`landmarks.json`:

    {"frame": "body0",
     "landmarks": [{"id": int, "kind": "tag" | "box", "class_name": str,
                    "tag_id": int | null, "position": [x, y, z], "rotation": [qx, qy, qz, qw],
                    "size": [sx, sy, sz], ...}, ...]}

All in metres, in the body frame of pose 0 (REP-103: x forward, y left, z up; its origin is the
first left camera's centre, `BODY_FROM_CAMERA` in `pipeline.datasets.kitti`). `position` is the
landmark's centre, `rotation` the landmark frame's orientation in body0.

- Tags (`kind` "tag", `class_name` "apriltag", also `"family": "tag36h11"`): `id` = `tag_id`.
  The tag frame is AprilTag's: origin at the centre, x to the right and y down the printed tag
  seen from its front, z into the tag (the rotation pupil-apriltags' `pose_R` estimates).
  `size` = `[s, s, 0]`, s the edge of the black square (the detectors' `tag_size`; the white
  quiet zone adds s/8 a side). `corners`: the black square's corners in body0, in the order
  AprilTag reports them: tag-frame (-s/2, s/2), (s/2, s/2), (s/2, -s/2), (-s/2, -s/2), i.e.
  bottom-left, bottom-right, top-right, top-left of the upright tag. The tags drawn are the
  official AprilTag images (OpenCV's `DICT_APRILTAG_36h11` holds them turned by 180 degrees, so
  `cv2.aruco` reports their corners starting from the official bottom-right).
- Boxes (`kind` "box", `class_name` from the preset, e.g. "car"): `id` >= 1000. The box frame
  has x along its length, y along its width, z up; `position` is the centre of its bounding
  box, `size` = `[length, width, height]`. A "car" is drawn as a body box and a smaller cabin
  box inside that bounding box.

`visibility.json`: `{"camera": "left", "frames": [{"index": i, "landmarks": [{"id", "pixels",
"bbox": [u_min, v_min, u_max, v_max]}]}]}`: for every left image, the landmarks it shows, their
unoccluded area in pixels and the inclusive pixel box around it (ground-truth 2-D boxes).

Presets (`configs/renderer/`): `demo` (a city block at half KITTI resolution, 295 frames, what
`make demo` renders), `kitti-size` (the same scene and drive at 1226 x 370), `corridor` (an
indoor loop with small tags and crates, like the paper's AprilTag run). The same preset, seed
and frame count give the same bytes (on one machine: OpenCV's SIMD paths may differ between
CPUs); `demo` and `kitti-size` share their landmarks and drive for a given seed.

Modules: `scene` (dataclasses), `textures` (procedural textures), `path` (the drive),
`layout` (the block scene from a preset), `raycast` (the renderer), `geometry` (pure camera
math), `config` (presets), `output` (the JSON files).
"""
