"""The log writer refuses what no reader would accept, before it is written, naming where
(`log/writer.py`): metadata that breaks the contract, a message that does (by its index on its
topic), a non-finite number, and on closing what only the whole log shows; a refused log is
not left behind."""

import pytest

from pipeline.errors import InputError
from pipeline.log import Detection, Detections, LogMetadata, LogWriter, Odometry

I3 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
I6 = tuple(float(i == j) for i in range(6) for j in range(6))
METADATA = LogMetadata(2, ((0.9, 0.1), (0.2, 0.8)), ("car", "van"), "tests")


def step(k: int, stamp: int) -> Odometry:
    return Odometry(stamp, k, k + 1, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), I6)


def test_metadata_that_breaks_the_contract_is_refused(tmp_path):
    bad = LogMetadata(2, ((0.9, 0.2), (0.2, 0.8)), ("car", "van"), "tests")  # a row sums to 1.1
    with pytest.raises(InputError, match=r"not writing .*a\.mcap: metadata 'mmslam'"):
        LogWriter(tmp_path / "a.mcap", bad)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("bad_step", [1, 2, 3])
def test_a_message_that_breaks_the_contract_is_refused_by_its_index(tmp_path, bad_step):
    """The odometry's steps 0, 1, ... in order, and step `bad_step` with a stamp before the
    previous one's."""
    with pytest.raises(InputError, match=rf"/odometry message {bad_step}: stamp_ns"):  # noqa: SIM117
        with LogWriter(tmp_path / "a.mcap", METADATA) as w:
            for k in range(bad_step):
                w.write(step(k, 10 * (k + 1)))
            w.write(step(bad_step, 5))
    assert not (tmp_path / "a.mcap").exists()


def test_a_non_finite_number_is_refused_by_its_index(tmp_path):
    with pytest.raises(InputError, match=r"/odometry message 1: holds a non-finite number"):  # noqa: SIM117
        with LogWriter(tmp_path / "a.mcap", METADATA) as w:
            w.write(step(0, 10))
            w.write(Odometry(20, 1, 2, (float("nan"), 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), I6))
    assert not (tmp_path / "a.mcap").exists()


def test_what_only_the_whole_log_shows_is_refused_on_closing(tmp_path):
    """Detections at pose 5, which the odometry (one step) never reaches."""
    detection = Detection(0, 0.9, 0.0, 0.0, 1.0, I3, "bbox")
    with pytest.raises(InputError, match=r"pose_index 5 is not reached"):  # noqa: SIM117
        with LogWriter(tmp_path / "a.mcap", METADATA) as w:
            w.write(step(0, 10))
            w.write(Detections(50, 5, (detection,)))
    assert not (tmp_path / "a.mcap").exists()
