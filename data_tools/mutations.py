"""The named mutations of `make mutate` (`data_tools/mutate.py`), module by module: each a small
plausible bug (a boundary moved, a check dropped, two values swapped, a result thrown away),
the text it replaces, and the tests that must notice it. A pattern occurs exactly once in its
file. `equivalent` marks a survivor that changes no behaviour, with the reason."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Mutation:
    module: str
    path: str
    name: str  # the bug it stands for
    pattern: str
    replacement: str
    equivalent: str | None = None


@dataclass(frozen=True)
class Module:
    tests: tuple[str, ...]  # pytest's arguments
    mutations: tuple[Mutation, ...]


FAST = ("-m", "not slow")
# The front-end's whole runs (e2e) take minutes; the readers' own tests decide.
DATASET_TESTS = (
    "tests/test_dataset_readers.py",
    "tests/test_sequence_layouts.py",
    "-m",
    "not slow and not e2e",
)
LOG_TESTS = (
    "tests/test_log_properties.py",
    "tests/test_log.py",
    "tests/test_log_integrity.py",
    "tests/test_log_doc.py",
    "tests/test_fuzz.py",
    *FAST,
)
DCSAM_TESTS = ("tests/test_dcsam.py", *FAST)

# (module, path, tests, [(name, pattern, replacement[, equivalent]), ...])
_TABLE: list[tuple[str, str, tuple[str, ...], list[tuple[str, ...]]]] = [
    (
        "datasets/pairing",
        "pipeline/datasets/pairing.py",
        DATASET_TESTS,
        [
            (
                "a tie goes to the later stamp",
                "stamp - stamps[at - 1] <= stamps[at] - stamp",
                "stamp - stamps[at - 1] < stamps[at] - stamp",
            ),
            (
                "the farther neighbour is taken",
                "return at - 1 if stamp - stamps[at - 1] <= stamps[at] - stamp else at",
                "return at if stamp - stamps[at - 1] <= stamps[at] - stamp else at - 1",
            ),
            (
                "a pair exactly at the tolerance is refused",
                "abs(right[j] - stamp) <= tolerance_ns",
                "abs(right[j] - stamp) < tolerance_ns",
            ),
            (
                "pairs need not be each other's nearest",
                " and _nearest(left, right[j]) == i",
                "",
            ),
            ("repeated stamps are taken", "if any(b <= a for a, b", "if any(b < a for a, b"),
            (
                "unmatched right frames counted against the left ones",
                "if j not in paired_right]",
                "if j not in paired_left]",
            ),
            ("an empty right side is read", "if left and right:", "if left:"),
        ],
    ),
    (
        "datasets/rectification",
        "pipeline/datasets/rectification.py",
        DATASET_TESTS,
        [
            (
                "distortion alone does not make rectification needed",
                "if np.any(np.abs(camera.distortion) > 0):\n                return True",
                "if False:\n                return True",
            ),
            (
                "a rotation is weighed in radians, not pixels",
                "np.max(np.abs(R - np.eye(3))) * fx > RECTIFIED_PX",
                "np.max(np.abs(R - np.eye(3))) > RECTIFIED_PX",
            ),
            (
                "the baseline divided by fy",
                "baseline = -right[0, 3] / fx if fx > 0",
                "baseline = -right[0, 3] / left[1, 1] if fx > 0",
            ),
            ("fy taken from fx", "float(left[1, 1]),", "float(left[0, 0]),"),
            (
                "equidistant cameras undistorted as radial-tangential",
                'if camera.model == "equidistant":\n        return cv2.fisheye',
                'if camera.model == "fisheye":\n        return cv2.fisheye',
            ),
            (
                "the rectifying rotations swapped",
                "    return Rectification(left, right, R1, R2, P1, P2)",
                "    return Rectification(left, right, R2, R1, P1, P2)",
            ),
            ("black borders kept (alpha 1)", "alpha=0.0,", "alpha=1.0,"),
            ("fisheye black borders kept (balance 1)", "balance=0.0,", "balance=1.0,"),
            (
                "a right projection offset in y accepted",
                " or np.any(np.abs(right[1:, 3]) > 1e-9)",
                "",
            ),
            (
                "a pair whose right camera sits to the left taken as rectified",
                "and translation[0] < 0\n",
                "and translation[0] != 0\n",
            ),
            (
                "the pinhole compared without the tolerance",
                "if np.max(np.abs(camera.K - P[:3, :3])) > RECTIFIED_PX:",
                "if np.max(np.abs(camera.K - P[:3, :3])) > 10 * RECTIFIED_PX:",
            ),
        ],
    ),
    (
        "datasets/camera",
        "pipeline/datasets/camera.py",
        (
            "tests/test_dataset_readers.py",
            "tests/test_sequence_layouts.py",
            "tests/test_kitti_layout.py",
            "tests/test_frontend_geometry.py",
            *FAST,
        ),
        [
            ("cx on the image's edge accepted", "0 <= k.cx < k.width", "0 <= k.cx <= k.width"),
            (
                "the principal point's offset in x weighed by the height",
                "MAX_PRINCIPAL_OFFSET * k.width",
                "MAX_PRINCIPAL_OFFSET * k.height",
            ),
            (
                "a non-positive baseline accepted",
                "min(k.fx, k.fy, k.baseline) <= 0",
                "min(k.fx, k.fy) <= 0",
            ),
            ("infinite numbers accepted", "if not math.isfinite(value):", "if False:"),
            ("the log's fy is fx", "fy=self.fy,", "fy=self.fx,"),
            (
                "the camera matrix's fy is fx",
                "[0.0, self.fy, self.cy]",
                "[0.0, self.fx, self.cy]",
            ),
            (
                "the camera's y axis points up in the body frame",
                "[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]",
                "[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]",
            ),
        ],
    ),
    (
        "datasets/euroc",
        "pipeline/datasets/euroc.py",
        DATASET_TESTS,
        [
            (
                "images returned without rectification",
                "return self.rectification.apply(*super().images(index))",
                "return super().images(index)",
            ),
            (
                "equidistant read as radial-tangential",
                '"equidistant": "equidistant",',
                '"equidistant": "radtan",',
            ),
            (
                "repeated data.csv stamps accepted",
                "if stamps and stamp <= stamps[-1]:",
                "if stamps and stamp < stamps[-1]:",
            ),
            (
                "the pair's pose taken the wrong way round",
                "np.linalg.inv(poses[1]) @ poses[0]",
                "np.linalg.inv(poses[0]) @ poses[1]",
            ),
            ("fu and fv swapped", "fu, fv, cu, cv = _numbers", "fv, fu, cu, cv = _numbers"),
            (
                "the resolution read as height, width",
                "width, height = _numbers",
                "height, width = _numbers",
            ),
            (
                "a frame's stamp taken from cam1",
                "[stamps[0][i] for i, _ in pairing.pairs]",
                "[stamps[1][j] for _, j in pairing.pairs]",
            ),
            (
                "OpenCV's %YAML header not skipped",
                'if text.startswith("%YAML:"):',
                'if text.startswith("%YAML:") and False:',
            ),
            (
                "a T_BS with a bottom row other than 0 0 0 1 accepted",
                "\n        or np.max(np.abs(body_from_sensor[3] - [0, 0, 0, 1])) > 0",
                "",
            ),
            (
                "a folder holding cam0/ itself not read",
                'for candidate in (path / "mav0", path):',
                'for candidate in (path / "mav0",):',
            ),
            ("colour images taken as grey", "self.colour = first.ndim == 3", "self.colour = False"),
        ],
    ),
    (
        "datasets/rosbag",
        "pipeline/datasets/rosbag.py",
        DATASET_TESTS,
        [
            (
                "rgba8 read as bgra8",
                '"rgba8": (4, cv2.COLOR_RGBA2BGR)',
                '"rgba8": (4, cv2.COLOR_BGRA2BGR)',
            ),
            (
                "bgra8 read as rgba8",
                '"bgra8": (4, cv2.COLOR_BGRA2BGR)',
                '"bgra8": (4, cv2.COLOR_RGBA2BGR)',
            ),
            ("8UC3 read as rgb8", '"8UC3": (3, None)', '"8UC3": (3, cv2.COLOR_RGB2BGR)'),
            (
                "rational_polynomial read as equidistant",
                '"rational_polynomial": "radtan"',
                '"rational_polynomial": "equidistant"',
            ),
            (
                "header stamps that repeat accepted",
                "if stamps and stamp <= stamps[-1]:",
                "if stamps and stamp < stamps[-1]:",
            ),
            (
                "cam0 and cam2 taken as a pair",
                "int(y) == int(x) + 1",
                "int(y) > int(x)",
            ),
            (
                "the camera_info of a compressed topic looked for under it",
                're.sub(r"/compressed$", "", image_topic)',
                "image_topic",
            ),
            (
                "an empty R kept (a degenerate rectification)",
                "if not np.any(R):",
                "if False:",
            ),
            (
                "one topic named rect makes the pair rectified",
                'if all("rect" in topic for topic in self.topics):',
                'if any("rect" in topic for topic in self.topics):',
            ),
            (
                "nanoseconds of a header stamp dropped",
                "* 1_000_000_000 + int(message.header.stamp.nanosec)",
                "* 1_000_000_000",
            ),
            (
                "a frame of another size passed on",
                "if size != expected:",
                "if False:",
            ),
            (
                "equidistant CameraInfo with too few coefficients accepted",
                'if np.any(D) and model == "equidistant" and D.size < 4:',
                "if False:",
            ),
            (
                "rows' padding kept",
                "[:, : width * channels]",
                "[:, step - width * channels :]",
            ),
        ],
    ),
    (
        "log/validate",
        "pipeline/log/validate.py",
        LOG_TESTS,
        [
            (
                "stamps going back accepted",
                "if previous is not None and msg.stamp_ns < previous:",
                "if False:",
            ),
            (
                "odometry skipping a pose accepted",
                "msg.from_index != expected or msg.to_index != expected + 1",
                "msg.from_index != expected",
            ),
            (
                "odometry repeating a stamp accepted",
                "if previous_stamp is not None and msg.stamp_ns == previous_stamp:",
                "if False:",
            ),
            ("log_time other than stamp_ns accepted", "if msg.stamp_ns != log_time:", "if False:"),
            (
                "a pose counted as reached one step late",
                "pending[0][0] <= self.odometry_count",
                "pending[0][0] < self.odometry_count",
            ),
            (
                "a pose's ground truth given twice accepted",
                "if topic == schemas.GT_POSE and not self._gt_poses.add(msg.pose_index):",
                "if topic == schemas.GT_POSE and not self._gt_poses.add(msg.pose_index) and 0:",
            ),
            (
                "two ground-truth landmark messages accepted",
                'self._once(topic, index, "ground-truth landmark message")',
                "pass",
            ),
            ("repeated landmark ids accepted", "if len(set(ids)) != len(ids):", "if False:"),
            (
                "a keyframe of exactly the most detections refused",
                "if count > limits.MAX_DETECTIONS_PER_POSE:",
                "if count >= limits.MAX_DETECTIONS_PER_POSE:",
            ),
            (
                "the pose set reads the wrong bit",
                "seen = bool(self._bits[byte] >> bit & 1)",
                "seen = bool(self._bits[byte] >> (bit + 1) & 1)",
            ),
            (
                "a message of exactly the cap refused",
                "if len(data) > cap:",
                "if len(data) >= cap:",
            ),
            (
                "a channel's schema encoding not checked",
                '("schema encoding", channel.schema_encoding, "jsonschema"),',
                "",
            ),
            (
                "a detection at the newest pose taken as unreached",
                "if msg.pose_index > max(self._highest.get(topic, 0), self.odometry_count):",
                "if msg.pose_index >= max(self._highest.get(topic, 0), self.odometry_count):",
            ),
            (
                "channels without messages not checked",
                "        for channel in channels:\n            self.check_channel(channel)\n",
                "",
            ),
        ],
    ),
    (
        "log/codec",
        "pipeline/log/codec.py",
        LOG_TESTS,
        [
            (
                "an asymmetric covariance accepted",
                "if not np.allclose(matrix, matrix.T, rtol=1e-6, atol=1e-12):",
                "if False:",
            ),
            (
                "a singular covariance accepted",
                "if eigenvalues[0] <= 0.0:",
                "if eigenvalues[0] < 0.0:",
            ),
            (
                "a variance below the floor accepted",
                "np.any(variances < low) or np.any(variances > high)",
                "np.any(variances > high)",
            ),
            (
                "an ill-conditioned covariance accepted",
                "if condition > limits.MAX_CONDITION:",
                "if False:",
            ),
            (
                "a vector's length below its bound accepted",
                "if not marker.low <= norm <= marker.high:",
                "if not norm <= marker.high:",
                "every Norm in messages.py has low 0 and a length is never negative",
            ),
            (
                "a quaternion shorter than 1 accepted",
                "if abs(norm - 1.0) > limits.QUATERNION_NORM_TOLERANCE:",
                "if norm - 1.0 > limits.QUATERNION_NORM_TOLERANCE:",
            ),
            (
                "a box upside down accepted",
                "if value[0] > value[2] or value[1] > value[3]:",
                "if value[0] > value[2]:",
            ),
            (
                "a transform's bottom row not checked",
                "if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):",
                "if False:",
            ),
            (
                "a transform's rotation not checked",
                "if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-3):",
                "if False:",
            ),
            (
                "class id C accepted",
                "elif value >= num_classes:",
                "elif value > num_classes:",
            ),
            (
                "nested messages not checked",
                "parts[name] = tuple(\n                checked(item, num_classes, "
                'f"{where}{name}[{k}].") for k, item in enumerate(value)\n            )',
                "parts[name] = value",
            ),
            (
                "NaN in JSON reported as malformed, not as non-finite",
                "json.loads(data, parse_constant=_reject_constant)",
                "json.loads(data)",
            ),
            (
                "an image stamp's seconds scaled wrong",
                "stamp_ns = wire.timestamp.sec * 1_000_000_000 + wire.timestamp.nsec",
                "stamp_ns = wire.timestamp.sec * 1_000_000 + wire.timestamp.nsec",
            ),
            (
                "an image stamp's nanoseconds written wrong",
                '"nsec": msg.stamp_ns % 1_000_000_000',
                '"nsec": msg.stamp_ns // 1_000_000_000',
            ),
        ],
    ),
    (
        "log/mcap_stream",
        "pipeline/log/mcap_stream.py",
        LOG_TESTS,
        [
            ("the data section's CRC not checked", "if expected not in (0, crc):", "if False:"),
            (
                "the summary's CRC not checked",
                "if expected not in (0, summary_crc):",
                "if False:",
            ),
            (
                "a chunk's CRC not checked",
                "if expected_crc != 0 and zlib.crc32(raw) != expected_crc:",
                "if False:",
            ),
            ("a chunk's size not checked", "if len(raw) != size:", "if False:"),
            ("no decompression budget", "if self._inflated > budget:", "if False:"),
            (
                "bytes after the closing magic accepted",
                "if f.read(len(MAGIC) + 1) != MAGIC:",
                "if f.read(len(MAGIC)) != MAGIC:",
            ),
            (
                "a file not starting with a header accepted",
                "if number == 0 and opcode != Opcode.HEADER:",
                "if False:",
            ),
            (
                "a channel defined twice differently accepted",
                "if known != channel:",
                "if False:",
            ),
            (
                "a record inside a chunk running past it accepted",
                "if length > len(view) - offset:",
                "if False:",
            ),
            (
                "a chunk claiming fewer bytes than it holds accepted",
                "raw = r.read(size + 1)",
                "raw = r.read(size)",
            ),
            (
                "a topic's first log time is its last",
                "info.first_ns = log_time if info.first_ns is None else min(info.first_ns, "
                "log_time)",
                "info.first_ns = log_time",
            ),
            (
                "a record past the file's end accepted",
                "if length > self._size - offset - _HEAD.size:",
                "if False:",
            ),
        ],
    ),
    (
        "log/reader",
        "pipeline/log/reader.py",
        LOG_TESTS,
        [
            (
                "ground-truth poses left in file order",
                "log.ground_truth_poses.sort(key=lambda m: m.pose_index)",
                "pass",
            ),
            ("images kept when not asked for", "if load_images:", "if not load_images:"),
            (
                "the whole-log checks skipped",
                "validator.finish(mcap.channels.values())",
                "pass",
            ),
            ("images not counted", "image_counts[topic] += 1", "pass"),
            ("the calibration dropped", "log.calibration = msg", "log.calibration = None"),
            (
                "a bad metadata record not named",
                "raise LogError(mcap.path, str(exc), f\"metadata '{METADATA_NAME}'\")",
                "raise LogError(mcap.path, str(exc))",
            ),
        ],
    ),
    (
        "log/writer",
        "pipeline/log/writer.py",
        (*LOG_TESTS[:-2], "tests/test_outputs.py", "tests/test_foxglove.py", *FAST),
        [
            (
                "messages written unchecked",
                "self._validator.message(channel, index, msg.stamp_ns, data)",
                "pass",
            ),
            (
                "the whole-log checks skipped on closing",
                "self._validator.finish(self._channels.values())",
                "pass",
            ),
            (
                "metadata written unchecked",
                "            parse_metadata(record)\n",
                "            pass\n",
            ),
            ("no data-section CRC", "enable_data_crcs=True", "enable_data_crcs=False"),
            ("every message named as the first", "index = self._counts[topic]", "index = 0"),
            (
                "a failed block's log kept",
                "        else:\n            self.abort()",
                "        else:\n            self.close()",
            ),
            ("NaN written", "allow_nan=False", "allow_nan=True"),
        ],
    ),
    (
        "outputs",
        "pipeline/outputs.py",
        ("tests/test_output_files.py", "tests/test_outputs.py", *FAST),
        [
            (
                "a trajectory to the millimetre",
                'f"{v:.9f}" for v in values',
                'f"{v:.3f}" for v in values',
            ),
            (
                "the quaternion written w first",
                "values = [*T[:3, 3], *q]",
                "values = [*T[:3, 3], q[3], *q[:3]]",
            ),
            ("a landmark's y and z swapped", "{x:.6f},{y:.6f},{z:.6f}", "{x:.6f},{z:.6f},{y:.6f}"),
            ("weights to two digits", 'f"{p},{d},{lm},{w:.6f}"', 'f"{p},{d},{lm},{w:.2f}"'),
            (
                "a live writer's temporary removed",
                "os.close(fd)\n            continue\n        try:",
                "os.close(fd)\n        try:",
            ),
            (
                "another target's temporaries removed",
                'return name.startswith(f".{target}.") and',
                'return name.startswith(".") and',
            ),
            ("a new file made private", "os.fchmod(fd, _default_mode(0o666))", "pass"),
            (
                "files of the old set not carried over",
                "for name in os.listdir(self.path):",
                "for name in []:",
            ),
            (
                "stale files carried over",
                "written = set(files) | set(stale)",
                "written = set(files)",
            ),
            (
                "the current directory replaced",
                "if target == cwd or target in cwd.parents:",
                "if False:",
            ),
            (
                "a folder holding a folder replaced",
                "        if inside is not None:\n            raise InputError(\n"
                '                f"{path}: holds the folder',
                "        if False:\n            raise InputError(\n"
                '                f"{path}: holds the folder',
            ),
            (
                "an output file name with a slash taken",
                'if not name or os.sep in name or name in (".", ".."):',
                "if not name:",
            ),
            (
                "a file in place of the folder taken",
                "if target.exists() and not target.is_dir():",
                "if False:",
            ),
        ],
    ),
    (
        "evaluation",
        "pipeline/evaluation.py",
        ("tests/test_evaluation.py", "tests/test_viz_correctness.py", *FAST),
        [
            ("the first poses not aligned", "est.align_origin(ref)", "pass"),
            (
                "rotation errors in degrees",
                "metrics.PoseRelation.rotation_angle_rad,",
                "metrics.PoseRelation.rotation_angle_deg,",
            ),
            (
                "a tie goes to the largest true id",
                "key=lambda kv: (-kv[1], kv[0])",
                "key=lambda kv: (-kv[1], -kv[0])",
            ),
            (
                "detections without truth vote",
                "if landmark < 0 or truth is None:",
                "if landmark < 0:",
            ),
            ("nulls counted as wrong", 'counts["null"] += 1', 'counts["wrong"] += 1'),
            (
                "matched with no detection shared",
                "if block[r, c] > 0:",
                "if block[r, c] >= 0:",
            ),
            ("the fewest detections kept together", "maximize=True", "maximize=False"),
            (
                "precision over every detection",
                '"precision": round(correct / decided, 6)',
                '"precision": round(correct / total, 6)',
            ),
            (
                "every false positive on a landmark counted as used",
                "false_used += int(landmark in stands_for)",
                "false_used += int(landmark >= 0)",
            ),
            (
                "landmarks per true one not divided",
                "round(len(holding) / len(seen), 6)",
                "round(len(holding), 6)",
            ),
            ("true landmark 0 taken for a false positive", "if truth < 0:", "if truth <= 0:"),
        ],
    ),
    (
        "backend/noise/contrasts",
        "pipeline/backend/noise/contrasts.py",
        ("tests/test_noise.py", *FAST),
        [
            (
                "each landmark's share of its own detections ignored",
                "share = 1.0 - 1.0 / np.maximum(np.asarray(sightings, dtype=float), 1.0)",
                "share = np.ones(len(sightings))",
            ),
            (
                "a planar log's pose taken as free in all six directions",
                "free = np.ones(POSE_DIRECTIONS, bool) if free is None else np.asarray(free, bool)",
                "free = np.ones(POSE_DIRECTIONS, bool)",
            ),
            (
                "the pose's error left in",
                "N = U[:, rank:]  # what the pose's error cannot move",
                "N = U",
            ),
            (
                "whitened at the stated noise, not at the scales in use",
                "root = np.sqrt(np.asarray(used, dtype=float))",
                "root = np.ones(3)",
            ),
        ],
    ),
    (
        "backend/noise/drift",
        "pipeline/backend/noise/drift.py",
        ("tests/test_noise.py", *FAST),
        [
            (
                "a window's discrepancy its first step's alone",
                'return np.einsum("kab,kb->a", T, residuals)',
                "return T[0] @ residuals[0]",
            ),
            (
                "the steps carried to the window's end in the wrong order",
                "        T = T @ adjoints[k]",
                "        T = adjoints[k] @ T",
            ),
            (
                "windows of one length overlapping",
                "pose_index % max(n, every) == 0",
                "pose_index % every == 0",
            ),
            (
                "the estimate's share of a direction not kept within [0, 1]",
                "lam = np.clip(lam, 0.0, 1.0)",
                "lam = lam",
            ),
            (
                "the estimate's relative covariance with the first pose's part added",
                "J = np.hstack([-relative.inverse().AdjointMap(), np.eye(6)])",
                "J = np.hstack([relative.inverse().AdjointMap(), np.eye(6)])",
            ),
        ],
    ),
    (
        "backend/noise/components",
        "pipeline/backend/noise/components.py",
        ("tests/test_noise.py", *FAST),
        [
            (
                "no observation dropped from the evidence",
                "evidence[i] = float(np.sum(gains[drop:]) - prior)",
                "evidence[i] = float(np.sum(gains) - prior)",
            ),
            (
                "a move down as easy as a move up",
                "needed = np.where(best < now, DOWN_EVIDENCE * min_evidence, min_evidence)",
                "needed = np.full_like(best, min_evidence)",
            ),
        ],
    ),
    (
        "backend/solver",
        "pipeline/backend/solver.py",
        ("tests/test_solver.py", *FAST),
        [
            (
                "the root's factor count not checked",
                " and self._landmark_factors[self._root] > 0",
                "",
            ),
            (
                "landmarks not eliminated after the poses",
                "groups.insert2(key, first + 1 if is_landmark_key(key) else first)",
                "groups.insert2(key, first)",
            ),
            (
                "QR refusals retried in batch",
                'if self.factorization == "QR" or "Indeterminate" not in reason:',
                'if "Indeterminate" not in reason:',
            ),
            (
                "removed factors still counted on their landmark",
                "self._landmark_factors.subtract(_landmark_keys(self._committed.pop(handle)))",
                "self._committed.pop(handle)",
            ),
            (
                "rotation and translation thresholds swapped",
                "[rotation] * 3 + [translation] * 3",
                "[translation] * 3 + [rotation] * 3",
            ),
            (
                "GTSAM's reason reads past its first paragraph",
                "        if not line:\n            break",
                "        if not line:\n            continue",
            ),
            (
                "a QR fallback recorded as a batch one",
                'self.fallbacks.append(SolverFallback(self.num_updates, "qr", reason))',
                'self.fallbacks.append(SolverFallback(self.num_updates, "batch", reason))',
            ),
            (
                "the oldest landmark taken as the root",
                "self._root = max(landmarks)",
                "self._root = min(landmarks)",
            ),
            (
                "the estimate left where the wildfire threshold stopped",
                "return self.isam.calculateBestEstimate()",
                "return self.isam.calculateEstimate()",
            ),
            (
                "movement thresholds in the wrong order",
                "        config.pose_rotation_threshold_rad,\n"
                "        config.pose_translation_threshold_m,\n",
                "        config.pose_translation_threshold_m,\n"
                "        config.pose_rotation_threshold_rad,\n",
            ),
            (
                "a removed variable's value kept in the batch solve",
                "            if key not in keys:  # a variable every factor of which was removed\n"
                "                values.erase(key)",
                "            if key not in keys:  # a variable every factor of which was removed\n"
                "                pass",
            ),
        ],
    ),
    (
        "backend/planar",
        "pipeline/backend/planar.py",
        ("tests/test_planar.py", *FAST),
        [
            (
                "is_planar ignores the odometry's z, roll and pitch",
                "    for odometry in log.odometry:\n",
                "    for odometry in []:\n",
            ),
            (
                "is_planar ignores the odometry's z",
                "if abs(odometry.translation[2]) > PLANAR_TOLERANCE:",
                "if False:",
            ),
            (
                "is_planar ignores pitch",
                "max(abs(odometry.rotation[0]), abs(odometry.rotation[1]))",
                "abs(odometry.rotation[0])",
            ),
            (
                "a log without odometry is planar",
                "if not log.odometry:\n        return False",
                "if not log.odometry:\n        return True",
            ),
            (
                "is_planar ignores the detections' elevation",
                "abs(detection.elevation) <= PLANAR_TOLERANCE",
                "True",
            ),
            (
                "the height prior weighs 1/sigma",
                "height_sigma_m**-2",
                "height_sigma_m**-1",
            ),
            (
                "'always' states the plane only for a planar log",
                'return mode == "always" or (mode == "auto" and is_planar(log))',
                'return mode in ("always", "auto") and is_planar(log)',
            ),
            (
                "the tilt prior's sigma is the height's",
                "Isotropic.Sigma(2, tilt_sigma_rad)",
                "Isotropic.Sigma(2, height_sigma_m)",
            ),
        ],
    ),
    (
        "dcsam/method",
        "pipeline/backend/methods/dcsam/method.py",
        DCSAM_TESTS,
        [
            (
                "a detection's own report counted in its class evidence",
                "                counts[r.landmark_id][r.measurement.detection.class_id] -= 1\n",
                "                pass\n",
            ),
            ("refine returns nothing", "        return changed\n", "        return []\n"),
            ("switches not counted", "        record.switches += 1\n", "        pass\n"),
            (
                "a landmark no detection holds stays in the map",
                "if self.holders[landmark_id] == 0:",
                "if False:",
            ),
            (
                "a withdrawn landmark taken again not reinstated",
                "if landmark_id in landmarks.withdrawn:",
                "if False:",
            ),
            (
                "the null's mode number is the own landmark's",
                "return self.num_candidates + 1 if self.active == NULL else self.active",
                "return self.num_candidates if self.active == NULL else self.active",
            ),
            (
                "the null weight read from the first mode",
                "record.null_weight = float(probabilities[-1])",
                "record.null_weight = float(probabilities[0])",
            ),
            (
                "withdrawn landmarks left in the map at the end",
                "            self.context.landmarks.discard(j)",
                "            pass",
            ),
            (
                "the report likelihood read by row (true class) instead of column",
                "report=self.context.confusion[:, m.detection.class_id].copy()",
                "report=self.context.confusion[m.detection.class_id, :].copy()",
            ),
            (
                "a released report not taken off the landmark's counts",
                "        self.report_counts[landmark_id][m.detection.class_id] -= 1\n",
                "",
            ),
        ],
    ),
    (
        "dcsam/model",
        "pipeline/backend/methods/dcsam/model.py",
        DCSAM_TESTS,
        [
            (
                "the geometric weights not normalised",
                "    return geometric / geometric.sum()",
                "    return geometric",
            ),
            (
                "a candidate weighed by w_new",
                "share * (1.0 - new_weight) * np.asarray(geometric",
                "share * new_weight * np.asarray(geometric",
            ),
            (
                "the new landmark's volume with the wrong sign",
                "new = -math.log(share * new_weight) + new_log_volume",
                "new = -math.log(share * new_weight) - new_log_volume",
            ),
            (
                "the normaliser with the wrong sign",
                "candidates + log_normaliser",
                "candidates - log_normaliser",
            ),
            (
                "SO(3)'s volume halved",
                "math.log(8.0 * math.pi**2)",
                "math.log(4.0 * math.pi**2)",
            ),
            ("report counts ignored", "return logs @ counts[reported]", "return logs.sum(axis=1)"),
            (
                "no uniform posterior where every class is ruled out",
                "return np.full(log_evidence.shape, 1.0 / log_evidence.size)",
                "return np.full(log_evidence.shape, 0.0)",
            ),
            (
                "mode probabilities favour the costliest",
                "weights = np.exp(-(costs - np.min(costs)))",
                "weights = np.exp(costs - np.min(costs))",
            ),
            (
                "a pose landmark's orientation volume left out",
                "return LOG_ROTATION_VOLUME + space.log_world_volume()",
                "return space.log_world_volume()",
            ),
        ],
    ),
    (
        "dcsam/discrete_step",
        "pipeline/backend/methods/dcsam/discrete_step.py",
        DCSAM_TESTS,
        [
            (
                "a new landmark's report averaged, not its best",
                "            out[mode] = float(np.max(d.report))",
                "            out[mode] = float(np.mean(d.report))",
            ),
            (
                "the null's report its best, not averaged",
                "out[d.null] = float(np.mean(d.report))",
                "out[d.null] = float(np.max(d.report))",
            ),
            (
                "the own and null modes' report left out",
                "            potentials[own] *= semantic[own]\n",
                "",
            ),
            (
                "detections sharing a landmark not grouped",
                "                parent[root(i)] = root(first_of[j])",
                "                pass",
            ),
            (
                "a group of exactly the limit solved by turns",
                "if len(landmarks_of(members)) <= exact_class_variables:",
                "if len(landmarks_of(members)) < exact_class_variables:",
            ),
            (
                "by turns, the classes ignore the associations",
                "                    evidence[j] = evidence[j] + log_report",
                "                    pass",
            ),
            (
                "the outside evidence turned upside down",
                "potentials = np.exp(evidence - top) if np.isfinite(top)",
                "potentials = np.exp(top - evidence) if np.isfinite(top)",
            ),
            (
                "the class factor's row on the wrong mode",
                "            table[mode] = d.report",
                "            table[0] = d.report",
            ),
            (
                "probabilities without the classes",
                "mode_probabilities(d.costs - np.log(unary_semantics(d, classes or None)))",
                "mode_probabilities(d.costs)",
            ),
        ],
    ),
]

MODULES: dict[str, Module] = {
    name: Module(
        tests,
        tuple(Mutation(name, path, entry[0], entry[1], entry[2], *entry[3:]) for entry in entries),
    )
    for name, path, tests, entries in _TABLE
}
