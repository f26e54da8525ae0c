"""Finding landmarks to merge in the map as it stands: candidate pairs, their joint covariance
from iSAM2, and the joint test of `joint_compatibility.py`.

Sources are the point landmarks observed in the last `recent_keyframes` keyframes (at the log's
end, every point landmark, its pairs tested at the map's covariance: `final_check`); each is
paired with the landmarks near it (spatial index, then a cheap covariance bound) that the
detector's classes allow and that were never detected in the same keyframe as it (two objects
seen at once are two objects). One joint
marginal over every landmark in a pair gives the covariance of all the differences together.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np
from gtsam.symbol_shorthand import L

from pipeline.backend import association as assoc
from pipeline.backend.budget import SearchBudget
from pipeline.backend.candidates import PosePrediction, covariance_bound
from pipeline.backend.decisions import MeasurementSpace, in_view
from pipeline.backend.geometry import world_point_covariance
from pipeline.backend.joint_compatibility import (
    PairSet,
    difference_blocks,
    difference_covariance,
    loop_drift_directions,
    pairs_to_merge,
)
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.methods.base import BackendContext
from pipeline.backend.noise import DriftScaleBelief
from pipeline.config import MergeConfig

logger = logging.getLogger(__name__)

DIM = 3  # point landmarks
# A landmark's detections can split between it and a duplicate only once both hold two or
# more; one of a single detection carries that detection's noise in its covariance already,
# and allowing it again merged lone detections into the next car of a row (kitti05-cars,
# noise x5).
MIN_SPLIT_DETECTIONS = 2


def class_agreement(p: np.ndarray, q: np.ndarray) -> float:
    """Probability that two landmarks with class posteriors p and q have the same class."""
    return float(np.dot(p, q))


def with_detection_noise(
    covariance: np.ndarray, pairs: np.ndarray, noise: np.ndarray, dim: int = DIM
) -> np.ndarray:
    """The pairs' difference covariance with `noise[k]` (dim x dim) added to pair
    `pairs[k]`'s own block: a difference that may be off by that much more, independently."""
    out = covariance.copy()
    for p, block in zip(pairs, noise, strict=True):
        rows = slice(p * dim, (p + 1) * dim)
        out[rows, rows] += block
    return out


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


class _Sightings(dict[int, set[int]]):
    """Per landmark, the keyframes of its detections (`observed_at`), looked up the first
    time it is asked for: a check asks of the same landmarks for source after source."""

    def __init__(self, observed_at: Callable[[int], set[int]]):
        super().__init__()
        self.observed_at = observed_at

    def __missing__(self, j: int) -> set[int]:
        self[j] = seen = self.observed_at(j)
        return seen


class _PartnerSearch:
    """A merge check's cheap search for each source's partners: mapped point landmarks within
    reach, classes agreeing, never seen in the same keyframe, within the gate of the two
    covariance bounds; the `max_partners` nearest. Sightings are gathered once a check.

    A landmark's bound is an iSAM2 marginal the first time it is asked for (then cached,
    `covariance_bound`): a check computes at most `marginals` of them. A source whose search
    would take more than are left is not searched (`partners` says None): it and the sources
    after it wait for the next check, keeping their landmarks apart meanwhile."""

    def __init__(self, finder: MergeFinder, gate: float, widest: float, marginals: int):
        self.finder = finder
        self.gate = gate
        self.widest = widest
        self.marginals = marginals  # new marginals the check may still compute
        self.sightings = _Sightings(finder.context.observed_at)

    def _afford(self, ids: list[int]) -> bool:
        """Whether the bounds of `ids` are cached or within the marginals left; if so, they
        are spent."""
        lms = self.finder.context.landmarks.landmarks
        new = sum(lms[j].covariance_bound is None for j in ids)
        if new > self.marginals:
            return False
        self.marginals -= new
        return True

    def partners(self, a: int) -> list[int] | None:
        """Source `a`'s partners, nearest first; None if finding them takes more marginals
        than the check has left."""
        c, lms, bound = self.finder.config, self.finder.context.landmarks, self.finder.bound
        if not self._afford([a]):
            return None
        spread = float(np.sqrt(2.0 * np.linalg.eigvalsh(bound(a))[-1]))
        position = lms.position(a)
        reach = c.search_sigmas * spread * math.sqrt(self.widest) + self.finder.margin_m
        near = [b for b in lms.near(LandmarkKind.POINT, position, reach) if b != a]
        if not near:
            return []
        classes = np.array([lms.landmarks[b].class_probabilities for b in near])
        agrees = classes @ lms.landmarks[a].class_probabilities >= c.min_class_agreement
        # Two landmarks seen in the same keyframe are two landmarks (tested before the bounds:
        # a crowded keyframe's own landmarks need none).
        seen_a, sightings = self.sightings[a], self.sightings
        near = [
            b
            for b, agree in zip(near, agrees, strict=True)
            if agree and seen_a.isdisjoint(sightings[b])
        ]
        if not near:
            return []
        if not self._afford(near):
            return None
        offsets = position - lms.positions(LandmarkKind.POINT, near)
        spreads = 2.0 * (bound(a) + np.array([bound(b) for b in near]).reshape(-1, DIM, DIM))
        d2 = assoc.mahalanobis_squared_batch(offsets, spreads)
        inside = np.flatnonzero(d2 <= self.gate)
        found = list(zip(d2[inside].tolist(), np.array(near)[inside].tolist(), strict=True))
        return [b for _, b in sorted(found)[: c.max_partners]]


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
        # How far a loop's covariance may be understated: what the loops closed so far say.
        self.drift_belief = DriftScaleBelief(
            config.drift_scale_weight, config.max_drift_scale, config.drift_scale_steps
        )
        # Mapped landmarks in the sensor's view, summed over the checks: how many a duplicate
        # could be a duplicate of.
        self._in_view = (0, 0)  # (landmarks, checks)

    def sources(self, pose_index: int, final: bool = False) -> list[int]:
        """Point landmarks seen lately, if any landmark was seen or moved since the last check
        (else nothing can have changed); the context's `changed` set is emptied. All the
        recent ones, not only the changed: a loop closure's evidence is their agreement.
        `final`: the point landmarks of `changed` instead, seen lately or not."""
        if not self.context.changed:
            return []
        changed, self.context.changed = self.context.changed, set()
        lms = self.context.landmarks.landmarks
        if final:
            candidates = changed
        else:
            candidates = {
                j for j in self.context.last_seen if self.context.seen_lately(j, pose_index)
            }
        return sorted(j for j in candidates if j in lms and lms[j].kind is LandmarkKind.POINT)

    def candidate_pairs(
        self, pose_index: int, widest: float = 1.0, final: bool = False
    ) -> list[tuple[int, int]]:
        """(source, target) pairs that may be one landmark, by cheap tests only: each source's
        `max_partners` nearest (by the bound's distance), and sources, the most recently seen
        first, only while the pairs hold at most `max_landmarks` landmarks (one joint
        marginal over them all must stay cheap, also after a long drift) and their search
        computes at most `max_marginals` new marginals (`_PartnerSearch`; the sources left
        over are searched at the next check). `widest`: the largest drift scale a loop is
        tested at, relative to the map's covariance. A source's partners are looked for only
        when its turn comes, so a keyframe that started thousands of landmarks costs the
        budget's worth of searches, not thousands. `final`: the sources are those of `changed`
        (`sources`), and the ones left over go back to it."""
        context, c = self.context, self.config
        sources = self.sources(pose_index, final)
        if not sources:
            return []
        # A loop's partner may be as far as the `widest` drift scale tested puts it.
        gate = assoc.chi2_gate(DIM, max(c.confidence, c.local_confidence)) * widest
        search = _PartnerSearch(self, gate, widest, c.max_marginals)
        pairs: set[tuple[int, int]] = set()
        involved: set[int] = set()
        ordered = sorted(sources, key=lambda j: -context.last_seen.get(j, -1))
        for turn, a in enumerate(ordered):
            context.heartbeat(f"merge check, partners of source {turn + 1} of {len(ordered)}")
            partners = search.partners(a)
            if partners is None:
                # The check's marginals are spent: the sources left wait for the next check.
                context.changed.update(ordered[turn:])
                logger.debug(
                    "pose %d: merge check's marginals spent, %d of %d sources searched",
                    pose_index, turn, len(ordered),
                )  # fmt: skip
                break
            mine = {(min(a, b), max(a, b)) for b in partners} - pairs
            more = {j for pair in mine for j in pair} - involved
            if len(involved) + len(more) > c.max_landmarks:
                if final:
                    context.changed.update(ordered[turn:])
                break
            pairs |= mine
            involved |= more
        # The newer landmark (larger id) is the source, merged into the older one.
        return sorted((b, a) for a, b in pairs)

    def _landmarks_in_view(self, prediction: PosePrediction) -> float:
        """The mean number of mapped point landmarks in the sensor's view over the checks so
        far (at least 1), counting the one at this check's predicted pose. A source that is a
        duplicate is one of them: each pair's prior holds 1 / that mean (`partner_prior`)."""
        if not self.config.partner_prior:
            return 1.0
        _, high = self.space.box()
        pose = prediction.pose
        translation = pose.translation()
        lms = self.context.landmarks
        near = lms.near(LandmarkKind.POINT, translation, float(high[-1]))
        points = np.array([lms.position(j) for j in near]).reshape(-1, 3)
        count = in_view(pose.rotation().matrix(), translation, points, self.space)
        total, checks = self._in_view
        self._in_view = (total + count, checks + 1)
        return max(1.0, (total + count) / (checks + 1))

    def _latest_detection_noise(self, landmark_id: int, estimates) -> np.ndarray:
        """The world-frame noise of the landmark's latest detection, from its pose's estimate.
        Once a landmark is mapped twice, each detection goes to the nearer of the two, and
        the two estimates settle about one detection's noise apart however many detections
        they hold: a local pair's test allows that (`local_detection_noise`)."""
        latest = max(self.context.held_detections(landmark_id), key=lambda m: m.pose_index)
        R, _ = estimates.pose(latest.pose_index)
        return world_point_covariance(R, latest.vector, latest.covariance)

    def bound(self, landmark_id: int) -> np.ndarray:
        """The landmark's marginal covariance, or an upper bound on it (`covariance_bound`)."""
        return covariance_bound(self.context.solver, self.context.landmarks, landmark_id)

    def find(
        self, pose_index: int, prediction: PosePrediction, final: bool = False
    ) -> list[tuple[int, int]]:
        """(duplicate, survivor) pairs to merge now, at the keyframe predicted by `prediction`
        (where the sensor looks from). A loop's test weighs a drift larger than the map's
        covariance holds by what the loops closed so far say (`DriftScaleBelief`), up to
        `max_drift_scale` times it, and what it closes is added to that. `final` (the log's
        last check): the sources are the landmarks of the context's `changed` set
        (`candidate_pairs`), and the pairs are tested as the map stands, at its covariance."""
        c = self.config
        if final:  # the map as it stands: the loops it could close are closed
            drift_scales = np.ones(1), np.zeros(1)
        else:
            drift_scales = self.drift_belief.scales, self.drift_belief.log_weights
        widest = float(np.max(drift_scales[0]))
        candidates = self.candidate_pairs(pose_index, widest, final)
        if not candidates:
            return []
        context = self.context
        involved = sorted({j for pair in candidates for j in pair})
        slots = {j: k for k, j in enumerate(involved)}
        joint = context.solver.joint_covariance([L(j) for j in involved])
        estimates = context.estimates()
        estimates.fetch([], involved)
        positions = {j: estimates.landmark(j) for j in involved}
        # Two landmarks both seen lately that were not associated are the association gate's
        # tail, so their merge gate is the wider local_confidence; one seen long ago would close
        # a loop, and its pair passes at confidence under the widest drift the test allows.
        # Of the differences' joint covariance only what the check uses is formed: each pair's
        # own block, the loop pairs' together (the drift's) and each group's; the cross terms
        # of pairs tested apart are most of it when a long drift lets many pairs in.
        closes = np.array([not context.seen_lately(b, pose_index) for _, b in candidates])
        noise: dict[int, np.ndarray] = {}  # by candidate: its detection's noise
        if c.local_detection_noise:
            split = [
                p
                for p in np.flatnonzero(~closes)
                if min(len(context.held_detections(j)) for j in candidates[p])
                >= MIN_SPLIT_DETECTIONS
            ]
            noise = {
                int(p): self._latest_detection_noise(candidates[p][0], estimates) for p in split
            }
        blocks = difference_blocks(joint, candidates, slots, DIM)
        for p, block in noise.items():
            blocks[p] += block
        sources = np.array([positions[a] for a, _ in candidates])
        loops = [candidates[p] for p in np.flatnonzero(closes)]
        drift = (
            loop_drift_directions(sources, closes, difference_covariance(joint, loops, slots, DIM))
            if loops
            else None
        )
        P = len(candidates)
        if drift is not None:  # the widest drift the loop's test allows
            G = drift.reshape(P, DIM, -1)
            blocks = blocks + (widest - 1.0) * (G @ G.transpose(0, 2, 1))
        offsets = np.array([positions[a] - positions[b] for a, b in candidates])
        gates = np.where(
            closes, assoc.chi2_gate(DIM, c.confidence), assoc.chi2_gate(DIM, c.local_confidence)
        )
        d2 = assoc.mahalanobis_squared_batch(offsets, blocks)
        passed = np.flatnonzero(d2 <= gates)
        # The nearest max_pairs at most: the searches' arithmetic grows with the square and
        # the cube of the pairs (`pairs_to_merge`).
        kept = sorted(int(p) for p in passed[np.argsort(d2[passed], kind="stable")[: c.max_pairs]])
        pairs = [candidates[p] for p in kept]
        differences = offsets[kept]
        loop = [bool(closes[p]) for p in kept]
        if not pairs:
            return []
        gate = assoc.chi2_gate(DIM, c.confidence)

        def alike(x: int, y: int) -> bool:
            C = difference_covariance(joint, [(x, y)], slots, DIM)
            return assoc.mahalanobis_squared(positions[x] - positions[y], C) <= gate

        lms = context.landmarks.landmarks
        log_volume = self.space.log_world_volume() - math.log(self._landmarks_in_view(prediction))
        log_prior = np.array(
            [
                log_volume
                + c.prior_log_odds
                + math.log(class_agreement(lms[a].class_probabilities, lms[b].class_probabilities))
                for a, b in pairs
            ]
        )
        merged = []
        # One budget for the check's searches: a check never takes unbounded time, however
        # many pairs the map's covariance lets through (`budget.py`).
        budget = SearchBudget(c.max_check_nodes)
        groups = pair_groups(pairs, loop)
        for k, group in enumerate(groups):
            context.heartbeat(f"merge check, pair group {k + 1} of {len(groups)}")
            chosen = [pairs[p] for p in group]
            rows = np.concatenate([np.arange(kept[p] * DIM, (kept[p] + 1) * DIM) for p in group])
            split = [i for i, p in enumerate(group) if kept[p] in noise]  # rows in the group
            covariance = with_detection_noise(
                difference_covariance(joint, chosen, slots, DIM),
                np.array(split, dtype=int),
                np.array([noise[kept[group[i]]] for i in split]),
            )
            closes_loop = any(loop[p] for p in group)
            scales, log_weights = drift_scales if closes_loop else (np.ones(1), np.zeros(1))
            pair_set = PairSet(
                pairs=chosen,
                differences=differences[group],
                covariance=covariance,
                log_prior=log_prior[group],
                loop=np.array([loop[p] for p in group]),
                alike=alike,
                drift=drift[rows] if closes_loop else None,
                scales=scales,
                log_scale_weights=log_weights,
            )
            to_merge = pairs_to_merge(
                pair_set,
                c.confidence if closes_loop else c.local_confidence,
                c.loop_log_odds,
                c.local_log_odds,
                c.ambiguity_log_odds,
                c.max_search_nodes,
                c.local_rivals,
                c.search_seeds,
                budget,
            )
            closed = [pair_set.pairs.index(pair) for pair in to_merge]
            if not final and any(pair_set.loop[p] for p in closed):  # what it says of the drift
                self.drift_belief.observe(pair_set.scale_log_likelihoods(closed)[0])
            merged += to_merge
        return merged
