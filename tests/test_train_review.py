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


def _warnings_of_both_trainers(monkeypatch, tmp_path, data, val) -> list[str]:
    """The warnings `train` and `train-detector` give, each as one text, for `--data data --val val`,
    stopped before any patch or candidate is made."""
    import geofeat.train.dataset as dataset
    import geofeat.train.detector as detector

    monkeypatch.setattr(dataset, "build_patch_set", _stop)
    monkeypatch.setattr(detector, "collect", _stop)
    texts = []
    for command, out in (("train", "w.pt"), ("train-detector", "k.npz")):
        with pytest.warns(UserWarning) as caught, pytest.raises(_Stop):
            main([command, "--data", str(data), "--val", str(val), "--out", str(tmp_path / out)])
        texts.append(" | ".join(str(w.message) for w in caught))
    return texts


def test_sequences_simulated_with_the_same_seed_are_not_held_out(tmp_path, monkeypatch):
    """`geofeat simulate` without --seed uses seed 0 every time: three runs into train/a, train/b and
    val/c write the same frames three times. Validation on c then scored the training data (no warning:
    the folders differ), and `train` drew a's and b's copies of one point as each other's negatives."""
    for name in ("train/a", "train/b", "val/c", "val/d"):
        seed = ["--seed", "5"] if name == "val/d" else []
        assert main(["simulate", str(tmp_path / name), *TINY, *seed]) == 0
    for text in _warnings_of_both_trainers(monkeypatch, tmp_path, tmp_path / "train", tmp_path / "val"):
        assert "--data: " in text and "hold the same frames" in text and "--seed" in text, text
        assert "--val: " in text and "c (= " in text and "not held out" in text, text
        assert "val/d" not in text, text  # its own seed: held out
    with pytest.raises(_Stop), warnings.catch_warnings():  # sequences of their own: no warning
        warnings.filterwarnings("error", message=".*(held out|same frames)")
        main(["train", "--data", str(tmp_path / "train" / "a"), "--val", str(tmp_path / "val" / "d"),
              "--out", str(tmp_path / "w2.pt")])


def _patches():
    import numpy as np

    from geofeat.train.dataset import PatchSet

    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (40, 32, 32)).astype(np.uint8)
    noisy = np.clip(base.astype(int) + rng.integers(-10, 11, base.shape), 0, 255).astype(np.uint8)
    return PatchSet(np.concatenate([base, noisy]), np.concatenate([np.arange(40), np.arange(40)]))


def test_a_diverged_training_stops_and_nan_weights_are_refused_on_loading(tmp_path):
    """--lr 1e6 turned the loss NaN after a few steps; training went on and wrote NaN weights (the
    run printed 'final loss nan' and exit 0), which `bench --descriptors geopatch=W.pt` then failed on
    in every sequence with 'features0 has NaN or infinite values', naming neither the weights nor --lr."""
    import torch

    from geofeat import make_descriptor
    from geofeat.descriptors.geopatch import GeoPatchConfig, GeoPatchNet, load_network, save_checkpoint
    from geofeat.train.loop import TrainConfig, train

    net = GeoPatchConfig(channels=(4, 8, 8), dim=16)
    with pytest.raises(ValueError, match=r"lr: training diverged at epoch \d+, step \d+ .*smaller learning rate.*--lr"):
        train(_patches(), tmp_path / "w.pt", TrainConfig(epochs=3, steps_per_epoch=5, batch_size=16, lr=1e6, net=net),
              progress=False, device="cpu")
    assert not (tmp_path / "w.pt").exists()
    bad = GeoPatchNet(net)
    with torch.no_grad():
        next(bad.parameters())[0] = float("nan")
    save_checkpoint(tmp_path / "nan.pt", bad)
    for load in (lambda: load_network(tmp_path / "nan.pt"), lambda: make_descriptor(f"geopatch={tmp_path / 'nan.pt'}")):
        with pytest.raises(ValueError, match=r"nan\.pt holds NaN or infinite weights.*--lr"):
            load()
    # a run that trains well is unchanged
    history = train(_patches(), tmp_path / "ok.pt", TrainConfig(epochs=1, steps_per_epoch=3, batch_size=16, net=net),
                    progress=False, device="cpu")
    assert len(history["loss"]) == 1 and load_network(tmp_path / "ok.pt")[0].config == net


def test_bench_reads_descriptor_weights_once_before_any_sequence(tmp_path, capsys):
    """A truncated (or foreign) --descriptors geopatch=W.pt failed in every sequence in turn ('FAILED
    a: ...', 'FAILED b: ...') after config.json and results.csv were started; a --detector
    geokey=W file was already refused before any work."""
    from geofeat.descriptors.geopatch import GeoPatchConfig, GeoPatchNet, save_checkpoint

    for name in ("a", "b"):
        assert main(["simulate", str(tmp_path / "seqs" / name), *TINY, "--seed", str(ord(name))]) == 0
    save_checkpoint(tmp_path / "w.pt", GeoPatchNet(GeoPatchConfig(channels=(4, 8, 8), dim=16)))
    (tmp_path / "trunc.pt").write_bytes((tmp_path / "w.pt").read_bytes()[:3000])
    capsys.readouterr()
    code = main(["bench", str(tmp_path / "seqs"), "--descriptors", f"geobit,geopatch={tmp_path / 'trunc.pt'}",
                 "--out", str(tmp_path / "bench"), "--keypoints", "50"])
    err = capsys.readouterr().err
    assert code == 2 and "trunc.pt is not a GeoPatch checkpoint" in err and "FAILED" not in err, err
    assert not (tmp_path / "bench" / "results.csv").exists()


def test_geopatch_weights_given_as_a_detector_are_named_as_such(tmp_path):
    """`--detector geokey=geopatch.pt` said 'not a GeoKey weights file for this version (cues ()...,
    expected ('level', ...))', as if the file were GeoKey weights of an older geofeat."""
    import numpy as np

    from geofeat.descriptors.geopatch import GeoPatchConfig, GeoPatchNet, save_checkpoint
    from geofeat.detectors.geokey import load_geokey

    save_checkpoint(tmp_path / "geopatch.pt", GeoPatchNet(GeoPatchConfig(channels=(4, 8, 8), dim=16)))
    with pytest.raises(ValueError, match=r"geopatch\.pt holds PyTorch weights.*--descriptors geopatch=PATH"):
        load_geokey(tmp_path / "geopatch.pt")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match=r"other\.npz is not a GeoKey weights file \(no cue_names array\)"):
        load_geokey(tmp_path / "other.npz")


@pytest.mark.parametrize("extra", [["--channels", "8", "8", "8"], ["--no-angle-pool"], ["--depth-profile", "clean"]])
def test_train_refuses_geopatch_options_with_an_image_patch_net(extra, tmp_path, capsys):
    """`train --net tfeat --channels 8 8 8` (or --no-angle-pool, --depth-profile) trained the fixed
    tfeat network on image patches, the option silently ignored."""
    code = main(["train", "--data", str(tmp_path), "--out", str(tmp_path / "w.pt"), "--net", "tfeat", *extra])
    err = capsys.readouterr().err
    assert code == 2 and f"error: {extra[0]}: GeoPatch's options" in err and "--net tfeat" in err, err
    assert not (tmp_path / "w.pt").exists()


def test_train_on_too_few_points_says_what_to_do_and_leaves_no_cache(tmp_path, capsys):
    """`--keypoints 1` (or a tiny sequence) gave 'data: need at least 2 surface points ...' after
    writing OUT.patches.npz, so the rerun with more keypoints was refused over that cache ('exists;
    pass --resume ... or --overwrite'); the count read '2 of 1 surface points'."""
    assert main(["simulate", str(tmp_path / "seq"), *TINY]) == 0
    capsys.readouterr()
    base = ["train", "--data", str(tmp_path / "seq"), "--out", str(tmp_path / "w.pt"), "--epochs", "1", "--steps", "1",
            "--batch-size", "4", "--channels", "4", "4", "4", "--device", "cpu"]
    assert main([*base, "--keypoints", "1"]) == 2
    err = capsys.readouterr().err
    assert "error: --data: 1 surface point seen in 2 frames or more" in err and "raise --keypoints (1 now)" in err, err
    assert not list(tmp_path.glob("w.pt*"))
    assert main([*base, "--keypoints", "8"]) == 0
    out = capsys.readouterr().out
    assert "training patches: " in out and " surface points (cached in" in out, out


def test_motion_blur_with_a_preset_that_has_none_is_refused(tmp_path, capsys):
    """`simulate --motion-blur` with the default mild preset blurred nothing (mild's longest blur is
    0 px) and wrote "motion_blur": true into groundtruth.json."""
    from geofeat.sim import simulate_sequence

    assert main(["simulate", str(tmp_path / "m"), *TINY, "--motion-blur"]) == 2
    err = capsys.readouterr().err
    assert "error: --motion-blur: the mild preset has no motion blur; add --preset paper" in err, err
    with pytest.raises(ValueError, match="motion_blur: the mild preset has no motion blur"):
        simulate_sequence(tmp_path / "m", n_frames=2, width=64, height=48, progress=False, motion_blur=True)
    assert not (tmp_path / "m").exists()


def test_train_says_when_its_val_sequences_give_no_pair(tmp_path, monkeypatch, capsys):
    """--val sequences without a scorable pair trained without validation, saying only 'no
    validation pairs' per epoch and 'validation MS nan' at the end."""
    import geofeat.train.dataset as dataset
    import geofeat.train.loop as loop

    for name, seed in (("data", "1"), ("val", "2")):
        assert main(["simulate", str(tmp_path / name), *TINY, "--seed", seed]) == 0
    monkeypatch.setattr(dataset, "validation_pairs", lambda *a, **k: [])
    monkeypatch.setattr(dataset, "build_patch_set", lambda *a, **k: _patches())
    monkeypatch.setattr(loop, "train", lambda *a, **k: {"loss": [0.5], "val_ms": [float("nan")]})
    capsys.readouterr()
    with pytest.warns(UserWarning, match="--val: no pair of these sequences could be scored"):
        assert main(["train", "--data", str(tmp_path / "data"), "--val", str(tmp_path / "val"),
                     "--out", str(tmp_path / "w.pt")]) == 0
    out = capsys.readouterr().out
    assert "no validation pairs in --val" in out and "nan" not in out, out


def test_train_detector_refuses_a_keypoint_count_given_twice(tmp_path, capsys):
    """`--keypoints 1024 1024` scored 1024 once and reported 'chosen by the mean validation MS at
    1024, 1024 keypoints per frame'."""
    code = main(["train-detector", "--data", str(tmp_path), "--val", str(tmp_path), "--out", str(tmp_path / "k.npz"),
                 "--keypoints", "100", "200", "100"])
    err = capsys.readouterr().err
    assert code == 2 and "error: --keypoints: 100 given twice" in err, err


def test_weights_of_another_network_name_the_descriptor_they_belong_to(tmp_path):
    """`train --net tfeat` weights given as geopatch=W.pt, or GeoPatch weights as tfeat-sim=W.pt, said
    'not a GeoPatch checkpoint (TypeError: GeoPatchConfig.__init__() got an unexpected keyword
    argument 'arch')', not which descriptor they are for."""
    from geofeat import make_descriptor
    from geofeat.descriptors.geopatch import GeoPatchConfig, GeoPatchNet, save_checkpoint
    from geofeat.descriptors.image_patch_nets import ImagePatchNet, default_config

    save_checkpoint(tmp_path / "geopatch.pt", GeoPatchNet(GeoPatchConfig(channels=(4, 8, 8), dim=16)))
    save_checkpoint(tmp_path / "tfeat.pt", ImagePatchNet(default_config("tfeat")))
    with pytest.raises(ValueError, match=r"tfeat\.pt holds tfeat-sim weights .*not GeoPatch; name them tfeat-sim=PATH"):
        make_descriptor(f"geopatch={tmp_path / 'tfeat.pt'}")
    for name in ("tfeat-sim", "logpolar-sim"):
        with pytest.raises(ValueError, match=r"geopatch\.pt holds geopatch weights .*name them geopatch=PATH"):
            make_descriptor(f"{name}={tmp_path / 'geopatch.pt'}")


def test_an_interrupted_overwrite_run_leaves_no_earlier_weights_beside_its_checkpoint(tmp_path, monkeypatch, capsys):
    """`train --overwrite` stopped after its first epoch left the earlier run's w.pt (and w.pt.json,
    w.pt.png) beside its own w.pt.ckpt, to be taken for the new run's weights."""
    import geofeat.train.loop as loop

    assert main(["simulate", str(tmp_path / "sim"), *TINY]) == 0
    run = ["train", "--data", str(tmp_path / "sim"), "--out", str(tmp_path / "w.pt"), "--epochs", "2", "--steps", "1",
           "--batch-size", "8", "--keypoints", "50"]
    assert main(run) == 0
    assert (tmp_path / "w.pt").is_file() and (tmp_path / "w.pt.json").is_file()
    capsys.readouterr()
    write = loop.atomic_file
    written = []

    def stop_after_first_checkpoint(path):
        if written:
            raise KeyboardInterrupt
        written.append(path)
        return write(path)

    monkeypatch.setattr(loop, "atomic_file", stop_after_first_checkpoint)
    assert main(run + ["--overwrite"]) == 130
    assert written == [tmp_path / "w.pt.ckpt"]
    left = sorted(p.name for p in tmp_path.iterdir() if p.name != "sim")
    assert left == [".geofeat-manifest.json", "w.pt.ckpt", "w.pt.patches.npz"], left  # the manifest: train's files
    out = capsys.readouterr().out
    assert "removed the earlier run's" in out and "w.pt.json" in out
    monkeypatch.setattr(loop, "atomic_file", write)
    assert main(run + ["--resume"]) == 0  # the new run goes on from its own checkpoint
    assert (tmp_path / "w.pt").is_file()


def test_train_seeds_the_image_patch_nets_starting_weights(tmp_path, monkeypatch, capsys):
    """`train --net tfeat` built the network before `train` seeded torch, so its starting weights came
    from whatever torch had drawn before: two runs with one --seed in one process wrote different
    weights, and --seed did not choose the starting point of the image-patch baselines."""
    import torch

    import geofeat.train.imagepatches as imagepatches

    assert main(["simulate", str(tmp_path / "seq"), *TINY]) == 0
    monkeypatch.setattr(imagepatches, "build_image_patch_set", lambda *a, **k: _patches())
    base = ["train", "--data", str(tmp_path / "seq"), "--net", "tfeat", "--epochs", "1", "--steps", "1",
            "--batch-size", "4", "--device", "cpu"]
    weights = {}
    for name, seed in (("a", "3"), ("b", "3"), ("c", "4")):
        torch.rand(5)  # whatever the process drew before must not matter
        assert main([*base, "--seed", seed, "--out", str(tmp_path / f"{name}.pt")]) == 0
        weights[name] = torch.load(tmp_path / f"{name}.pt", weights_only=False)["state_dict"]
    for key, value in weights["a"].items():
        torch.testing.assert_close(weights["b"][key], value, rtol=0, atol=0, msg=key)
    assert any(not torch.equal(weights["c"][key], value) for key, value in weights["a"].items())


def test_train_refuses_a_val_flag_without_sequences(tmp_path, capsys):
    """`train --val --out w.pt` (an empty shell variable after --val) trained without validation,
    saying only "no --val sequences" at the end."""
    with pytest.raises(SystemExit) as stop:
        main(["train", "--data", str(tmp_path), "--val", "--out", str(tmp_path / "w.pt")])
    assert stop.value.code == 2 and "--val" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_keypoints_within_a_pixel_of_a_stronger_one_are_not_a_surface_point_of_their_own(tmp_path, monkeypatch):
    """SIFT finds one blob at two scales a fraction of a pixel apart (keypoint_set "unique" merges
    only equal positions): each got an id of its own, so `train` drew the other, nearly the same
    patch, as a negative (and --mining hardest always took it)."""
    import numpy as np

    import geofeat.train.dataset as dataset
    import geofeat.train.imagepatches as imagepatches
    from geofeat.io import read_sequence
    from geofeat.keypoints import Keypoints

    assert main(["simulate", str(tmp_path / "seq"), *TINY]) == 0
    seq = read_sequence(tmp_path / "seq")
    plain = dataset.sequence_patches(seq, 64)
    plain_image = imagepatches.sequence_image_patches(seq, "tfeat", 64)
    detect = dataset.detect

    def with_twins(frame, n, **options):  # each keypoint again, weaker, 0.4 px away
        k = detect(frame, n, **options)
        return Keypoints(np.concatenate([k.xy, k.xy + 0.4]), np.r_[k.angles, k.angles], np.r_[k.sizes, k.sizes],
                         np.r_[k.responses, k.responses - 1e-6])

    monkeypatch.setattr(dataset, "detect", with_twins)
    monkeypatch.setattr(imagepatches, "detect", with_twins)
    twins = dataset.sequence_patches(seq, 64)
    assert len(np.unique(plain.ids)) > 2
    assert np.array_equal(twins.ids, plain.ids) and np.array_equal(twins.patches, plain.patches)
    twins_image = imagepatches.sequence_image_patches(seq, "tfeat", 64)
    assert np.array_equal(twins_image.ids, plain_image.ids)


def test_fine_tuning_in_place_with_overwrite_keeps_the_starting_weights(tmp_path, capsys):
    """`train --init w.pt --out w.pt --overwrite` removed w.pt with the earlier run's files before
    `train` read it, then stopped with 'no GeoPatch checkpoint at w.pt': the user's weights were lost
    and nothing was trained. It is refused before any work, naming --init, and w.pt stays."""
    from geofeat.descriptors.geopatch import GeoPatchConfig, GeoPatchNet, save_checkpoint

    sim = tmp_path / "sim"
    assert main(["simulate", str(sim), *TINY]) == 0
    weights = tmp_path / "w.pt"
    save_checkpoint(weights, GeoPatchNet(GeoPatchConfig(channels=(4, 8, 8))))
    before = weights.read_bytes()
    capsys.readouterr()
    args = ["train", "--data", str(sim), "--epochs", "1", "--steps", "1", "--batch-size", "8", "--keypoints", "50",
            "--device", "cpu", "--overwrite"]
    assert main([*args, "--init", str(weights), "--out", str(weights)]) == 2
    assert "--init" in capsys.readouterr().err
    assert weights.read_bytes() == before
    assert not (tmp_path / "w.pt.patches.npz").exists()
    # the same file by another spelling, or as a file written beside OUT, is refused too
    other = tmp_path / "sub"
    other.mkdir()
    assert main([*args, "--init", str(other / ".." / "w.pt"), "--out", str(weights)]) == 2
    assert weights.read_bytes() == before


def test_training_patches_use_the_sequence_radius_as_every_command_does(tmp_path):
    """`train` cut its patches at 0.075 m whatever a sequence's geofeat.json said, while `bench`,
    `extract` and `train-detector` describe that sequence at its own radius (`inputs.resolve_radius`):
    a network trained on one scale of patch, then scored on another."""
    import json

    import numpy as np

    import geofeat.train.dataset as dataset
    from geofeat.geodesic.polar import polar_patches
    from geofeat.io import read_sequence

    assert main(["simulate", str(tmp_path / "seq"), *TINY]) == 0
    meta = tmp_path / "seq" / "geofeat.json"
    data = json.loads(meta.read_text())
    data["radius"] = 0.05
    meta.write_text(json.dumps(data))
    seq = read_sequence(tmp_path / "seq")
    assert seq.radius == 0.05
    own = dataset.sequence_patches(seq, 64)
    assert np.array_equal(own.patches, dataset.sequence_patches(seq, 64, radius=0.05).patches)
    assert not np.array_equal(own.patches, dataset.sequence_patches(seq, 64, radius=0.075).patches)
    pair = dataset.validation_pairs([tmp_path / "seq"], n_keypoints=64, max_pairs_per_sequence=1)[0]
    ref = seq.frame(seq.reference)
    k_ref = dataset.detect(ref, 64, detector="sift")
    expected = polar_patches(ref, k_ref.xy, radius=0.05, depth_config=dataset._sequence_config(seq, None, ref))
    np.testing.assert_array_equal(pair.ref_patches, expected.values)


@pytest.mark.parametrize("change, message", [
    (dict(seed=-1), "seed: expected a whole number >= 0"),  # numpy's "expected non-negative integer"
    (dict(seed=1.5), "seed: expected a whole number"),
    (dict(radii=()), "radii: expected one or more"),  # "max() arg is an empty sequence", after training
    (dict(radii=(float("nan"),)), "radii: expected a number >= 0"),
    (dict(hidden=(2.5,)), "hidden: expected positive whole layer widths"),  # a torch TypeError
    (dict(labels="found"), "labels: expected one of repeatable, matchable"),
])
def test_train_detector_options_are_checked_before_the_candidates_are_collected(change, message, tmp_path,
                                                                                monkeypatch):
    """A negative or fractional seed, no suppression radius, a fractional hidden width: train_detector
    collected every candidate (and fitted both scorers) before failing with numpy's, Python's or torch's
    words, which named no option."""
    import geofeat.train.detector as detector

    monkeypatch.setattr(detector, "collect", _stop)
    monkeypatch.setattr(detector, "check_simulated", lambda paths, what: [tmp_path])
    with pytest.raises(ValueError, match=message):
        detector.train_detector([tmp_path], [tmp_path], tmp_path / "k.npz", n=16, steps=5, progress=False, **change)
    assert not (tmp_path / "k.npz").exists()


@pytest.mark.parametrize("positives", ["none", "all"])
def test_train_detector_refuses_training_labels_all_of_one_kind(positives, tmp_path, monkeypatch):
    """When no candidate of --data was found again in another frame (or every one was), both scorers were
    fitted to one label, learned no ranking, and were written as trained weights without a word."""
    import numpy as np

    import geofeat.train.detector as detector
    from geofeat.detectors.cues import CUE_NAMES

    x = np.random.default_rng(0).normal(size=(200, len(CUE_NAMES))).astype(np.float32)
    y = np.full(200, 0.0 if positives == "none" else 1.0, np.float32)
    monkeypatch.setattr(detector, "check_simulated", lambda paths, what: [tmp_path / what])
    monkeypatch.setattr(detector, "warn_if_not_held_out", lambda *args: None)
    monkeypatch.setattr(detector, "collect", lambda *args, **kwargs: (x, y))
    monkeypatch.setattr(detector, "fit", _stop)
    which = "none" if positives == "none" else "every one"
    with pytest.raises(ValueError, match=f"--data: {which} of the 200 candidates is repeatable"):
        detector.train_detector([tmp_path], [tmp_path], tmp_path / "k.npz", n=16, steps=5, progress=False,
                                names=("--data", "--val"))
    assert not (tmp_path / "k.npz").exists()


def test_train_detector_says_when_validation_could_not_choose(tmp_path, monkeypatch):
    """Validation sequences on which no scorer and radius got a single correct match (MS 0 for every
    entry) left the choice to `max`'s first entry, written and reported as chosen by validation."""
    import numpy as np

    import geofeat.train.detector as detector
    from geofeat.detectors.cues import CUE_NAMES

    rng = np.random.default_rng(0)
    x = rng.normal(size=(200, len(CUE_NAMES))).astype(np.float32)
    y = (x[:, 0] > 0).astype(np.float32)
    zero = {"repeatability": 0.0, "ms": 0.0, "mma": 0.0, "hits": 0.0, "pairs": 0.0, "n_ref": 0.0}
    monkeypatch.setattr(detector, "check_simulated", lambda paths, what: [tmp_path / what])
    monkeypatch.setattr(detector, "warn_if_not_held_out", lambda *args: None)
    monkeypatch.setattr(detector, "collect", lambda *args, **kwargs: (x, y))
    monkeypatch.setattr(detector, "validation_scores", lambda *args, **kwargs: dict(zero))
    monkeypatch.setattr(detector, "frames_without_keypoints", lambda *args: ([], 1))  # no frames to read
    with pytest.warns(UserWarning, match=r"--val: no scorer and radius got a correct GeoPatch match .*arbitrary"):
        detector.train_detector([tmp_path], [tmp_path], tmp_path / "k.npz", n=16, steps=5, progress=False,
                                radii=(2.0, 3.0), names=("--data", "--val"))
    good = dict(zero, ms=0.5)
    monkeypatch.setattr(detector, "validation_scores", lambda *args, **kwargs: dict(good))
    with warnings.catch_warnings():  # a validation that scores: no warning
        warnings.filterwarnings("error", message=".*arbitrary")
        detector.train_detector([tmp_path], [tmp_path], tmp_path / "k2.npz", n=16, steps=5, progress=False,
                                radii=(2.0, 3.0), names=("--data", "--val"))


def test_validation_textured_with_a_training_image_is_not_held_out(tmp_path, monkeypatch):
    """`geofeat simulate` draws its default texture from the packaged photographs: a --val sequence of
    its own seed could show the very picture a --data sequence was trained on, and train and
    train-detector took it as held out without a word (only copies of the frames were warned of)."""
    from geofeat.sim.textures import packaged_texture_dir

    photos = packaged_texture_dir()
    shape = ["--frames", "2", "--width", "64", "--height", "48", "--no-progress"]
    for name, seed, texture in (("data/a", 1, "kodak_kodim23.jpg"), ("val/b", 2, "kodak_kodim23.jpg"),
                                ("val/c", 3, "scipy_ascent.jpg")):
        assert main(["simulate", str(tmp_path / name), *shape, "--seed", str(seed),
                     "--texture", str(photos / texture)]) == 0
    for text in _warnings_of_both_trainers(monkeypatch, tmp_path, tmp_path / "data", tmp_path / "val"):
        assert "--val: " in text and "b (kodak_kodim23.jpg, as " in text and "not held out in texture" in text, text
        assert "val/c" not in text, text  # a picture training never saw: held out
    with pytest.raises(_Stop), warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*held out")
        main(["train", "--data", str(tmp_path / "data"), "--val", str(tmp_path / "val" / "c"),
              "--out", str(tmp_path / "w2.pt")])


def test_resuming_another_networks_checkpoint_is_refused_before_the_patches(tmp_path, monkeypatch, capsys):
    """A GeoPatch run resumed with --net tfeat (or the reverse) has the same training settings, so when
    its patch cache was gone the checkpoint passed every check and was refused only by `train`, after
    the patches of every --data sequence had been built (minutes to hours)."""
    import geofeat.train.dataset as dataset
    import geofeat.train.imagepatches as imagepatches
    from geofeat.descriptors.geopatch import GeoPatchConfig
    from geofeat.train.loop import TrainConfig, train

    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=8, net=GeoPatchConfig(channels=(16, 32, 64)))
    train(_patches(), tmp_path / "w.pt", config, progress=False, device="cpu")  # as `train --steps 1 --batch-size 8`
    monkeypatch.setattr(dataset, "build_patch_set", _stop)
    monkeypatch.setattr(imagepatches, "build_image_patch_set", _stop)
    run = ["train", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "w.pt"), "--epochs", "1",
           "--steps", "1", "--batch-size", "8", "--resume"]
    assert main([*run, "--net", "tfeat"]) == 2
    err = capsys.readouterr().err
    assert "--resume: " in err and "w.pt.ckpt holds the weights of another network than --net tfeat" in err, err
    assert main(run) == 2  # its own network: on to the data checks, which find no --data folder
    err = capsys.readouterr().err
    assert "--data" in err and "--resume" not in err, err


def test_angle_shifts_are_refused_for_tfeats_cartesian_patches(tmp_path, capsys, monkeypatch):
    """`train --net tfeat --augment-shift` rolled the columns of TFeat's Cartesian image patches (the
    left edge wrapped around beside the right, a patch no keypoint gives) and trained on them without
    a word; the shift is a rotation only for polar patches (GeoPatch, logpolar)."""
    import geofeat.train.dataset as dataset
    from geofeat.descriptors.image_patch_nets import ImagePatchNet, default_config
    from geofeat.train.loop import TrainConfig, train

    monkeypatch.setattr(dataset, "check_simulated", _stop)  # the first step after the options are checked
    code = main(["train", "--data", str(tmp_path), "--out", str(tmp_path / "w.pt"), "--net", "tfeat",
                 "--augment-shift"])
    err = capsys.readouterr().err
    assert code == 2 and "error: --augment-shift: rolls the angle columns of polar patches" in err, err
    assert "tfeat's patches are Cartesian" in err and "(--net tfeat)" in err, err
    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=4, augment_shift=True)
    with pytest.raises(ValueError, match="augment_shift: .*tfeat's patches are Cartesian"):
        train(_patches(), tmp_path / "w.pt", config, net=ImagePatchNet(default_config("tfeat")), progress=False,
              device="cpu")
    assert not list(tmp_path.glob("w.pt*"))
    for net in ("logpolar", "geopatch"):  # polar patches: the shift is a rotation, and the run goes on
        with pytest.raises(_Stop):
            main(["train", "--data", str(tmp_path), "--out", str(tmp_path / f"{net}.pt"), "--net", net,
                  "--augment-shift"])


def test_resuming_without_the_patch_cache_checks_the_data_against_the_checkpoints_run(tmp_path, monkeypatch, capsys):
    """With OUT.patches.npz gone but OUT.ckpt there, --resume rebuilt the patches from whatever --data
    then held (here simulated again with another seed) and went on training the checkpoint's weights
    on them without a word; the cache's check never ran. The checkpoint now records what its run was
    trained on, and a mismatch is refused before any patch is built. A checkpoint that records nothing
    (an older geofeat's) resumes with a warning that nothing could be checked."""
    import torch

    import geofeat.train.dataset as dataset

    sim = ["simulate", str(tmp_path / "seq"), *TINY]
    run = ["train", "--data", str(tmp_path / "seq"), "--out", str(tmp_path / "w.pt"), "--epochs", "1", "--steps", "1",
           "--batch-size", "4", "--channels", "4", "4", "4", "--keypoints", "50", "--device", "cpu"]
    cache, checkpoint = tmp_path / "w.pt.patches.npz", tmp_path / "w.pt.ckpt"
    assert main(sim) == 0 and main(run) == 0
    cache.unlink()
    with warnings.catch_warnings():  # the same data: resumed, patches rebuilt, no warning about them
        warnings.filterwarnings("error", message="--resume")
        assert main([*run, "--resume"]) == 0
    cache.unlink()
    assert main([*sim, "--seed", "3", "--overwrite"]) == 0
    capsys.readouterr()
    monkeypatch.setattr(dataset, "build_patch_set", _stop)  # refused before any patch is built
    assert main([*run, "--resume"]) == 2
    err = capsys.readouterr().err
    assert "error: --resume: " in err and "w.pt.ckpt holds the state of a run with other options (--data seq: other " \
        "frames than that run's (simulated again or edited since))" in err, err
    state = torch.load(checkpoint, weights_only=False)
    del state["source"]  # as an older geofeat wrote it
    torch.save(state, checkpoint)
    with pytest.warns(UserWarning, match=r"--resume: .*w.pt.ckpt does not record what its run was trained on"), \
            pytest.raises(_Stop):
        main([*run, "--resume"])
