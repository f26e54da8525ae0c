"""The synthetic stereo renderer: camera math, images against known geometry, the KITTI files."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from data_tools.render import main, render_sequence, stereo_poses, trajectory
from data_tools.renderer import textures
from data_tools.renderer.config import PRESET_DIR, load_preset
from data_tools.renderer.geometry import (
    clip_polygon_near,
    invert_transform,
    pixel_ray_coordinates,
    project_points,
    ray_plane_depth,
)
from data_tools.renderer.layout import (
    block_walls,
    check_path_clearance,
    motion_from_config,
    place_landmarks,
)
from data_tools.renderer.path import body_poses
from data_tools.renderer.raycast import PinholeCamera, SceneRenderer, sample_texture
from data_tools.renderer.scene import Scene, Tag, Texture, facing_surface, tag_surface
from pipeline.datasets.camera import BODY_FROM_CAMERA
from pipeline.datasets.kitti import KittiSequence, camera_poses_to_body
from pipeline.errors import InputError
from pipeline.geometry import transform_points

CAMERA = PinholeCamera(613, 185, 353.5456, 353.5456, 300.6937, 91.3052, supersample=2)
BASELINE = 0.5372
SEQUENCE_FRAMES = 8

# cv2.aruco holds tag36h11 turned by 180 degrees: its corner k is the official corner
# ARUCO_TO_APRILTAG[k] in AprilTag's order (bottom-left, bottom-right, top-right, top-left).
ARUCO_TO_APRILTAG = [1, 0, 3, 2]


def tag_detector() -> cv2.aruco.ArucoDetector:
    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    return cv2.aruco.ArucoDetector(dictionary, parameters)


def to_uint8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def horizontal_shift(left: np.ndarray, right: np.ndarray, u: int, v: int, half: int = 7) -> float:
    """Where the left patch at (u, v) sits in the right image's row: u - u_right, sub-pixel."""
    patch = left[v - half : v + half + 1, u - half : u + half + 1].astype(np.float32)
    start = max(0, u - half - 140)
    strip = right[v - half : v + half + 1, start : u + half + 1].astype(np.float32)
    cost = cv2.matchTemplate(strip, patch, cv2.TM_SQDIFF)[0]
    i = int(np.argmin(cost))
    offset = 0.0
    if 0 < i < cost.size - 1:
        a, b, c = cost[i - 1], cost[i], cost[i + 1]
        offset = 0.5 * (a - c) / (a - 2 * b + c)
    return u - (start + half + i + offset)


# ---------------------------------------------------------------- camera and plane math


def test_sub_pixel_rays_average_to_the_pixel_centre():
    one = pixel_ray_coordinates(10, 100.0, 4.5, supersample=1)
    two = pixel_ray_coordinates(10, 100.0, 4.5, supersample=2)
    assert one[0] == pytest.approx(-0.045)
    assert two.reshape(10, 2).mean(axis=1) == pytest.approx(one)
    assert two[1] - two[0] == pytest.approx(0.5 / 100.0)


def test_projection_inverts_the_pixel_rays():
    k = CAMERA.camera_matrix
    xs = pixel_ray_coordinates(CAMERA.width, CAMERA.fx, CAMERA.cx)
    ys = pixel_ray_coordinates(CAMERA.height, CAMERA.fy, CAMERA.cy)
    depth = 7.0
    points = np.array([[xs[37] * depth, ys[120] * depth, depth], [xs[600] * 2, ys[3] * 2, 2.0]])
    assert project_points(points, k) == pytest.approx(np.array([[37.0, 120.0], [600.0, 3.0]]))
    assert np.isnan(project_points(np.array([[1.0, 1.0, -1.0]]), k)).all()


def test_ray_plane_depth():
    # The plane z = 5 seen head-on: depth 5 on every ray.
    xs, ys = np.array([-0.3, 0.0, 0.4]), np.array([[0.2], [-0.1]])
    assert ray_plane_depth(xs, ys, [0, 0, 5.0], [0, 0, -1.0]) == pytest.approx(np.full((2, 3), 5))
    # The floor y = 1.5 (camera y points down): the ray (0, 0.3, 1) meets it at Z = 5.
    depth = ray_plane_depth(np.array(0.0), np.array(0.3), [0, 1.5, 0], [0, -1.0, 0])
    assert depth == pytest.approx(5.0, rel=1e-12)  # 1.5 / 0.3: round-off only
    # A ray parallel to the floor never meets it; a plane behind the camera gives Z < 0.
    assert np.isinf(ray_plane_depth(np.array(0.0), np.array(0.0), [0, 1.5, 0], [0, -1.0, 0]))
    behind = ray_plane_depth(np.array(0.0), np.array(0.0), [0, 0, -2.0], [0, 0, 1.0])
    assert behind == pytest.approx(-2.0, rel=1e-12)


def test_near_plane_clipping_keeps_the_front_part():
    quad = np.array([[-1.0, 0, -1], [1, 0, -1], [1, 0, 3], [-1, 0, 3]])
    clipped = clip_polygon_near(quad, 0.5)
    assert len(clipped) == 4
    assert clipped[:, 2].min() == pytest.approx(0.5)
    assert sorted(map(tuple, clipped)) == sorted(
        [(-1.0, 0.0, 0.5), (1.0, 0.0, 0.5), (1.0, 0.0, 3.0), (-1.0, 0.0, 3.0)]
    )
    assert len(clip_polygon_near(quad - [0, 0, 5], 0.5)) == 0


def test_texture_levels_are_area_means_and_sampling_hits_texel_centres():
    image = np.random.default_rng(0).integers(0, 256, size=(64, 96)).astype(np.uint8)
    texture = Texture.from_image(image)
    assert texture.num_levels == 7
    level1 = image.astype(np.float64).reshape(32, 2, 48, 2).mean(axis=(1, 3))
    assert np.abs(texture.level(1) - level1).max() <= 0.5
    assert texture.level(6).shape == (1, 1)
    rows, cols = np.array([0, 10, 63]), np.array([0, 50, 95])
    s, t = (cols + 0.5) / 96, (rows + 0.5) / 64
    values = sample_texture(texture, s.astype(np.float32), t.astype(np.float32), np.zeros(3))
    assert values == pytest.approx(image[rows, cols].astype(np.float32), abs=0.01)
    at_level1 = sample_texture(
        texture, np.array([0.5 / 48], np.float32), np.array([0.5 / 32], np.float32), np.ones(1)
    )
    assert at_level1[0] == pytest.approx(float(texture.level(1)[0, 0]), abs=0.01)


# ---------------------------------------------------------------- rendered images


def wall_scene(tags: tuple[Tag, ...] = ()) -> Scene:
    """A textured wall 4 m ahead of a camera at the origin (camera frame = world frame)."""
    rng = np.random.default_rng(1)
    image = textures.clutter(rng, 12, 6, 120, 150.0, 3.0)
    wall = facing_surface(
        np.array([0.0, 0, 4.0]),
        np.array([0, 0, -1.0]),
        np.array([0, -1.0, 0]),
        12,
        6,
        Texture.from_image(image),
    )
    return Scene((wall, *[tag_surface(t) for t in tags]), tags)


def turned_tag(tag_id: int, centre, turn_deg: float, size: float = 0.4) -> Tag:
    turn = math.radians(turn_deg)
    z_axis = np.array([math.sin(turn), 0.0, math.cos(turn)])  # into the tag
    y_axis = np.array([0.0, 1.0, 0.0])  # down
    return Tag(
        tag_id, size, np.array(centre), np.column_stack([np.cross(y_axis, z_axis), y_axis, z_axis])
    )


@pytest.mark.parametrize("turn_deg", [0.0, 40.0])
def test_tag_is_detected_where_its_corners_project(turn_deg):
    tag = turned_tag(42, [-0.6, 0.1, 3.0], turn_deg)
    renderer = SceneRenderer(wall_scene((tag,)), CAMERA)
    right_from_left = np.eye(4)
    right_from_left[0, 3] = BASELINE
    for world_from_camera in (np.eye(4), right_from_left):
        image = to_uint8(renderer.render(world_from_camera).image)
        corners, ids, _ = tag_detector().detectMarkers(image)
        assert ids is not None and ids.ravel().tolist() == [42]
        camera_points = transform_points(invert_transform(world_from_camera), tag.corners())
        expected = project_points(camera_points, CAMERA.camera_matrix)[ARUCO_TO_APRILTAG]
        assert np.abs(corners[0][0] - expected).max() < 1.0


def test_tag_cells_are_dark_and_bright_where_the_code_says():
    tag = turned_tag(7, [0.0, 0.0, 2.0], 0.0, size=0.8)
    view = SceneRenderer(wall_scene((tag,)), CAMERA).render(np.eye(4))
    # Cell (i, j) of the 8 x 8 black-bordered square, centre in the tag frame.
    cells = cv2.aruco.generateImageMarker(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), 7, 8
    )
    official = np.rot90(cells, 2)
    step = tag.size / 8
    for i in range(8):
        for j in range(8):
            local = np.array([(j + 0.5) * step - tag.size / 2, (i + 0.5) * step - tag.size / 2, 0])
            world = tag.rotation @ local + tag.centre
            u, v = project_points(world[None], CAMERA.camera_matrix)[0]
            value = view.image[round(v), round(u)]
            assert (value > 128) == (official[i, j] > 127), (i, j, value)


@pytest.mark.parametrize("depth", [3.0, 7.3, 15.0])
def test_texture_edges_land_at_their_sub_pixel_projection(depth):
    """Rendering is area-exact: a dark square's width and centre, read off one image row by
    integrating its darkness, match the projection to a few hundredths of a pixel."""
    image = np.full((100, 100), 250, np.uint8)
    image[30:70, 30:70] = 10  # the square spans x in [0.3, 0.7) of a 1 m board
    board = facing_surface(
        np.array([0.137, -0.05, depth]),
        np.array([0, 0, -1.0]),
        np.array([0, -1.0, 0]),
        1.0,
        1.0,
        Texture.from_image(image),
    )
    backdrop = facing_surface(
        np.array([0, 0, depth + 1]),
        np.array([0, 0, -1.0]),
        np.array([0, -1.0, 0]),
        50,
        50,
        Texture.from_image(np.full((4, 4), 250, np.uint8)),
    )
    view = SceneRenderer(Scene((board, backdrop)), CAMERA).render(np.eye(4))
    left, right = CAMERA.fx * np.array([-0.063, 0.337]) / depth + CAMERA.cx
    row = view.image[round(CAMERA.fy * -0.05 / depth + CAMERA.cy)]
    darkness = (row.max() - row) / (row.max() - row.min())
    columns = np.arange(row.size)
    assert darkness.sum() == pytest.approx(right - left, abs=0.02)
    assert (columns * darkness).sum() / darkness.sum() == pytest.approx(
        (left + right) / 2, abs=0.02
    )


def test_stereo_shift_is_focal_times_baseline_over_depth():
    renderer = SceneRenderer(wall_scene(), CAMERA)
    right_from_left = np.eye(4)
    right_from_left[0, 3] = BASELINE
    left = renderer.render(np.eye(4))
    right = to_uint8(renderer.render(right_from_left).image)
    expected = CAMERA.fx * BASELINE / 4.0
    for u, v in [(100, 40), (300, 90), (500, 150), (450, 30), (200, 160)]:
        assert left.depth[v, u] == pytest.approx(4.0, rel=1e-5)
        assert horizontal_shift(to_uint8(left.image), right, u, v) == pytest.approx(
            expected, abs=0.5
        )


def test_nearer_surfaces_hide_farther_ones():
    scene = wall_scene()
    rng = np.random.default_rng(2)
    board = facing_surface(
        np.array([0.5, 0, 2.0]),
        np.array([0, 0, -1.0]),
        np.array([0, -1.0, 0]),
        1.0,
        1.0,
        Texture.from_image(textures.clutter(rng, 1, 1, 100, 200.0, 5.0)),
        owner=1001,
    )
    # Listed after the wall, so the depth test (not the drawing order) must win.
    view = SceneRenderer(Scene((*scene.surfaces, board)), CAMERA).render(np.eye(4))
    u, v = project_points(np.array([[0.5, 0.0, 2.0]]), CAMERA.camera_matrix)[0]
    assert view.depth[round(v), round(u)] == pytest.approx(2.0, rel=1e-5)
    assert view.depth[10, 10] == pytest.approx(4.0, rel=1e-5)
    ss = CAMERA.supersample
    assert view.owner[round(v) * ss, round(u) * ss] == 1001
    assert view.owner[10 * ss, 10 * ss] == -1
    assert np.isinf(SceneRenderer(Scene(()), CAMERA).render(np.eye(4)).depth).all()


# ---------------------------------------------------------------- presets, path, layout


def test_presets_load_and_bad_presets_are_refused(tmp_path):
    names = sorted(p.stem for p in PRESET_DIR.glob("*.toml"))
    assert {"demo", "kitti-size"} <= set(names)
    for name in names:
        load_preset(name)
    kitti = load_preset("kitti-size").camera
    assert (kitti.width, kitti.height) == (1226, 370)
    text = (PRESET_DIR / "demo.toml").read_text()
    for bad in (
        text.replace("width = 613", "width = 613\ncolour = true"),
        text.replace("supersample = 2", "supersample = 2.5"),
        text.replace("count = 22  # valid: in [0, 587]\n", ""),
        text.replace('style = "street"', 'style = "forest"'),
    ):
        path = tmp_path / "bad.toml"
        path.write_text(bad)
        with pytest.raises(InputError):
            load_preset(path)
    with pytest.raises(InputError):
        load_preset("no-such-preset")


def test_demo_drive_revisits_its_start_within_the_limits():
    config = load_preset("demo")
    poses = body_poses(motion_from_config(config), config.camera.frame_rate)
    assert 150 <= len(poses) <= 300
    rotations = poses[:, :3, :3]
    assert np.allclose(rotations @ rotations.transpose(0, 2, 1), np.eye(3), atol=1e-9)
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    assert steps.max() <= config.path.speed / config.camera.frame_rate * 1.05
    yaw = np.unwrap(np.arctan2(rotations[:, 1, 0], rotations[:, 0, 0]))
    assert np.abs(np.diff(yaw)).max() * config.camera.frame_rate < 1.2 * config.path.max_yaw_rate
    assert yaw[-1] - yaw[0] > 2 * math.pi  # more than a lap, counter-clockwise
    late = poses[int(0.8 * len(poses)) :, :3, 3]
    assert np.linalg.norm(late - poses[0, :3, 3], axis=1).min() < 1.0
    walls = block_walls(
        config.scene.block_length, config.scene.block_width, config.scene.street_width
    )
    check_path_clearance(walls, poses[:, :2, 3], 1.0)
    with pytest.raises(InputError):
        inside = walls[0].start + 2.0 * walls[0].direction + 0.5 * walls[0].normal
        check_path_clearance(walls, inside[None], 1.0)


def test_demo_and_kitti_size_share_their_landmarks_and_drive():
    placed = []
    for name in ("demo", "kitti-size"):
        config = load_preset(name)
        scene = config.scene
        walls = block_walls(scene.block_length, scene.block_width, scene.street_width)
        drive = trajectory(config)
        tags, objects = place_landmarks(config, walls, drive[:, :2, 3], seed=3)
        placed.append((drive, [(t.tag_id, *t.centre) for t in tags], [o.centre for o in objects]))
    (drive_a, tags_a, objects_a), (drive_b, tags_b, objects_b) = placed
    assert np.array_equal(drive_a, drive_b)
    assert tags_a == tags_b and np.array_equal(objects_a, objects_b)


# ---------------------------------------------------------------- the written sequence


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("render") / "demo"
    return render_sequence("demo", out, seed=0, num_frames=SEQUENCE_FRAMES)


@pytest.mark.slow
def test_sequence_round_trips_through_kitti_sequence(sequence):
    config = load_preset("demo")
    reader = KittiSequence(sequence)
    assert len(reader) == SEQUENCE_FRAMES
    cam = config.camera
    k = reader.intrinsics
    assert (k.width, k.height) == (cam.width, cam.height)
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx((cam.fx, cam.fy, cam.cx, cam.cy), abs=1e-9)
    assert k.baseline == pytest.approx(cam.baseline, abs=1e-9)
    assert reader.times == pytest.approx(np.arange(SEQUENCE_FRAMES) / cam.frame_rate)
    left, right = reader[1]
    assert left.dtype == np.uint8 and left.shape == (cam.height, cam.width) == right.shape
    assert left.std() > 20 and not np.array_equal(left, right)
    # Poses: the drive's left cameras relative to the first; identity first.
    drive = trajectory(config, SEQUENCE_FRAMES)
    cameras = np.array([stereo_poses(p, cam.baseline)[0] for p in drive])
    expected = np.linalg.inv(cameras[0]) @ cameras
    assert reader.gt_poses == pytest.approx(expected, abs=1e-8)
    assert reader.gt_poses[0] == pytest.approx(np.eye(4))
    body = camera_poses_to_body(reader.gt_poses)
    assert body[1] == pytest.approx(np.linalg.inv(drive[0]) @ drive[1], abs=1e-8)


@pytest.mark.slow
def test_landmarks_file_describes_the_scene(sequence):
    document = json.loads((sequence / "landmarks.json").read_text())
    config = load_preset("demo")
    assert document["frame"] == "body0"
    landmarks = document["landmarks"]
    ids = [m["id"] for m in landmarks]
    assert len(set(ids)) == len(ids)
    tags = [m for m in landmarks if m["kind"] == "tag"]
    boxes = [m for m in landmarks if m["kind"] == "box"]
    assert len(tags) == config.tags.count and len(boxes) == config.objects.count
    for m in tags:
        assert m["id"] == m["tag_id"] and 0 <= m["tag_id"] < 587
        assert m["size"] == [config.tags.size, config.tags.size, 0.0]
        corners = np.array(m["corners"])
        assert corners.mean(axis=0) == pytest.approx(m["position"], abs=1e-6)
    for m in boxes:
        assert m["id"] >= 1000 and m["tag_id"] is None and m["class_name"] == "car"
        # Boxes stand on the street, the camera height below body0 (the first pose is level).
        assert m["position"][2] - m["size"][2] / 2 == pytest.approx(
            -config.path.camera_height, abs=1e-6
        )
    for m in landmarks:
        assert np.linalg.norm(m["rotation"]) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.slow
def test_tags_in_the_images_are_where_the_ground_truth_says(sequence):
    """Through poses.txt and landmarks.json only: the detected tags' corners must lie at the
    projections of the true corners, and their left-right shift at f * b / Z."""
    reader = KittiSequence(sequence)
    k = reader.intrinsics
    truth = {m["id"]: m for m in json.loads((sequence / "landmarks.json").read_text())["landmarks"]}
    visible = json.loads((sequence / "visibility.json").read_text())["frames"]
    checked = 0
    detector = tag_detector()
    for index, body in enumerate(camera_poses_to_body(reader.gt_poses)):
        left, right = reader[index]
        camera_from_body0 = np.linalg.inv(body @ BODY_FROM_CAMERA)
        found = {}
        for side, image in (("left", left), ("right", right)):
            corners, ids, _ = detector.detectMarkers(image)
            ids = [] if ids is None else ids.ravel().tolist()
            found[side] = {i: c[0] for i, c in zip(ids, corners, strict=True)}
        for seen in visible[index]["landmarks"]:
            m = truth[seen["id"]]
            if m["kind"] != "tag" or seen["pixels"] < 600:
                continue
            points = transform_points(camera_from_body0, np.array(m["corners"]))
            expected = project_points(points, k.camera_matrix)[ARUCO_TO_APRILTAG]
            if not (np.all(expected >= 3) and np.all(expected <= [k.width - 4, k.height - 4])):
                continue  # cut by the image border
            assert seen["id"] in found["left"], f"tag {seen['id']} not detected in {index}"
            assert np.abs(found["left"][seen["id"]] - expected).max() < 1.0
            box = seen["bbox"]
            assert expected[:, 0].min() >= box[0] - 1.5 and expected[:, 0].max() <= box[2] + 1.5
            if seen["id"] in found["right"]:
                shift = found["left"][seen["id"]][:, 0] - found["right"][seen["id"]][:, 0]
                depth = points[ARUCO_TO_APRILTAG, 2]
                assert shift == pytest.approx(k.fx * k.baseline / depth, abs=1.0)
            checked += 1
    assert checked >= 2


@pytest.mark.slow
def test_same_seed_same_bytes_other_seed_other_scene(sequence, tmp_path):
    again = render_sequence("demo", tmp_path / "again", seed=0, num_frames=SEQUENCE_FRAMES)
    files = sorted(p.relative_to(sequence) for p in sequence.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    for name in files:
        assert (sequence / name).read_bytes() == (again / name).read_bytes(), name
    other = render_sequence("demo", tmp_path / "other", seed=1, num_frames=1)
    first = "image_0/000000.png"
    assert (other / first).read_bytes() != (sequence / first).read_bytes()
    assert (other / "landmarks.json").read_text() != (sequence / "landmarks.json").read_text()
    # Re-rendering over a previous render replaces it; anything else is left alone.
    render_sequence("demo", tmp_path / "other", seed=1, num_frames=1)
    (tmp_path / "precious").mkdir()
    (tmp_path / "precious" / "notes.txt").write_text("keep")
    with pytest.raises(InputError):
        render_sequence("demo", tmp_path / "precious", num_frames=1)
    assert (tmp_path / "precious" / "notes.txt").read_text() == "keep"


def test_command_line_reports_bad_input(tmp_path, caplog):
    assert main(["no-such-preset", "--out", str(tmp_path / "x")]) == 2
    assert main(["demo", "--out", str(tmp_path / "x"), "--num-frames", "0"]) == 2
    assert not (tmp_path / "x").exists()
