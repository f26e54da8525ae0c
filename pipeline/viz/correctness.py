"""Which associations are right, against the ground truth a log may carry
(`truth_landmark_id`), as the run goes: what the map draws in red and the plots count.

A detection's association is judged as `metrics.json` judges the final ones
(`pipeline.evaluation.association_counts`): each landmark stands for the true landmark most of
its detections saw (majority vote, ties to the smallest true id), and a detection is right when
its landmark stands for its own true landmark. Here the vote is kept up to date keyframe by
keyframe: a detection judged right now may be judged wrong later, when more of its landmark's
detections turn out to be of another object. One difference from the metric: a detection
without a `truth_landmark_id` is `unlabelled` here (unknown, never drawn red), where the metric
counts it as wrong. No Rerun here.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Sequence

from pipeline.backend.hypotheses import NULL
from pipeline.evaluation import landmark_truth_by_majority

CORRECT = "correct"
WRONG = "wrong"
NULL_DECISION = "null"  # the null hypothesis took the detection: neither right nor wrong
UNLABELLED = "unlabelled"  # the log says nothing of what the detection saw
VERDICTS = (CORRECT, WRONG, NULL_DECISION, UNLABELLED)

Key = tuple[int, int]  # (pose index, detection index)


def verdicts(truth_ids: Sequence[int | None], landmark_ids: Sequence[int]) -> list[str]:
    """Each detection's verdict, from every detection's true landmark and chosen one (NULL:
    the null hypothesis)."""
    stands_for = landmark_truth_by_majority(list(truth_ids), list(landmark_ids))
    out = []
    for truth, landmark in zip(truth_ids, landmark_ids, strict=True):
        if landmark == NULL:
            out.append(NULL_DECISION)
        elif truth is None:
            out.append(UNLABELLED)
        else:
            out.append(CORRECT if stands_for.get(landmark) == truth else WRONG)
    return out


def count(verdict_list: Sequence[str]) -> dict[str, int]:
    tally = Counter(verdict_list)
    return {v: tally[v] for v in VERDICTS}


def _stands_for(votes: Counter[int]) -> int | None:
    """The true landmark these votes elect: most votes, ties to the smallest id."""
    if not votes:
        return None
    return min(votes.items(), key=lambda kv: (-kv[1], kv[0]))[0]


class AssociationTally:
    """The verdicts of every detection so far, kept up to date as associations are made,
    changed, and landmarks merged: each change costs the size of one landmark's vote, not
    the whole run's. Agrees with `verdicts` over the same associations at every step."""

    def __init__(self) -> None:
        self._held: dict[Key, tuple[int | None, int]] = {}  # key -> (truth, landmark)
        self._members: dict[int, set[Key]] = defaultdict(set)  # landmark -> its detections
        self._votes: dict[int, Counter[int]] = defaultdict(Counter)  # landmark -> truth votes
        self._right: dict[int, int] = {}  # landmark -> its labelled detections judged right
        self._totals = {v: 0 for v in VERDICTS}

    def __len__(self) -> int:
        return len(self._held)

    def _unjudge(self, landmark: int) -> None:
        """Take a landmark's detections out of the totals (before its vote changes)."""
        labelled = sum(self._votes[landmark].values())
        right = self._right.pop(landmark, 0)
        self._totals[CORRECT] -= right
        self._totals[WRONG] -= labelled - right

    def _judge(self, landmark: int) -> None:
        votes = self._votes[landmark]
        right = max(votes.values(), default=0)
        self._right[landmark] = right
        self._totals[CORRECT] += right
        self._totals[WRONG] += sum(votes.values()) - right

    def _remove(self, key: Key) -> None:
        truth, landmark = self._held.pop(key)
        if landmark == NULL:
            self._totals[NULL_DECISION] -= 1
            return
        self._members[landmark].discard(key)
        if truth is None:
            self._totals[UNLABELLED] -= 1
            return
        self._unjudge(landmark)
        self._votes[landmark][truth] -= 1
        if not self._votes[landmark][truth]:
            del self._votes[landmark][truth]
        self._judge(landmark)

    def assign(self, key: Key, truth: int | None, landmark: int) -> None:
        """Detection `key`, of true landmark `truth` (None: unlabelled), is now associated
        with `landmark` (NULL: the null hypothesis), whether for the first time or again."""
        if key in self._held:
            self._remove(key)
        self._held[key] = (truth, landmark)
        if landmark == NULL:
            self._totals[NULL_DECISION] += 1
            return
        self._members[landmark].add(key)
        if truth is None:
            self._totals[UNLABELLED] += 1
            return
        self._unjudge(landmark)
        self._votes[landmark][truth] += 1
        self._judge(landmark)

    def merge(self, duplicate: int, survivor: int) -> None:
        """Every detection of `duplicate` now belongs to `survivor`."""
        members = self._members.pop(duplicate, set())
        self._unjudge(duplicate)
        self._unjudge(survivor)
        self._votes[survivor].update(self._votes.pop(duplicate, Counter()))
        self._judge(survivor)
        self._members[survivor] |= members
        for key in members:
            self._held[key] = (self._held[key][0], survivor)

    def verdict(self, key: Key) -> str:
        truth, landmark = self._held[key]
        if landmark == NULL:
            return NULL_DECISION
        if truth is None:
            return UNLABELLED
        return CORRECT if _stands_for(self._votes[landmark]) == truth else WRONG

    def counts(self) -> dict[str, int]:
        return dict(self._totals)

    def wrong(self) -> list[tuple[Key, int]]:
        """(detection, landmark) of every detection judged wrong now, in detection order."""
        elected = {j: _stands_for(votes) for j, votes in self._votes.items() if votes}
        return [
            (key, landmark)
            for key, (truth, landmark) in sorted(self._held.items())
            if landmark != NULL and truth is not None and elected.get(landmark) != truth
        ]
