"""Review of the commands that make data and weights (`simulate`, `train`, `train-detector`) and of
loading what they write: results that were silently wrong, and failures that did not say what to do."""

from __future__ import annotations

import warnings

import pytest

from geofeat.cli import main

TINY = ["--frames", "2", "--width", "64", "--height", "48", "--no-progress", "--texture", "procedural"]


class _Stop(Exception):
    """Raised by a patched step to end a run once its checks are done."""


def _stop(*args, **kwargs):
    raise _Stop


def test_sequences_simulated_with_the_same_seed_are_not_held_out(tmp_path, monkeypatch):
    """`geofeat simulate` without --seed uses seed 0 every time: three runs into train/a, train/b and
    val/c write the same frames three times. Validation on c then scored the training data (no warning:
    the folders differ), and `train` drew a's and b's copies of one point as each other's negatives."""
    import geofeat.train.dataset as dataset
    import geofeat.train.detector as detector

    for name in ("train/a", "train/b", "val/c", "val/d"):
        seed = ["--seed", "5"] if name == "val/d" else []
        assert main(["simulate", str(tmp_path / name), *TINY, *seed]) == 0
    monkeypatch.setattr(dataset, "build_patch_set", _stop)
    monkeypatch.setattr(detector, "collect", _stop)
    for command, out in (("train", "w.pt"), ("train-detector", "k.npz")):
        with pytest.warns(UserWarning) as caught, pytest.raises(_Stop):
            main([command, "--data", str(tmp_path / "train"), "--val", str(tmp_path / "val"),
                  "--out", str(tmp_path / out)])
        text = " | ".join(str(w.message) for w in caught)
        assert "--data: " in text and "hold the same frames" in text and "--seed" in text, text
        assert "--val: " in text and "c (= " in text and "not held out" in text, text
        assert "val/d" not in text, text  # its own seed: held out
    with pytest.raises(_Stop), warnings.catch_warnings():  # sequences of their own: no warning
        warnings.filterwarnings("error", message=".*(held out|same frames)")
        main(["train", "--data", str(tmp_path / "train" / "a"), "--val", str(tmp_path / "val" / "d"),
              "--out", str(tmp_path / "w2.pt")])
