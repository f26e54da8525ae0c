"""`check_intrinsics`'s principal point rules on wide images (KITTI's 1242 x 375): a point on
or past the image's edge is outside it, and how far from the centre it may lie is a quarter of
the image's width across, a quarter of its height up and down."""

import pytest

from pipeline.datasets.camera import MAX_PRINCIPAL_OFFSET, StereoIntrinsics, check_intrinsics
from pipeline.errors import InputError

WIDTH, HEIGHT = 1242, 375


def intrinsics(cx: float, cy: float) -> StereoIntrinsics:
    return StereoIntrinsics(WIDTH, HEIGHT, 700.0, 700.0, cx, cy, 0.54)


@pytest.mark.parametrize(("cx", "cy"), [(WIDTH, HEIGHT / 2), (WIDTH / 2, HEIGHT), (-0.5, 187.0)])
def test_a_principal_point_on_or_past_the_edge_is_outside_the_images(cx, cy):
    with pytest.raises(InputError, match=r"lies outside the 1242x375 images"):
        check_intrinsics(intrinsics(cx, cy), "calib.txt")


@pytest.mark.parametrize(
    ("dx", "dy", "accepted"),
    [
        (0.2 * WIDTH, 0.0, True),  # 248 px across: far more than a quarter of the height
        (0.3 * WIDTH, 0.0, False),
        (0.0, 0.2 * HEIGHT, True),
        (0.0, 0.3 * HEIGHT, False),
    ],
)
def test_the_principal_point_may_lie_a_quarter_of_the_image_from_its_centre(dx, dy, accepted):
    assert pytest.approx(0.25) == MAX_PRINCIPAL_OFFSET
    k = intrinsics(WIDTH / 2 + dx, HEIGHT / 2 + dy)
    if accepted:
        check_intrinsics(k, "calib.txt")
    else:
        with pytest.raises(InputError, match="far from the centre"):
            check_intrinsics(k, "calib.txt")
