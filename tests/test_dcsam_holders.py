"""DC-SAM's landmarks and their holders (`methods/dcsam/method.py`): a landmark no detection
holds leaves the map's spatial index (withdrawn), and is back in it, where the estimate puts
it, once a detection holds it again."""

import gtsam
import numpy as np

from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.methods.dcsam import DiscreteContinuous
from tests.backend_cases import add_landmark, detection_of, hand_context, measurement

POSITION = np.array([5.0, 1.0, 0.0])


def test_a_landmark_held_again_is_back_in_the_map():
    context = hand_context()
    method = DiscreteContinuous(context)
    j = add_landmark(context, POSITION, 0.1)
    context.solver.update()
    m = measurement(0, detection_of(gtsam.Pose3(), POSITION))

    def indexed() -> bool:
        return j in context.landmarks.near(LandmarkKind.POINT, POSITION, 1.0)

    method._hold(j, m)
    assert indexed() and j not in context.landmarks.withdrawn
    method._release(j, m)  # its last holder gone
    assert not indexed() and j in context.landmarks.withdrawn
    method._hold(j, m)  # held again
    assert indexed() and j not in context.landmarks.withdrawn
    assert method.holders[j] == 1
