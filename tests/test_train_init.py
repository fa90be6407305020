"""Training options of GeoPatch v2: starting from given weights, photometric augmentation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from geofeat.descriptors.geopatch import GeoPatchConfig, load_network
from geofeat.train.dataset import PatchSet
from geofeat.train.loop import TrainConfig, _batch, train

NET = GeoPatchConfig(channels=(4, 8, 8), dim=16)


def _data() -> PatchSet:
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (40, 32, 32)).astype(np.uint8)
    noisy = np.clip(base.astype(int) + rng.integers(-10, 11, base.shape), 0, 255).astype(np.uint8)
    return PatchSet(np.concatenate([base, noisy]), np.concatenate([np.arange(40), np.arange(40)]))


def test_init_starts_from_the_given_weights(tmp_path):
    data = _data()
    first = train(data, tmp_path / "a.pt", TrainConfig(epochs=1, steps_per_epoch=3, batch_size=16, net=NET),
                  progress=False, device="cpu")
    assert first["loss"]
    # zero steps of training from a.pt leave its weights unchanged
    train(data, tmp_path / "b.pt", TrainConfig(epochs=1, steps_per_epoch=0, batch_size=16, net=NET),
          progress=False, device="cpu", init=tmp_path / "a.pt")
    wa, _ = load_network(tmp_path / "a.pt")
    wb, _ = load_network(tmp_path / "b.pt")
    for (_, pa), (_, pb) in zip(wa.state_dict().items(), wb.state_dict().items()):
        torch.testing.assert_close(pa, pb)
    # a different network shape is refused
    with pytest.raises(ValueError, match="init"):
        train(data, tmp_path / "c.pt", TrainConfig(epochs=1, steps_per_epoch=0, batch_size=16,
                                                   net=GeoPatchConfig(channels=(8, 8, 8), dim=16)),
              progress=False, device="cpu", init=tmp_path / "a.pt")


def test_photometric_augmentation_changes_contrast_not_layout():
    data = _data()
    idx = np.arange(8)
    rng = np.random.default_rng(1)
    plain = _batch(data.patches, idx, rng, False, False)
    aug = _batch(data.patches, idx, rng, False, True)
    assert aug.shape == plain.shape == (8, 1, 32, 32)
    diff = (aug - plain).abs().mean(dim=(1, 2, 3))
    assert (diff > 0.005).all()
    # a monotone change plus small noise: the patches stay strongly correlated with the originals
    for a, p in zip(aug, plain):
        assert np.corrcoef(a.ravel().numpy(), p.ravel().numpy())[0, 1] > 0.9


@pytest.mark.parametrize("change, message", [
    (dict(epochs=0), "epochs: expected"), (dict(steps_per_epoch=-1), "steps_per_epoch: expected"),
    (dict(batch_size=0), "batch_size: expected"), (dict(batch_size=1, mining="hardest"), "batch_size: expected"),
    (dict(lr=float("nan")), "lr: expected"), (dict(lr=-0.1), "lr: expected"), (dict(margin=0.0), "margin: expected"),
    (dict(mining="semi-hard"), "mining: expected"), (dict(seed=-1), "seed: expected"),
])
def test_bad_settings_are_refused_before_training(change, message, tmp_path):
    """NaN lr trained to NaN weights, epochs=0 ended on an IndexError, batch_size=0 on a torch error."""
    config = TrainConfig(**dict(dict(epochs=1, steps_per_epoch=1, batch_size=8, net=NET), **change))
    with pytest.raises(ValueError, match=message):
        train(_data(), tmp_path / "w.pt", config, progress=False, device="cpu")
    assert list(tmp_path.iterdir()) == []


def test_existing_weights_are_replaced_only_with_overwrite(tmp_path):
    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=8, net=NET)
    (tmp_path / "w.pt").write_bytes(b"my own weights")
    with pytest.raises(ValueError, match="exists.*overwrite"):
        train(_data(), tmp_path / "w.pt", config, progress=False, device="cpu")
    assert (tmp_path / "w.pt").read_bytes() == b"my own weights"
    train(_data(), tmp_path / "w.pt", config, progress=False, device="cpu", overwrite=True)
    assert load_network(tmp_path / "w.pt")[0].config == NET
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name]


def test_resume_refuses_a_corrupt_checkpoint_or_other_settings(tmp_path):
    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=8, net=NET)
    (tmp_path / "a.pt.ckpt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="resume: .*a.pt.ckpt is not a checkpoint"):
        train(_data(), tmp_path / "a.pt", config, resume=True, progress=False, device="cpu")
    train(_data(), tmp_path / "b.pt", config, progress=False, device="cpu")
    # more epochs would continue a cosine schedule fitted to one epoch; another net would not load
    for change, message in ((dict(epochs=2), "epochs 1, not 2"), (dict(mining="hardest"), "mining 'random'"),
                            (dict(net=GeoPatchConfig(channels=(8, 8, 8), dim=16)), "net")):
        with pytest.raises(ValueError, match=f"resume: .*other settings.*{message}"):
            train(_data(), tmp_path / "b.pt", TrainConfig(**dict(config.__dict__, **change)), resume=True,
                  progress=False, device="cpu")


def test_resume_refuses_other_patches_than_its_run(tmp_path):
    """`train(other_data, out, resume=True)` from Python continued the run on patches it was not trained
    on without a word (the `train` command compares its --data; Python callers had no check)."""
    config = TrainConfig(epochs=2, steps_per_epoch=1, batch_size=8, net=NET)
    train(_data(), tmp_path / "w.pt", config, progress=False, device="cpu")
    other = _data()
    other.patches = 255 - other.patches
    with pytest.raises(ValueError, match=r"resume: .*w.pt.ckpt continues a run trained on other patches"):
        train(other, tmp_path / "w.pt", config, resume=True, progress=False, device="cpu")
    shuffled = _data()
    shuffled.ids = shuffled.ids[::-1].copy()  # the same patches, other surface points
    with pytest.raises(ValueError, match="other patches"):
        train(shuffled, tmp_path / "w.pt", config, resume=True, progress=False, device="cpu")
    resumed = train(_data(), tmp_path / "w.pt", config, resume=True, progress=False, device="cpu")
    assert len(resumed["loss"]) == 2


def test_resume_without_a_checkpoint_says_it_starts_from_the_first_epoch(tmp_path):
    """--resume with nothing to resume trained from scratch without a word (a typo in --out, or a run
    that had already finished and removed its checkpoint)."""
    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=8, net=NET)
    with pytest.warns(UserWarning, match=r"resume: no .*w.pt.ckpt to resume from.*first epoch"):
        train(_data(), tmp_path / "w.pt", config, resume=True, progress=False, device="cpu")
    assert load_network(tmp_path / "w.pt")[0].config == NET


def test_a_corrupt_patch_cache_is_one_error(tmp_path):
    (tmp_path / "w.pt.patches.npz").write_bytes(b"not an archive")
    with pytest.raises(ValueError, match="patches: cannot read .*w.pt.patches.npz"):
        PatchSet.load(tmp_path / "w.pt.patches.npz")
    _data().save(tmp_path / "p.npz")
    assert len(PatchSet.load(tmp_path / "p.npz")) == 80


def test_an_unfinished_runs_checkpoint_is_kept_without_resume_or_overwrite(tmp_path):
    """A run stopped after some epochs leaves w.pt.ckpt (to --resume from) but no w.pt: running again
    without --resume started anew and replaced the checkpoint, and the epochs it held, silently; so
    were a w.pt.json or w.pt.png of the user's (and --overwrite replaces only files `train` wrote)."""
    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=8, net=NET)
    for name in ("w.pt.ckpt", "w.pt.json", "w.pt.png"):
        folder = tmp_path / name
        folder.mkdir()
        (folder / name).write_bytes(b"hours of training")
        with pytest.raises(ValueError, match=f"{name} exists.*--resume.*--overwrite"):
            train(_data(), folder / "w.pt", config, progress=False, device="cpu")
        assert (folder / name).read_bytes() == b"hours of training"
        assert sorted(p.name for p in folder.iterdir()) == [name]
    with pytest.raises(ValueError, match="w.pt.json exists, and `geofeat train` did not write it"):
        train(_data(), tmp_path / "w.pt.json" / "w.pt", config, progress=False, device="cpu", overwrite=True)
    (tmp_path / "w.pt.json" / "w.pt.json").unlink()
    train(_data(), tmp_path / "w.pt.json" / "w.pt", config, progress=False, device="cpu", overwrite=True)
    assert load_network(tmp_path / "w.pt.json" / "w.pt")[0].config == NET


def test_the_device_is_checked_before_training(tmp_path, monkeypatch):
    """A device torch does not know, or CUDA without a GPU, was a torch error (AssertionError "Torch not
    compiled with CUDA enabled") after the patches were built."""
    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=8, net=NET)
    with pytest.raises(ValueError, match="device: expected"):
        train(_data(), tmp_path / "w.pt", config, progress=False, device="gpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(RuntimeError, match="no CUDA GPU"):
        train(_data(), tmp_path / "w.pt", config, progress=False, device="cuda")
    assert list(tmp_path.iterdir()) == []


def test_a_falsy_device_is_torchs_cuda_0_not_the_cpu(tmp_path, monkeypatch):
    """device=0 is torch's cuda:0 and "" no device at all: both trainers read them as "not given"
    (`device or ...`) and trained on the CPU without a word. Without a CUDA GPU both are now errors
    naming the device, for GeoPatch's and GeoKey's trainers alike."""
    from geofeat.train.detector import fit

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=8, net=NET)
    x, y = np.zeros((16, 9), np.float32), np.r_[np.zeros(8), np.ones(8)]
    for run in (lambda device: train(_data(), tmp_path / "w.pt", config, progress=False, device=device),
                lambda device: fit(x, y, steps=1, batch=8, device=device)):
        with pytest.raises((RuntimeError, ValueError), match="no CUDA GPU|device: expected"):
            run(0)  # a CPU build of torch has no accelerator for an index to name: not a device at all
        with pytest.raises(ValueError, match="device: expected"):
            run("")
    assert list(tmp_path.iterdir()) == []


def test_hardest_mining_never_takes_another_view_of_the_same_point_for_a_negative():
    """With fewer surface points than the batch, the sampler draws a point twice; hardest mining took
    the second pair for a negative of the first and pushed two views of one point apart."""
    from geofeat.train.loop import triplet_loss

    a = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])  # rows 0 and 1: one surface point, drawn twice
    ids = torch.tensor([7, 7, 3])
    assert triplet_loss(a, a.clone(), None, 1.0, "hardest", ids=ids) == 0  # |a - n| = sqrt(2) > margin
    assert triplet_loss(a, a.clone(), None, 1.0, "hardest", ids=torch.tensor([7, 8, 3])) > 0.6


def test_training_with_hardest_mining_tells_the_loss_which_rows_are_one_point(tmp_path, monkeypatch):
    from geofeat.train import loop

    seen = []

    def spy(a, p, n, margin, mining, ids=None):
        seen.append(ids)
        return loop_loss(a, p, n, margin, mining, ids=ids)

    loop_loss = loop.triplet_loss
    monkeypatch.setattr(loop, "triplet_loss", spy)
    data = _data()  # 40 surface points, batch 64: some are drawn twice
    train(data, tmp_path / "w.pt", TrainConfig(epochs=1, steps_per_epoch=2, batch_size=64, mining="hardest", net=NET),
          progress=False, device="cpu")
    assert len(seen) == 2 and all(ids is not None and len(ids) == 64 and len(set(ids.tolist())) < 64 for ids in seen)


def test_hardest_mining_batches_always_hold_two_surface_points(tmp_path, monkeypatch):
    """On 2 surface points with batches of 3, a quarter of the batches drew every row from one point:
    hardest mining then found no negative, and the step's loss was 0, with no gradient, without a word.
    Every batch now holds both points, and data with fewer points than a batch's rows is warned of."""
    from geofeat.train import loop

    seen = []

    def spy(a, p, n, margin, mining, ids=None):
        seen.append(ids.tolist())
        return loop_loss(a, p, n, margin, mining, ids=ids)

    loop_loss = loop.triplet_loss
    monkeypatch.setattr(loop, "triplet_loss", spy)
    patches = np.random.default_rng(0).integers(0, 256, (4, 32, 32)).astype(np.uint8)
    data = PatchSet(patches, np.array([0, 0, 1, 1]))  # 2 surface points, 2 views each
    config = TrainConfig(epochs=1, steps_per_epoch=20, batch_size=3, mining="hardest", net=NET)
    with pytest.warns(UserWarning, match=r"mining: hardest .* has 2 surface points seen in 2 frames or more for "
                                         r"batches of 3 triplets.*one of at most 1 others"):
        train(data, tmp_path / "w.pt", config, progress=False, device="cpu")
    assert len(seen) == 20 and all(set(ids) == {0, 1} for ids in seen), seen
    import warnings

    with warnings.catch_warnings():  # as many points as rows (drawn without replacement): no warning
        warnings.filterwarnings("error", message="mining")
        train(data, tmp_path / "w2.pt", TrainConfig(epochs=1, steps_per_epoch=2, batch_size=2, mining="hardest",
                                                    net=NET), progress=False, device="cpu")
        train(data, tmp_path / "w3.pt", TrainConfig(epochs=1, steps_per_epoch=2, batch_size=4, net=NET),
              progress=False, device="cpu")  # random mining draws its negatives from all the data


def test_train_detector_counts_take_a_numpy_whole_number_and_name_a_string_whole():
    """A numpy count was a TypeError ("not iterable"); "100" was iterated and refused as '1'."""
    from geofeat.train.detector import check_counts

    assert check_counts(np.int64(100)) == (100,) and check_counts((100, np.int32(200))) == (100, 200)
    with pytest.raises(ValueError, match="keypoints: expected a whole number >= 1, got '100'"):
        check_counts("100")


def test_cli_init_without_channels_takes_the_init_weights_widths(tmp_path, capsys):
    """`geofeat train --init shipped` as docs/training.md shows it: the shipped weights are the paper's
    widths (32 64 128), not --channels' default; without --channels the run takes the weights' widths.
    An explicit --channels that differs is still refused, naming the option."""
    from geofeat.cli import main

    sim = tmp_path / "sim"
    assert main(["simulate", str(sim), "--frames", "2", "--width", "64", "--height", "48", "--no-progress",
                 "--texture", "procedural"]) == 0
    common = ["train", "--data", str(sim), "--epochs", "1", "--steps", "1", "--batch-size", "8", "--keypoints", "50",
              "--init", "shipped", "--device", "cpu"]
    assert main([*common, "--out", str(tmp_path / "w.pt")]) == 0
    tuned, _ = load_network(tmp_path / "w.pt")
    shipped, _ = load_network(None)
    assert tuned.config == shipped.config
    assert main([*common, "--out", str(tmp_path / "x.pt"), "--channels", "16", "32", "64"]) == 2
    assert "--channels" in capsys.readouterr().err


def test_the_training_plot_says_when_there_was_no_validation():
    """Without validation pairs the MS axis of OUT.png was drawn empty, with nothing saying why."""
    import matplotlib.pyplot as plt

    from geofeat.train.loop import _figure

    fig = _figure({"epoch": [1, 2], "loss": [0.5, 0.4], "val_ms": [float("nan")] * 2})
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    plt.close(fig)
    assert any("no validation pairs" in t for t in texts)
    fig = _figure({"epoch": [1, 2], "loss": [0.5, 0.4], "val_ms": [0.3, 0.4]})
    assert not [t for ax in fig.axes for t in ax.texts]
    plt.close(fig)


def test_the_validation_score_says_what_it_measures(tmp_path, capsys):
    """The per-epoch 'validation MS' (one-way nearest-neighbour matches of 1024 SIFT keypoints per frame,
    not the benchmark's 2048 with its matching) was printed, plotted and written unqualified."""
    import json

    import matplotlib.pyplot as plt

    from geofeat.train.dataset import ValidationPair
    from geofeat.train.loop import _figure

    rng = np.random.default_rng(1)
    patches = rng.random((6, 32, 32)).astype(np.float32)
    pair = ValidationPair(patches, np.ones(6, bool), patches, np.ones(6, bool), np.stack([np.arange(6)] * 2, 1))
    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=8, net=NET)
    history = train(_data(), tmp_path / "w.pt", config, validation=[pair], device="cpu")
    measure = "1024 SIFT keypoints per frame, one-way nearest-neighbour matches"
    assert f"validation MS 1.000 ({measure})" in capsys.readouterr().out  # the line of the epoch
    written = json.loads((tmp_path / "w.pt.json").read_text())
    assert written["val_measure"] == history["val_measure"] == measure
    fig = _figure(written)
    assert measure in fig.axes[0].get_title()
    plt.close(fig)


def test_a_checkpoint_loaded_for_another_device_restores_its_random_state(tmp_path):
    """`train(..., resume=True, device="cuda")` loaded the checkpoint with map_location=cuda, which
    moved the saved CPU random state onto the GPU too; torch.set_rng_state refused it and the resume
    failed as "is not a checkpoint of this network". The state is now read onto the CPU whatever
    the training device."""
    from geofeat.train.loop import load_resume_state

    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=8, net=NET)
    train(_data(), tmp_path / "w.pt", config, progress=False, device="cpu")
    state = load_resume_state(tmp_path / "w.pt.ckpt", config)
    assert state["torch_rng"].device.type == "cpu"
    saved = torch.get_rng_state()
    try:
        torch.set_rng_state(state["torch_rng"])
    finally:
        torch.set_rng_state(saved)


def test_an_interrupted_run_resumes_to_the_weights_of_an_uninterrupted_one(tmp_path, monkeypatch):
    """Resuming after epoch 1 of 2 (weights, optimizer, schedule, both random generators restored)
    gives the same weights as training the 2 epochs in one go."""
    import geofeat.train.loop as loop

    config = TrainConfig(epochs=2, steps_per_epoch=3, batch_size=16, net=NET, augment_shift=True,
                         augment_photometric=True)
    whole = train(_data(), tmp_path / "a.pt", config, progress=False, device="cpu")
    sample, calls = loop.TripletSampler.sample, []

    def stop_in_epoch_2(self, batch):
        calls.append(batch)
        if len(calls) > config.steps_per_epoch:
            raise KeyboardInterrupt
        return sample(self, batch)

    monkeypatch.setattr(loop.TripletSampler, "sample", stop_in_epoch_2)
    with pytest.raises(KeyboardInterrupt):
        train(_data(), tmp_path / "b.pt", config, progress=False, device="cpu")
    monkeypatch.setattr(loop.TripletSampler, "sample", sample)
    torch.manual_seed(99)  # the resumed run must not depend on the process's random state
    resumed = train(_data(), tmp_path / "b.pt", config, resume=True, progress=False, device="cpu")
    assert resumed["loss"] == whole["loss"]
    wa, _ = load_network(tmp_path / "a.pt")
    wb, _ = load_network(tmp_path / "b.pt")
    for (name, pa), (_, pb) in zip(wa.state_dict().items(), wb.state_dict().items()):
        torch.testing.assert_close(pa, pb, rtol=0, atol=0, msg=name)


def test_cli_init_takes_the_init_weights_angle_pooling(tmp_path, capsys, monkeypatch):
    """`train --init W` with weights trained with --no-angle-pool said 'init: the weights' network
    GeoPatchConfig(..., angle_pool=False, ...) differs from the requested GeoPatchConfig(...)' (naming no
    option), though the run takes the weights' widths by itself; `--init shipped --no-angle-pool` said
    the same. The run now takes the weights' pooling, and refuses --no-angle-pool with pooling weights."""
    import geofeat.train.dataset as dataset
    from geofeat.cli import main
    from geofeat.descriptors.geopatch import GeoPatchNet, save_checkpoint

    flat = GeoPatchConfig(channels=(4, 8, 8), angle_pool=False)
    save_checkpoint(tmp_path / "flat.pt", GeoPatchNet(flat))
    sim = tmp_path / "sim"
    assert main(["simulate", str(sim), "--frames", "2", "--width", "64", "--height", "48", "--no-progress",
                 "--texture", "procedural"]) == 0
    common = ["train", "--data", str(sim), "--epochs", "1", "--steps", "1", "--batch-size", "8", "--keypoints", "50",
              "--device", "cpu"]
    assert main([*common, "--init", str(tmp_path / "flat.pt"), "--out", str(tmp_path / "w.pt")]) == 0
    assert load_network(tmp_path / "w.pt")[0].config == flat
    capsys.readouterr()

    def built(*args, **kwargs):
        raise AssertionError("patches were built before the bad option was reported")

    monkeypatch.setattr(dataset, "build_patch_set", built)
    assert main([*common, "--init", "shipped", "--no-angle-pool", "--out", str(tmp_path / "x.pt")]) == 2
    err = capsys.readouterr().err
    assert "error: --no-angle-pool: the --init weights shipped max-pool over angle" in err, err
    assert "leave --no-angle-pool out" in err, err
