"""The statistics of a sweep's report against values computed by hand: bootstrap intervals over
seeds, paired comparisons and their edge cases, the representative seed, the per-cell tables
and summary lines, and results.csv rows with and without the newer metrics."""

from __future__ import annotations

from dataclasses import MISSING, fields, replace

import pytest

from data_tools.sweep.grid import Cell, RunKey
from data_tools.sweep.inference import Estimate, compare, estimate, is_tie, sign_p, wilcoxon_p
from data_tools.sweep.results import (
    COLUMNS,
    OPTIONAL,
    ResultRow,
    read_results,
    results_text,
    row_from_metrics,
)
from data_tools.sweep.stats import (
    comparisons,
    headlines,
    near_reference,
    representative_seed,
    rows_of_cell,
    seed_summaries,
    slowest_run,
)
from data_tools.sweep.tables import estimate_text, headline_text, render_tables
from pipeline.errors import InputError
from tests.sweep_rows import BASE, HAND_CONFIG, HAND_ROWS

# --- bootstrap intervals ----------------------------------------------------------------------


def test_bootstrap_interval_by_hand():
    # [0, 0, 3]: a resample's mean is k, k ~ Binomial(3, 1/3): P(0) = 8/27 > 2.5 %, and
    # P(k <= 2) = 26/27 < 97.5 %, so the interval is [0, 3].
    assert estimate([0.0, 0.0, 3.0]) == Estimate(1.0, 0.0, 3.0, 3)
    # Nine 0s and a 10: k ~ Binomial(10, 0.1); P(k <= 2) = 0.930 < 97.5 % <= P(k <= 3) = 0.987,
    # so the upper end is 3, well inside the range of the data.
    assert estimate([0.0] * 9 + [10.0]) == Estimate(1.0, 0.0, 3.0, 10)
    # Two values: a resample's mean is a, (a + b) / 2 or b, each end with probability 1/4.
    assert estimate([0.0, 10.0]) == Estimate(5.0, 0.0, 10.0, 2)


def test_bootstrap_interval_edge_cases_and_determinism():
    assert estimate([]) is None
    assert estimate([2.5]) == Estimate(2.5, None, None, 1)  # one seed: no interval
    assert estimate([4.0, 4.0, 4.0]) == Estimate(4.0, 4.0, 4.0, 3)  # all alike: no spread
    data = [3.1, 7.4, 2.2, 9.9, 5.0, 4.4, 6.1]
    first = estimate(data)
    assert first == estimate(data)  # a fixed random state: the same report twice
    assert first.low < first.mean < first.high
    assert estimate_text(first, 1) == f"5.4 [{first.low:.1f}, {first.high:.1f}]"
    assert estimate_text(Estimate(2.5, None, None, 1), 2) == "2.50"
    assert estimate_text(None, 2) == "-"


# --- paired comparisons -----------------------------------------------------------------------


def test_ties_are_within_a_centimetre_or_one_percent():
    assert is_tie(10.0, 10.09)  # 1 % of 10.09 is 0.1009
    assert not is_tie(10.0, 10.11)
    assert is_tie(0.5, 0.509)  # 1 cm
    assert not is_tie(0.5, 0.52)


def test_paired_comparison_by_hand():
    # Five wins on the five seeds both have (seed 9 and seed 5 have no pair): the exact
    # Wilcoxon p is 2 / 2^5 and the sign test's 2 * (1/2)^5.
    ours = {0: 1.0, 1: 2.0, 2: 3.0, 3: 4.0, 4: 5.0, 9: 1.0}
    theirs = {0: 2.0, 1: 4.0, 2: 6.0, 3: 8.0, 4: 10.0, 5: 7.0}
    c = compare(ours, theirs)
    assert (c.pairs, c.wins, c.ties, c.losses) == (5, 5, 0, 0)
    assert c.wilcoxon_p == pytest.approx(0.0625)
    assert c.sign_p == pytest.approx(0.0625)
    # Differences -1, -2, -3, +4 and +0.004 (a tie): 3 wins, 1 loss. Sign test: 2 P(X >= 3),
    # X ~ Binomial(4, 1/2) = 2 * 5/16. Wilcoxon: ranks 2, 3, 4 negative, 1 and 5 positive,
    # W+ = 6; 13 of the 32 sign patterns have W+ <= 6, two-sided 26/32.
    c = compare(
        {0: 1.0, 1: 2.0, 2: 3.0, 3: 8.0, 4: 5.004}, {0: 2.0, 1: 4.0, 2: 6.0, 3: 4.0, 4: 5.0}
    )
    assert (c.pairs, c.wins, c.ties, c.losses) == (5, 3, 1, 1)
    assert c.sign_p == pytest.approx(0.625)
    assert c.wilcoxon_p == pytest.approx(0.8125)


def test_paired_comparison_edge_cases():
    same = compare({0: 1.0, 1: 2.0}, {0: 1.0, 1: 2.0})  # every difference zero
    assert (same.pairs, same.wins, same.ties, same.losses) == (2, 0, 2, 0)
    assert same.wilcoxon_p is None and same.sign_p is None
    none = compare({0: 1.0}, {1: 1.0})  # no seed in common
    assert (none.pairs, none.wins, none.ties, none.losses) == (0, 0, 0, 0)
    assert none.wilcoxon_p is None and none.sign_p is None
    one = compare({0: 1.0}, {0: 3.0})  # a single pair: nothing could be significant
    # p-values computed from counts: 1 to round-off
    assert (one.wins, one.wilcoxon_p, one.sign_p) == (1, pytest.approx(1.0), pytest.approx(1.0))
    assert wilcoxon_p([0.0, 0.0, 0.0]) is None
    assert wilcoxon_p([0.0, 1.0, 0.0]) == pytest.approx(1.0)  # zeros dropped: one left
    assert sign_p(0, 0) is None


# --- per-cell statistics, tables and summary lines from hand-made rows -------------------------


def test_representative_seed_is_the_median_run_of_mm_nh():
    def run(seed: int, rmse: float, method: str = "mm-nh") -> ResultRow:
        return replace(HAND_ROWS[0], seed=seed, method=method, translation_rmse=rmse)

    rows = [run(0, 5.0), run(1, 1.0), run(2, 3.0), run(3, 0.1, "ml")]
    assert representative_seed(rows) == 2
    # An even count: the lower of the middle two (RMSE 1, 2, 3, 5: seed 3's 2).
    assert representative_seed([*rows, run(3, 2.0)]) == 3
    assert representative_seed([run(0, 1.0, "ml")]) is None


def test_seed_summaries_by_hand():
    base = rows_of_cell(HAND_ROWS, BASE)
    known, ml, mm_nh = seed_summaries(base, HAND_CONFIG.methods)
    # ML's translation RMSE 7, 11, 13: a resample's mean is 7 or 13 with probability 1/27 each
    # (> 2.5 %), so the interval spans the data.
    assert ml.estimates["translation_rmse"] == Estimate(pytest.approx(31 / 3), 7.0, 13.0, 3)
    assert (ml.median_translation_rmse, ml.worst_translation_rmse) == (11.0, 13.0)
    assert ml.estimates["switches"] == Estimate(pytest.approx(1.0), 0.0, 2.0, 3)
    assert ml.estimates["one_to_one_wrong"] is None  # no run recorded it
    assert mm_nh.runs == 2 and mm_nh.worst_translation_rmse == 3.5
    assert known.runtime_s == pytest.approx(1.5)  # a mean: round-off
    # Known DA 1, 2, 3 allow 2.0, 3.5, 5.0: MM + NH's 2.5 is not near, its 3.5 just is; ML's
    # 7, 11, 13 none.
    assert (mm_nh.near_reference, ml.near_reference, known.near_reference) == ((1, 2), (0, 3), None)
    compared = dict(comparisons(base, HAND_CONFIG.methods))
    # MM + NH 2.5, 3.5 against ML 7, 11 (seed 2 has no MM + NH run) and Known 1, 2.
    assert (compared["ml"].pairs, compared["ml"].wins, compared["ml"].losses) == (2, 2, 0)
    assert compared["ml"].sign_p == pytest.approx(0.5)
    assert compared["ml"].wilcoxon_p == pytest.approx(0.5)
    assert (compared["known"].wins, compared["known"].losses) == (0, 2)
    assert comparisons([r for r in base if r.method != "mm-nh"], HAND_CONFIG.methods) == []


def test_near_reference_counts_the_seeds_both_have():
    ours = {("a", 0): 2.0, ("a", 1): 2.01, ("a", 2): 9.0, ("b", 0): 0.4}
    reference = {("a", 0): 1.0, ("a", 1): 1.0, ("b", 0): 0.0, ("c", 0): 1.0}
    # 1.5 * 1 + 0.5 = 2: 2.0 near, 2.01 not; 0.4 within the 0.5 m margin of 0; ("a", 2) and
    # ("c", 0) are not shared
    assert near_reference(ours, reference) == (2, 3)
    assert near_reference(ours, {("d", 0): 1.0}) is None


def with_one_to_one(row: ResultRow, wrong: int, missed: int, per_true: float) -> ResultRow:
    return replace(row, one_to_one_wrong=wrong, one_to_one_null=missed, landmarks_per_true=per_true)


def test_cell_tables_and_summary_lines_by_hand():
    rows = list(HAND_ROWS)
    # ML at the base cell with the one-to-one scores of newer runs: wrong 4, 4, 4; missed 1
    # on one run only (the others made before it was recorded).
    rows[3] = with_one_to_one(rows[3], 4, 1, 1.5)
    rows[4] = replace(rows[4], one_to_one_wrong=4)
    rows[5] = replace(rows[5], one_to_one_wrong=4)
    tables = render_tables(HAND_CONFIG, rows)
    section = tables[tables.index("### `noise1-mis0.1`") :]
    assert (
        "| ML | 3 | 10.33 [7.00, 13.00] | 11.00 | 13.00 | 0 / 3 | 0.2200 [0.1200, 0.3200] "
        "| 4.0 [4.0, 4.0] | 1.0 | 1.50 | 0.0 [0.0, 0.0] | 1.0 [0.0, 2.0] | 1.5 |"
    ) in section
    assert "| MM + NH | 2 | 3.00 [2.50, 3.50] | 3.00 | 3.50 | 1 / 2 |" in section
    assert "| Known DA | 3 | 2.00 [1.00, 3.00] | 2.00 | 3.00 | - |" in section
    assert "| Known DA | 2 | 0 | 0 | 2 | 0.5 | 0.5 |" in section
    assert "| ML | 2 | 2 | 0 | 0 | 0.5 | 0.5 |" in section
    # The noisy cell: MM + NH has no run there, so no paired table follows it.
    noisy = tables[tables.index("### `noise4-mis0.1`") :]
    assert "| ML | 2 | 30.00 [20.00, 40.00] | 30.00 | 40.00 |" in noisy
    assert "MM + NH vs" not in noisy
    # Over every run: ML 7, 11, 13, 40, 20 against MM + NH 2.5, 3.5 on the two runs both have.
    lines = {h.method: headline_text(h) for h in headlines(rows, HAND_CONFIG.methods)}
    assert lines["mm-nh"] == (
        "MM + NH: translation RMSE 3.00 [2.50, 3.50] m over 2 run(s); "
        "against ML on the same 2: wins 2, ties 0, losses 0"
    )
    assert lines["ml"].startswith("ML: translation RMSE 18.20 [") and "against" not in lines["ml"]
    assert lines["known"].endswith("on the same 5: wins 5, ties 0, losses 0")


# --- results.csv: the newer metrics, and runs and files from before them ----------------------

NEW_METRICS = {
    "method": "mm-nh",
    "num_poses": 10,
    "num_detections": 6,
    "num_landmarks": 4,
    "runtime_s": 0.5,
    "translation_error_m": {"max": 2.0, "mean": 1.0, "median": 1.0, "rmse": 1.25},
    "rotation_error_rad": {"max": 0.2, "mean": 0.1, "median": 0.1, "rmse": 0.125},
    "association": {"correct": 4, "wrong": 1, "null": 1, "unlabelled": 0},
    "association_one_to_one": {
        "correct": 3,
        "wrong": 2,
        "null": 1,
        "precision": 0.6,
        "recall": 0.5,
        "false_positives_used": 0,
        "true_landmarks_seen": 3,
        "landmarks_per_true": 1.333333,
    },
    "switches": 2,
    "merges": 1,
    "solver_fallbacks": {"batch": 3, "qr": 0},
    "noise_scales": {
        "odometry": {
            "roll": 1.0,
            "pitch": 1.0,
            "yaw": 4.5,
            "forward": 1.0,
            "lateral": 0.8,
            "vertical": 1.0,
        },
        "measurement": {"bearing": 1.0, "elevation": 0.5, "range": 2.0},
        "moves": [
            {"pose_index": 50, "source": "drift windows", "scales": {}},
            {"pose_index": 200, "source": "detections", "scales": {}},
        ],
    },
}


def test_rows_carry_the_newer_metrics_and_leave_them_empty_for_older_runs(tmp_path):
    assert {
        "one_to_one_correct",
        "one_to_one_wrong",
        "one_to_one_null",
        "one_to_one_precision",
        "one_to_one_recall",
        "landmarks_per_true",
        "false_positives_used",
        "true_landmarks_seen",
        "merges",
        "variance_scale_roll",
        "variance_scale_pitch",
        "variance_scale_yaw",
        "variance_scale_forward",
        "variance_scale_lateral",
        "variance_scale_vertical",
        "variance_scale_bearing",
        "variance_scale_elevation",
        "variance_scale_range",
        "noise_moves",
        "fallbacks_batch",
        "fallbacks_qr",
    } == OPTIONAL
    key = RunKey(Cell(1.0, 0.1), 3, "mm-nh")
    row = row_from_metrics(key, NEW_METRICS)
    assert (row.one_to_one_correct, row.one_to_one_wrong, row.one_to_one_null) == (3, 2, 1)
    # 3 / 5 and 3 / 6, computed: equal to round-off
    assert (row.one_to_one_precision, row.one_to_one_recall) == pytest.approx((0.6, 0.5))
    assert (row.landmarks_per_true, row.false_positives_used, row.true_landmarks_seen) == (
        1.333333,
        0,
        3,
    )
    assert (row.merges, row.switches) == (1, 2)
    assert (row.variance_scale_yaw, row.variance_scale_lateral) == (4.5, 0.8)
    scales = (row.variance_scale_bearing, row.variance_scale_elevation, row.variance_scale_range)
    assert scales == (1.0, 0.5, 2.0)
    assert row.noise_moves == 2
    assert (row.fallbacks_batch, row.fallbacks_qr) == (3, 0)
    older = {
        k: v
        for k, v in NEW_METRICS.items()
        if k not in ("association_one_to_one", "merges", "solver_fallbacks")
    }
    older["noise_scales"] = {"odometry": "n/a"}
    old = row_from_metrics(key, older)
    assert all(getattr(old, c) is None for c in OPTIONAL)
    assert old.translation_rmse == row.translation_rmse and old.switches == 2
    # Written and read back: an empty field for what an older run did not record.
    path = tmp_path / "results.csv"
    path.write_text(results_text([row, old]))
    assert read_results(path) == [row, old]
    assert path.read_text().splitlines()[2].endswith("," * len(OPTIONAL))


def test_a_results_file_from_before_the_newer_columns_is_read(tmp_path):
    path = tmp_path / "results.csv"
    required = [c for c in COLUMNS if c not in OPTIONAL]
    old = HAND_ROWS[0]
    cut = [line.split(",")[: len(required)] for line in results_text([old]).splitlines()]
    assert cut[0] == required  # the optional columns come last
    path.write_text("\n".join(",".join(line) for line in cut) + "\n")
    assert read_results(path) == [old]
    # A required column stays required, and an optional one must still be a number.
    path.write_text(",".join(c for c in COLUMNS if c != "seed") + "\n")
    with pytest.raises(InputError, match="missing column 'seed'"):
        read_results(path)
    header, line = results_text([old]).splitlines()
    values = line.split(",")
    values[COLUMNS.index("merges")] = "two"
    path.write_text(f"{header}\n{','.join(values)}\n")
    with pytest.raises(InputError, match="line 2: 'merges' must be int"):
        read_results(path)


def test_the_slowest_run_is_measured_against_its_own_cell_and_methods_median():
    def timed(cell, method, seed, runtime_s):
        zeros = {f.name: 0 for f in fields(ResultRow) if f.default is MISSING}
        return ResultRow(**{**zeros, "cell": cell, "method": method, "seed": seed,
                            "runtime_s": runtime_s})  # fmt: skip

    rows = [timed("a", "known", s, t) for s, t in enumerate([1.0, 1.0, 2.5])]  # 2.5x
    rows += [timed("a", "mm-nh", s, t) for s, t in enumerate([10.0, 30.0, 12.0])]  # 2.5x too
    rows += [timed("b", "mm-nh", s, t) for s, t in enumerate([4.0, 13.0, 5.0])]  # 2.6x
    rows += [timed("c", "ml", 0, 100.0)]  # one seed: no median to measure against
    slowest = slowest_run(rows)
    assert (slowest.cell, slowest.method, slowest.seed) == ("b", "mm-nh", 1)
    assert slowest.ratio == pytest.approx(13.0 / 5.0)
    assert slowest_run(rows[-1:]) is None
