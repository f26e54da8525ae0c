"""A EuRoC / TUM-VI `sensor.yaml` read by hand-written files: each distortion model's name
read as the model the rectification warps with, and the numbers where they belong."""

import numpy as np
import pytest

from pipeline.datasets.euroc import read_sensor_yaml

SENSOR = """sensor_type: camera
T_BS:
  cols: 4
  rows: 4
  data: [1.0, 0.0, 0.0, 0.1, 0.0, 1.0, 0.0, 0.2, 0.0, 0.0, 1.0, 0.3, 0.0, 0.0, 0.0, 1.0]
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.7, 457.3, 367.2, 248.4]
distortion_model: {model}
distortion_coefficients: [-0.28, 0.07, 0.0002, 0.00002]
"""


@pytest.mark.parametrize(
    ("name", "model"),
    [("radial-tangential", "radtan"), ("radtan", "radtan"), ("equidistant", "equidistant")],
)
def test_each_distortion_model_is_read_as_the_one_named(tmp_path, name, model):
    path = tmp_path / "sensor.yaml"
    path.write_text(SENSOR.format(model=name))
    camera, body_from_sensor = read_sensor_yaml(path)
    assert camera.model == model
    assert (camera.width, camera.height) == (752, 480)
    np.testing.assert_allclose(camera.K, [[458.7, 0, 367.2], [0, 457.3, 248.4], [0, 0, 1]])
    np.testing.assert_allclose(camera.distortion, [-0.28, 0.07, 0.0002, 0.00002])
    np.testing.assert_allclose(body_from_sensor[:3, 3], [0.1, 0.2, 0.3])
