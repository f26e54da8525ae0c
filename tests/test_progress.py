"""Progress without a terminal: a line every interval and one at the end, never a bar."""

import io

from pipeline.progress import Progress, progress_line, track


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_progress_line_reads_as_counts_and_percent():
    assert progress_line("replay ml", 120, 2761, "pose", 12.4) == (
        "replay ml: 120/2761 poses (4%), 12 s"
    )
    assert progress_line("sweep", 3, None, "run", 0.0) == "sweep: 3 runs, 0 s"


def test_without_a_terminal_a_line_every_interval_and_at_the_end():
    stream, clock = io.StringIO(), FakeClock()
    items = []
    for item in track(range(10), 10, "work", "frame", stream=stream, interval_s=5, clock=clock):
        items.append(item)
        clock.now += 2.0  # an item every 2 s: a line after items 3 and 6 (6 s, 12 s ... apart)
    assert items == list(range(10))
    lines = stream.getvalue().splitlines()
    assert lines == [
        "work: 3/10 frames (30%), 6 s",
        "work: 6/10 frames (60%), 12 s",
        "work: 9/10 frames (90%), 18 s",
        "work: 10/10 frames (100%), 20 s",
    ]
    assert "\r" not in stream.getvalue()


def test_a_last_line_that_showed_the_end_is_not_repeated():
    # `mmslam sweep`: its last run's update may print the last line itself.
    stream, clock = io.StringIO(), FakeClock()
    for _ in track(range(3), 3, "sweep", "run", stream=stream, interval_s=5, clock=clock):
        clock.now += 6.0  # a line after every item, the last one's included
    assert stream.getvalue().splitlines() == [
        "sweep: 1/3 runs (33%), 6 s",
        "sweep: 2/3 runs (66%), 12 s",
        "sweep: 3/3 runs (100%), 18 s",
    ]


def test_disabled_progress_prints_nothing():
    stream, clock = io.StringIO(), FakeClock()
    shown = Progress(4, "quiet", enabled=False, stream=stream, interval_s=0, clock=clock)
    for _ in range(4):
        clock.now += 10
        shown.update()
    shown.close()
    assert stream.getvalue() == ""


def test_a_run_too_short_for_a_line_stays_quiet():
    stream, clock = io.StringIO(), FakeClock()
    for _ in track(range(4), 4, "work", stream=stream, interval_s=5, clock=clock):
        clock.now += 1.0
    assert stream.getvalue() == ""


def test_no_last_line_after_a_failure():
    stream, clock = io.StringIO(), FakeClock()
    try:
        for _ in track(range(10), 10, "work", stream=stream, interval_s=5, clock=clock):
            raise RuntimeError("stop")
    except RuntimeError:
        pass
    assert stream.getvalue() == ""


def test_a_slow_item_beats_with_what_it_is_doing():
    stream, clock = io.StringIO(), FakeClock()
    shown = Progress(46, "replay mm-nh", "pose", stream=stream, interval_s=5, clock=clock)
    for _ in range(45):  # fast poses: no line
        shown.update()
    for step in range(1, 13):  # the last takes 12 s, its steps a second each
        clock.now += 1.0
        shown.beat(f"pose 45: step {step}")
    shown.update()
    shown.close()
    assert stream.getvalue().splitlines() == [
        "replay mm-nh: 45/46 poses (97%), 5 s; pose 45: step 5",
        "replay mm-nh: 45/46 poses (97%), 10 s; pose 45: step 10",
        "replay mm-nh: 46/46 poses (100%), 12 s",
    ]


def test_disabled_progress_does_not_beat():
    stream, clock = io.StringIO(), FakeClock()
    shown = Progress(2, "quiet", enabled=False, stream=stream, interval_s=0, clock=clock)
    clock.now += 10
    shown.beat("working")
    assert stream.getvalue() == ""
