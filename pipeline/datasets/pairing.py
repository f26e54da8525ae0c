"""Left and right frames paired by their stamps (ROS bags, EuRoC): pure functions, no I/O.

A pair is made only of a left and a right frame that are each other's nearest in time and no
further apart than a tolerance. A frame without such a partner (dropped by a driver, or a
camera that started late) is left out and reported, never paired with a neighbour's frame:
pairing by position would put images of different times together after one lost frame.
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class StereoPairing:
    """Indices into the left and right stamp lists: the pairs, in time order, and the frames
    of each side left without a partner."""

    pairs: list[tuple[int, int]]
    unmatched_left: list[int]
    unmatched_right: list[int]


def _nearest(stamps: Sequence[int], stamp: int) -> int:
    """The index of the stamp nearest `stamp` in increasing `stamps` (the earlier on a tie)."""
    at = bisect.bisect_left(stamps, stamp)
    if at == 0:
        return 0
    if at == len(stamps):
        return len(stamps) - 1
    return at - 1 if stamp - stamps[at - 1] <= stamps[at] - stamp else at


def pair_stamps(left: Sequence[int], right: Sequence[int], tolerance_ns: int) -> StereoPairing:
    """Pair strictly increasing left and right stamps (ns): left `i` with right `j` when each is
    the other's nearest and they differ by at most `tolerance_ns`."""
    for name, stamps in (("left", left), ("right", right)):
        if any(b <= a for a, b in itertools.pairwise(stamps)):
            raise ValueError(f"{name} stamps must increase strictly")
    pairs: list[tuple[int, int]] = []
    if left and right:
        for i, stamp in enumerate(left):
            j = _nearest(right, stamp)
            if abs(right[j] - stamp) <= tolerance_ns and _nearest(left, right[j]) == i:
                pairs.append((i, j))
    paired_left = {i for i, _ in pairs}
    paired_right = {j for _, j in pairs}
    return StereoPairing(
        pairs,
        [i for i in range(len(left)) if i not in paired_left],
        [j for j in range(len(right)) if j not in paired_right],
    )
