"""Finding landmarks to merge in the map as it stands: candidate pairs, their joint covariance
from iSAM2, and the joint test of `joint_compatibility.py`.

Sources are the point landmarks observed in the last `recent_keyframes` keyframes; each is
paired with the landmarks near it (spatial index, then a cheap covariance bound) that the
detector's classes allow and that were never detected in the same keyframe as it (two objects
seen at once are two objects). One joint marginal over every landmark in a pair gives the
covariance of all the differences together.
"""

from __future__ import annotations

import math

import numpy as np
from gtsam.symbol_shorthand import L

from pipeline.backend import association as assoc
from pipeline.backend.decisions import MeasurementSpace
from pipeline.backend.joint_compatibility import PairSet, difference_covariance, pairs_to_merge
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.methods.base import BackendContext
from pipeline.config import MergeConfig

DIM = 3  # point landmarks


def class_agreement(p: np.ndarray, q: np.ndarray) -> float:
    """Probability that two landmarks with class posteriors p and q have the same class."""
    return float(np.dot(p, q))


def pair_groups(pairs: list[tuple[int, int]], loop: list[bool]) -> list[list[int]]:
    """Pairs that must be tested together: those sharing a landmark, and all those that close
    a loop (one correction of the map must explain them all). Indices into `pairs`."""
    parent = list(range(len(pairs)))

    def root(p: int) -> int:
        while parent[p] != p:
            parent[p] = parent[parent[p]]
            p = parent[p]
        return p

    first_of: dict[int, int] = {}
    first_loop = None
    for p, (a, b) in enumerate(pairs):
        for j in (a, b):
            if j in first_of:
                parent[root(p)] = root(first_of[j])
            else:
                first_of[j] = p
        if loop[p]:
            if first_loop is None:
                first_loop = p
            parent[root(p)] = root(first_loop)
    groups: dict[int, list[int]] = {}
    for p in range(len(pairs)):
        groups.setdefault(root(p), []).append(p)
    return list(groups.values())


class MergeFinder:
    def __init__(
        self,
        context: BackendContext,
        config: MergeConfig,
        margin_m: float,
        space: MeasurementSpace,
    ):
        self.context = context
        self.config = config
        self.margin_m = margin_m  # allowance for the other landmark's spread in the search
        self.space = space  # where detections fall: where a landmark of its own could be

    def sources(self, pose_index: int) -> list[int]:
        """Point landmarks seen lately, if any landmark was seen or moved since the last check
        (else nothing can have changed); the context's `changed` set is emptied. All the
        recent ones, not only the changed: a loop closure's evidence is their agreement."""
        if not self.context.changed:
            return []
        self.context.changed = set()
        lms = self.context.landmarks.landmarks
        return sorted(
            j
            for j in self.context.last_seen
            if self.context.seen_lately(j, pose_index)
            and j in lms
            and lms[j].kind is LandmarkKind.POINT
        )

    def candidate_pairs(self, pose_index: int) -> list[tuple[int, int]]:
        """(source, target) pairs that may be one landmark, by cheap tests only: each source's
        `max_partners` nearest (by the bound's distance), and sources, the most recently seen
        first, only while the pairs hold at most `max_landmarks` landmarks (one joint
        marginal over them all must stay cheap, also after a long drift)."""
        context, c = self.context, self.config
        lms = context.landmarks
        sources = self.sources(pose_index)
        if not sources:
            return []
        gate = assoc.chi2_gate(DIM, max(c.confidence, c.local_confidence))
        bound = {j: self._bound(j) for j in sources}
        seen_at: dict[int, set[int]] = {}
        partners: dict[int, list[tuple[float, int]]] = {}
        for a in sources:
            spread = float(np.sqrt(2.0 * np.linalg.eigvalsh(bound[a])[-1]))
            position = lms.position(a)
            found = []
            for b in lms.near(
                LandmarkKind.POINT, position, c.search_sigmas * spread + self.margin_m
            ):
                if b == a:
                    continue
                agreement = class_agreement(
                    lms.landmarks[a].class_probabilities, lms.landmarks[b].class_probabilities
                )
                if agreement < c.min_class_agreement:
                    continue
                bound_b = bound.get(b)
                if bound_b is None:
                    bound_b = bound[b] = self._bound(b)
                d2 = assoc.mahalanobis_squared(
                    position - lms.position(b), 2.0 * (bound[a] + bound_b)
                )
                if d2 > gate:
                    continue
                for j in (a, b):
                    if j not in seen_at:
                        seen_at[j] = context.observed_at(j)
                if seen_at[a] & seen_at[b]:
                    continue  # seen together: two landmarks
                found.append((d2, b))
            partners[a] = sorted(found)[: c.max_partners]
        pairs: set[tuple[int, int]] = set()
        involved: set[int] = set()
        for a in sorted(partners, key=lambda j: -context.last_seen.get(j, -1)):
            mine = {(min(a, b), max(a, b)) for _, b in partners[a]} - pairs
            more = {j for pair in mine for j in pair} - involved
            if len(involved) + len(more) > c.max_landmarks:
                break
            pairs |= mine
            involved |= more
        # The newer landmark (larger id) is the source, merged into the older one.
        return sorted((b, a) for a, b in pairs)

    def _bound(self, landmark_id: int) -> np.ndarray:
        landmark = self.context.landmarks.landmarks[landmark_id]
        if landmark.covariance_bound is None:
            landmark.covariance_bound = self.context.solver.marginal_covariance(L(landmark_id))
        return landmark.covariance_bound

    def find(self, pose_index: int) -> list[tuple[int, int]]:
        """(duplicate, survivor) pairs to merge now."""
        candidates = self.candidate_pairs(pose_index)
        if not candidates:
            return []
        context, c = self.context, self.config
        involved = sorted({j for pair in candidates for j in pair})
        slots = {j: k for k, j in enumerate(involved)}
        joint = context.solver.joint_covariance([L(j) for j in involved])
        estimates = context.estimates()
        estimates.fetch([], involved)
        positions = {j: estimates.landmark(j) for j in involved}
        # Two landmarks both seen lately that were not associated are the association gate's
        # tail, so their merge gate is the wider local_confidence; one seen long ago would close
        # a loop, and its pair passes at confidence.
        pairs, differences, loop = [], [], []
        covariance = difference_covariance(joint, candidates, slots, DIM)
        for p, (a, b) in enumerate(candidates):
            closes_loop = not context.seen_lately(b, pose_index)
            gate = assoc.chi2_gate(DIM, c.confidence if closes_loop else c.local_confidence)
            diff = positions[a] - positions[b]
            block = covariance[p * DIM : (p + 1) * DIM, p * DIM : (p + 1) * DIM]
            if assoc.mahalanobis_squared(diff, block) <= gate:
                pairs.append((a, b))
                differences.append(diff)
                loop.append(closes_loop)
        if not pairs:
            return []
        gate = assoc.chi2_gate(DIM, c.confidence)

        def alike(x: int, y: int) -> bool:
            C = difference_covariance(joint, [(x, y)], slots, DIM)
            return assoc.mahalanobis_squared(positions[x] - positions[y], C) <= gate

        lms = context.landmarks.landmarks
        log_volume = self.space.log_world_volume()
        log_prior = np.array(
            [
                log_volume
                + c.prior_log_odds
                + math.log(class_agreement(lms[a].class_probabilities, lms[b].class_probabilities))
                for a, b in pairs
            ]
        )
        merged = []
        for group in pair_groups(pairs, loop):
            chosen = [pairs[p] for p in group]
            pair_set = PairSet(
                pairs=chosen,
                differences=np.array([differences[p] for p in group]),
                covariance=difference_covariance(joint, chosen, slots, DIM),
                log_prior=log_prior[group],
                loop=np.array([loop[p] for p in group]),
                alike=alike,
            )
            closes_loop = bool(pair_set.loop.any())
            merged += pairs_to_merge(
                pair_set,
                c.confidence if closes_loop else c.local_confidence,
                c.loop_log_odds,
                c.local_log_odds,
                c.ambiguity_log_odds,
                c.max_search_nodes,
                c.local_rivals,
            )
        return merged
