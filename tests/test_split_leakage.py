"""Held-out splits stay held out: no training or validation scene replays a test scene (seeds), the
texture splits are disjoint, and `geofeat retrieval` chooses K on other objects than it tests on."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmark_scripts import import_benchmarks
from geofeat.apps.retrieval import split_queries


@pytest.fixture(scope="module")
def scripts():
    """The benchmark scripts make_sim_datasets and sim_difficulty, imported from benchmarks/."""
    return tuple(import_benchmarks("make_sim_datasets", "sim_difficulty"))


def difficulty_seeds(seed0: int = 5000, per_scenario: int = 10) -> set[int]:
    """The seeds sim_difficulty.py gives its test sequences (seed0 + 100 i + scenario index), as
    documented in its code, for up to `per_scenario` sequences per scenario."""
    return {seed0 + 100 * i + s for i in range(per_scenario) for s in range(3)}


def recorded_seeds(mod, monkeypatch, tmp_path, split, count, seed0, textures=None) -> list[int]:
    """Seeds make_sim_datasets.make would simulate `split` with (simulate_sequence replaced by a recorder)."""
    seen = []
    monkeypatch.setattr(mod, "simulate_sequence", lambda folder, **kw: seen.append(int(kw["seed"])))
    mod.make(split, count, tmp_path, 8, seed0, textures, ("paper", "hard", "mild"))
    return seen


def test_training_never_replays_a_test_scene(scripts, monkeypatch, tmp_path):
    """GeoPatch v8's training set out/sim3 was `make_sim_datasets.py --train 72 --seed 5000`: seeds
    5000-5071, whose first three (paper deform / rotate / scale, 8 frames) are the seeds, preset,
    scenario and length of the test sequences out/difficulty/paper/{deform,rotate,scale}-0, so the
    same cloth, wind, lights and camera path under another photograph. Disjointness held only for
    the default --seed. Now a train or val seed in the reserved test seeds is refused."""
    msd, sd = scripts
    with pytest.raises(ValueError, match="reserved"):
        seeds = recorded_seeds(msd, monkeypatch, tmp_path, "train", 72, 5000)
        assert not set(seeds) & difficulty_seeds(), "training seeds replay test scenes"
    with pytest.raises(ValueError, match="reserved"):  # val of --seed 4000 is 5000-5003
        recorded_seeds(msd, monkeypatch, tmp_path, "val", 4, 4000, textures=[Path("x.jpg")])
    # a split larger than its block ran into the next split's seeds (train 1000 + 1500 = val's 2000-)
    with pytest.raises(ValueError, match="at most 1000"):
        recorded_seeds(msd, monkeypatch, tmp_path, "train", 1500, 1000)


@pytest.mark.parametrize("seed0", [0, 1000, 2000, 3000, 3999, 6000, 8000])
def test_allowed_train_and_val_seeds_avoid_every_test_seed(scripts, monkeypatch, tmp_path, seed0):
    """For any --seed make_sim_datasets accepts, its train and val seeds are disjoint from each
    other, from its own test split, and from every seed sim_difficulty.py may use (it refuses
    seeds outside the reserved range)."""
    msd, sd = scripts
    splits = {}
    for split, count in (("train", 1000), ("val", 1000), ("test", 6)):
        try:
            splits[split] = set(recorded_seeds(msd, monkeypatch, tmp_path / split, split, count, seed0,
                                               None if split == "train" else [Path("x.jpg")]))
        except ValueError:
            splits[split] = None  # refused: nothing simulated
    assert splits["train"] is None or not splits["train"] & set(sd.TEST_SEEDS)
    assert splits["val"] is None or not splits["val"] & set(sd.TEST_SEEDS)
    if splits["train"] and splits["val"]:
        assert not splits["train"] & splits["val"] and not splits["train"] & splits["test"]
    # every seed sim_difficulty.py hands out is a reserved test seed, or it refuses
    for seed0_test in (5000, 5050, 4990, 5900, 6000):
        for i in range(12):
            try:
                assert sd.scene_seed(seed0_test, i, "scale") in sd.TEST_SEEDS
            except ValueError:
                assert seed0_test + 100 * i + 2 not in sd.TEST_SEEDS


def test_documented_splits_are_disjoint(scripts, monkeypatch, tmp_path):
    """The documented training sets that remain allowed (sim, sim2: --seed 1000; det: --train 36)
    and validation sets (det2: --seed 8000 --val 18) share no seed with the test sets."""
    msd, sd = scripts
    train = set(recorded_seeds(msd, monkeypatch, tmp_path / "a", "train", 36, 1000))
    val = set(recorded_seeds(msd, monkeypatch, tmp_path / "b", "val", 18, 8000, [Path("x.jpg")]))
    assert train == set(range(1000, 1036)) and val == set(range(9000, 9018))
    assert not (train | val) & difficulty_seeds()


def test_texture_splits_are_disjoint_and_deterministic(scripts):
    """Training draws the packaged photographs; validation the first N_VAL_TEXTURES of the shared
    photographs that are not packaged (name order); test the rest. No name (stem) in two splits."""
    msd, sd = scripts
    if not sd.SHARED_TEXTURES.is_dir():
        pytest.skip("the project's shared texture folder is not here")
    from geofeat.sim.textures import list_textures, packaged_texture_dir

    train = {p.stem for p in list_textures(packaged_texture_dir())}
    held = msd.heldout_textures(sd.SHARED_TEXTURES)
    val = {p.stem for p in held[: sd.N_VAL_TEXTURES]}
    test = {p.stem for p in sd.test_textures(sd.SHARED_TEXTURES)}
    assert len(val) == sd.N_VAL_TEXTURES and test
    assert not train & val and not train & test and not val & test
    assert [p.stem for p in held] == sorted(p.stem for p in held)  # name order: the same split every run


def test_simulate_says_its_default_textures_are_trained_on():
    """`geofeat simulate` draws, by default, the textures the shipped weights were trained on; its help
    said only "a packaged photo", and a user's "held-out" test made that way was not held out."""
    import argparse

    from geofeat.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    text = " ".join(sub.choices["simulate"].format_help().split())
    assert "trained on" in text and "held-out" in text and "--texture-dir" in text


def test_retrieval_validation_and_test_halves_hold_different_objects():
    """K was chosen on a random half of the queries: with 3 sequences per object, a test query's own
    object almost always had a query in the validation half. Whole classes are split now."""
    classes = np.repeat([f"object-{i:02d}" for i in range(20)], 3)  # 60 queries, 3 per object
    for seed in range(5):
        val, test = split_queries(len(classes), seed, groups=classes)
        assert sorted(np.concatenate([val, test]).tolist()) == list(range(60))
        assert not set(classes[val]) & set(classes[test])
        assert len(set(classes[val])) == 10 and len(set(classes[test])) == 10
    one = np.array(["cloth", "cloth"])  # a single class: split query by query (nothing else to split by)
    val, test = split_queries(2, 0, groups=one)
    assert len(val) == 1 and len(test) == 1
    with pytest.raises(ValueError, match="groups"):
        split_queries(3, 0, groups=["a", "b"])


def test_a_folder_of_another_run_is_not_reused_as_this_one(scripts, monkeypatch, tmp_path):
    """make_sim_datasets.py keeps sequences already there, but only the one this run would simulate:
    a sequence of other settings, or of an earlier simulator, stops the run (it once passed for the
    new data, so figures were measured on sequences nobody asked for)."""
    mod, _ = scripts
    mod.make("val", 1, tmp_path, 2, 1000, None, ("mild",))
    (folder,) = (tmp_path / "val").iterdir()
    made = []
    with monkeypatch.context() as m:
        m.setattr(mod, "simulate_sequence", lambda folder, **kw: made.append(folder))
        mod.make("val", 1, tmp_path, 2, 1000, None, ("mild",))  # the same run: reused
        assert made == []
        with pytest.raises(SystemExit, match=r"n_frames 2 \(wanted 3\)"):
            mod.make("val", 1, tmp_path, 3, 1000, None, ("mild",))
        meta = json.loads((folder / "groundtruth.json").read_text())
        del meta["simulator_revision"]  # as written before revisions were recorded
        (folder / "groundtruth.json").write_text(json.dumps(meta))
        with pytest.raises(SystemExit, match="simulator revision 1"):
            mod.make("val", 1, tmp_path, 2, 1000, None, ("mild",))
        assert made == []
