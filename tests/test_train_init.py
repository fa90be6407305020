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
