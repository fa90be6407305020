"""The heatmap-detector trial (benchmarks/heatmap_detector_trial.py): its peak-position losses
reward what the protocol counts (the same peak, within a few pixels, in both views), and its cache
of loaded pairs is never read back for other sequences."""

from __future__ import annotations

import pytest

from benchmark_scripts import import_benchmarks

torch = pytest.importorskip("torch")


@pytest.fixture(scope="module")
def trial():
    return import_benchmarks("heatmap_detector_trial")[0]


def peaks(points, size=32):
    """(1, 1, size, size) heatmap, 0 with 1 at each (x, y)."""
    h = torch.zeros(1, 1, size, size)
    for x, y in points:
        h[0, 0, y, x] = 1.0
    return h


def lattice(shift=0, size=32, region=None):
    """A peak in every 8 x 8 cell at (2, 2) + (8i, 8j), moved `shift` px along x (inside `region`, a
    (stop_x, stop_y) corner, when given)."""
    return peaks([(x + (shift if region is None or (x < region[0] and y < region[1]) else 0), y)
                  for x in range(2, size, 8) for y in range(2, size, 8)], size)


def test_position_loss_grows_with_the_distance_between_the_two_peaks(trial):
    mask = torch.ones(1, 1, 32, 32)
    losses = [float(trial.position_loss(lattice(), lattice(d), mask, 8)) for d in (0, 1, 2)]
    assert losses[0] < 0.2
    assert losses[1] > losses[0] + 0.5 and losses[2] > losses[1] + 0.5


def test_position_loss_ignores_windows_that_are_not_wholly_visible(trial):
    moved = lattice(3, region=(16, 16))
    hidden = torch.ones(1, 1, 32, 32)
    hidden[..., :20, :20] = 0  # every window that holds a moved peak
    assert float(trial.position_loss(lattice(), moved, hidden, 8)) < 0.2
    assert float(trial.position_loss(lattice(), moved, torch.ones(1, 1, 32, 32), 8)) > 0.5


def test_peak_score_loss_asks_a_high_value_only_where_the_reference_has_a_peak_nearby(trial):
    mask = torch.ones(1, 1, 32, 32)
    warped = peaks([(10, 10)])  # the reference's one peak, in the target's pixels
    found_high = peaks([(11, 10)]) * 0.9 + 0.05  # the target's peak 1 px away, valued high
    found_low = peaks([(11, 10)]) * 0.1 + 0.05
    far_high = peaks([(20, 20)]) * 0.9 + 0.05  # a peak with no partner, valued high
    loss = lambda t: float(trial.peak_score_loss(t, warped, mask))  # noqa: E731
    assert loss(found_high) < loss(found_low)
    assert loss(far_high) > loss(found_high) + 1.0


def test_pairs_cache_is_read_back_only_for_the_folders_that_made_it(trial, monkeypatch, tmp_path):
    import numpy as np

    pair = (np.full((4, 6), 0.2, np.float32), np.full((4, 6), 0.6, np.float32),
            np.ones((4, 6, 2), np.float32), np.ones((4, 6), bool))
    monkeypatch.setattr(trial, "load_pairs", lambda folders, jobs=1: [pair] * len(folders))
    cache = str(tmp_path / "pairs.npz")
    made = trial.cached_pairs([tmp_path / "a", tmp_path / "b"], cache)
    monkeypatch.setattr(trial, "load_pairs", lambda folders, jobs=1: pytest.fail("the cache was not read"))
    again = trial.cached_pairs([tmp_path / "b", tmp_path / "a"], cache)  # the same folders, in any order
    assert len(again) == len(made) == 2
    assert all(np.allclose(x, y) for p, q in zip(made, again) for x, y in zip(p, q))
    with pytest.raises(SystemExit, match="other sequence folders"):
        trial.cached_pairs([tmp_path / "a", tmp_path / "c"], cache)
