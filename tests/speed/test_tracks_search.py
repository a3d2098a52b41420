"""The Tab. 3 search finds the largest track count that holds a target FPS by measuring, not guessing."""

import pytest

from d4rt.speed.tracks import max_tracks_at_fps


class FakeRun:
    """A pipeline whose wall time is exactly encode_s + n * per_track_s (no clock involved)."""

    def __init__(self, frames, encode_s, per_track_s):
        self.frames, self.encode_s, self.per_track_s = frames, encode_s, per_track_s
        self.asked = []

    def seconds(self, n, repeats):
        self.asked.append(n)
        return self.encode_s + n * self.per_track_s


@pytest.mark.parametrize("guess_factor", [0.3, 1.0, 3.0])  # the throughput estimate low, right, high
@pytest.mark.parametrize("fps", [60, 24, 10, 1])
def test_finds_the_largest_count_within_tolerance(fps, guess_factor):
    run = FakeRun(frames=48, encode_s=0.1, per_track_s=1e-4)
    truth = int((48 / fps - 0.1) / 1e-4 + 1e-9)
    rate = guess_factor * 48 / 1e-4  # track queries per second the guess is made from
    result = max_tracks_at_fps(run, fps, rate, tolerance=0.02, max_trials=30)
    assert result["bracketed"]
    assert truth * 0.98 - 1 <= result["tracks"] <= truth  # it held when measured, and is within tolerance
    assert all(t["holds"] == (t["seconds"] <= 48 / fps) for t in result["trials"])
    assert run.asked[0] == 0  # the encoder alone is measured first


def test_zero_when_the_encoder_alone_is_too_slow():
    run = FakeRun(frames=8, encode_s=1.0, per_track_s=1e-3)
    result = max_tracks_at_fps(run, 60, 1e6, tolerance=0.02, max_trials=10)
    assert result["tracks"] == 0 and run.asked == [0]


def test_counts_grow_as_the_target_fps_falls():
    counts = [max_tracks_at_fps(FakeRun(24, 0.05, 2e-5), fps, 1e6, 0.05, 20)["tracks"] for fps in (60, 24, 10, 1)]
    assert counts == sorted(counts) and counts[0] < counts[-1]
