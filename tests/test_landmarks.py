"""The landmarks' spatial index answers what a search of every landmark would."""

import numpy as np
import pytest

from pipeline.backend.landmarks import LandmarkKind, LandmarkMap, SpatialHash


@pytest.mark.parametrize("radius", [0.5, 4.0, 500.0])  # a few cells, many, wider than the map
def test_a_query_finds_exactly_the_items_within_its_radius(radius):
    rng = np.random.default_rng(1)
    index = SpatialHash(cell_size=2.0)
    positions = rng.uniform(-20.0, 20.0, size=(300, 3))
    for item, position in enumerate(positions):
        index.set(item, position)
    for item in range(0, 300, 7):  # some move, some leave
        positions[item] += 3.0
        index.set(item, positions[item])
    for item in range(0, 300, 11):
        index.remove(item)
    alive = [i for i in range(300) if i % 11]
    for center in rng.uniform(-20.0, 20.0, size=(20, 3)):
        expected = [i for i in alive if np.linalg.norm(positions[i] - center) <= radius]
        assert index.query(center, radius) == expected


def test_several_balls_searched_at_once_find_what_each_finds_alone():
    rng = np.random.default_rng(2)
    index = SpatialHash(cell_size=2.0)
    positions = rng.uniform(-20.0, 20.0, size=(300, 3))
    for item, position in enumerate(positions):
        index.set(item, position)
    for trial in range(20):
        centers = rng.uniform(-25.0, 25.0, size=(5, 3))
        # mostly a few cells; on some trials one ball wider than the map
        radii = rng.uniform(0.1, 6.0, size=5)
        if trial % 4 == 0:
            radii[trial % 5] = 500.0
        found = index.query_many(centers, radii)
        for center, radius, ids in zip(centers, radii, found, strict=True):
            expected = [i for i in range(300) if np.linalg.norm(positions[i] - center) <= radius]
            assert ids == expected


def test_a_withdrawn_landmark_is_no_candidate_until_it_is_held_again():
    """dcsam's landmarks that every detection left: out of the index, kept in the map, moved
    by the solver without coming back; reinstated where it is now; discarded at the end."""
    landmarks = LandmarkMap(num_classes=2, cell_size=2.0)
    a = landmarks.create(LandmarkKind.POINT, np.zeros(3)).id
    b = landmarks.create(LandmarkKind.POINT, np.ones(3)).id
    landmarks.withdraw(a)
    landmarks.withdraw(a)  # twice is once
    assert landmarks.near(LandmarkKind.POINT, np.zeros(3), 5.0) == [b]
    landmarks.move(a, np.full(3, 0.5))
    assert landmarks.near(LandmarkKind.POINT, np.zeros(3), 5.0) == [b]
    assert a in landmarks.landmarks
    landmarks.reinstate(a, np.full(3, 3.0))
    assert landmarks.near(LandmarkKind.POINT, np.full(3, 3.0), 0.1) == [a]
    landmarks.withdraw(b)
    landmarks.discard(b)
    assert sorted(landmarks.landmarks) == [a] and not landmarks.withdrawn
    with pytest.raises(KeyError):  # only a withdrawn landmark is discarded
        landmarks.discard(a)


def test_positions_in_one_gather_are_each_landmarks_position():
    rng = np.random.default_rng(3)
    lms = LandmarkMap(num_classes=2, cell_size=1.0)
    ids = [lms.create(LandmarkKind.POINT, rng.normal(size=3) * 5.0).id for _ in range(6)]
    lms.move(ids[2], np.array([0.1, 0.2, 0.3]))
    lms.merge(ids[4], ids[0])
    kept = [ids[5], ids[2], ids[0]]
    gathered = lms.positions(LandmarkKind.POINT, kept)
    assert gathered.tobytes() == np.array([lms.position(j) for j in kept]).tobytes()
    assert lms.positions(LandmarkKind.POINT, []).shape == (0, 3)
