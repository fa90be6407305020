"""tfeat-sim / logpolar-sim: patch sampling, shapes, and that the shipped (trained) weights beat a
random-weight net of the same architecture on a held-back simulated pair."""

import numpy as np
import pytest

import geofeat
from geofeat.scoring import ground_truth_pairs, score_detect
from geofeat.descriptors.image_patch_nets import ImagePatchDescriptor, image_patches
from geofeat.descriptors.patches import cartesian_grid, sample_patches
from geofeat.keypoints import detect
from geofeat.matching import match
from geofeat.sim import simulate_sequence


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """A simulated deform pair with a seed and a texture that training never saw (procedural
    texture, seed 4242; the training sequences use seeds 1000-1029)."""
    folder = tmp_path_factory.mktemp("nets") / "heldout-deform"
    simulate_sequence(folder, scenario="deform", n_frames=3, seed=4242, texture="procedural",
                      width=320, height=240, progress=False)
    seq = geofeat.read_sequence(folder)
    ref, tgt = seq.frame(seq.reference), seq.frame(seq.targets[-1])
    k_ref, k_tgt = detect(ref, 400, detector="sift"), detect(tgt, 400, detector="sift")
    mapped, visible = seq.correspondences(seq.targets[-1], seq.reference, k_tgt.xy)
    k_tgt, mapped = k_tgt[visible], mapped[visible]
    return ref, tgt, k_ref, k_tgt, ground_truth_pairs(k_ref.xy, mapped), folder


def _ms(d, pair) -> float:
    ref, tgt, k_ref, k_tgt, gt, _ = pair
    m = match(d.compute(ref, k_ref), d.compute(tgt, k_tgt))
    return score_detect(m.matches0, gt, len(k_ref), len(k_tgt)).ms


@pytest.mark.parametrize("arch", ["tfeat", "logpolar"])
def test_trained_weights_beat_random_weights(pair, arch):
    trained, random = _ms(ImagePatchDescriptor(arch), pair), _ms(ImagePatchDescriptor(arch, weights="random"), pair)
    assert trained > random + 0.02, (trained, random)


def test_train_command_writes_weights_that_make_descriptor_loads(pair, tmp_path):
    from geofeat.cli import main

    out = tmp_path / "tfeat.pt"
    rc = main(["train", "--net", "tfeat", "--data", str(pair[-1]), "--out", str(out), "--epochs", "1",
               "--steps", "2", "--batch-size", "16", "--keypoints", "64", "--device", "cpu"])
    assert rc == 0 and out.is_file()
    d = geofeat.make_descriptor(f"tfeat-sim={out}")
    assert d.net.config.arch == "tfeat"
    ref, _, k_ref = pair[:3]
    assert d.compute(ref, k_ref[:5]).descriptors.shape == (5, 128)


def test_make_descriptor_shapes_and_defaults():
    frame = geofeat.read_demo_frame()
    d = geofeat.make_descriptor("tfeat-sim")
    f = d.compute(frame, np.array([[100.0, 120.0], [300.0, 200.0]]))  # bare positions: angle 0, size 8
    assert f.descriptors.shape == (2, 128) and f.descriptors.dtype == np.float32 and f.valid.all()
    np.testing.assert_allclose(np.linalg.norm(f.descriptors, axis=1), 1.0, atol=1e-5)
    np.testing.assert_array_equal(f.angles, [0.0, 0.0])
    with pytest.raises(ValueError, match="keypoints"):
        d.compute(frame, np.zeros((3, 3)))


def test_patch_sampler_follows_rotation_and_scale():
    """A patch of an image rotated by 90 degrees about the keypoint, sampled with the angle turned
    by -90 (OpenCV's angle is clockwise on screen), equals the original patch."""
    rng = np.random.default_rng(0)
    image = rng.uniform(0, 1, (101, 101)).astype(np.float32)
    xy = np.array([[50.0, 50.0]])
    grid = cartesian_grid(16)
    p0 = sample_patches(image, xy, np.array([30.0]), np.array([10.0]), grid)
    rot = np.ascontiguousarray(np.rot90(image))  # counter-clockwise on screen; centre stays put
    p1 = sample_patches(rot, xy, np.array([30.0 - 90.0]), np.array([10.0]), grid)
    np.testing.assert_allclose(p1, p0, atol=1e-5)
    assert image_patches(image, xy, "logpolar").shape == (1, 32, 32)


@pytest.mark.parametrize("name", ["tfeat-sim", "logpolar-sim"])
def test_off_image_keypoints_and_nan_angles_are_refused(name):
    """Keypoints off the image were described from replicated border pixels and reported valid (every
    other descriptor refuses them); a NaN angle gave valid NaN descriptors."""
    frame = geofeat.read_demo_frame()
    d = geofeat.make_descriptor(name)
    with pytest.raises(ValueError, match="keypoints: 1 keypoint.s. off the 640x480 image"):
        d.compute(frame, np.array([[320.0, 240.0], [5000.0, 3000.0]]))
    from geofeat.keypoints import Keypoints

    kps = Keypoints(np.array([[320.0, 240.0]]), np.array([np.nan]), np.array([8.0]), np.zeros(1))
    with pytest.raises(ValueError, match="angle"):
        d.compute(frame, kps)


@pytest.mark.parametrize("batch_size", [0, -1, 2.5, True])
def test_batch_size_must_be_a_positive_whole_number(batch_size):
    """0 failed with "range() arg 3 must not be zero", -1 with a descriptor-count mismatch, 2.5 ran as 2."""
    with pytest.raises(ValueError, match="^batch_size: "):
        ImagePatchDescriptor("tfeat", batch_size=batch_size)


@pytest.mark.parametrize("radius", [10.0, 30.0, 60.0, 120.0])
def test_patches_of_large_supports_stay_centred_on_the_keypoint(radius):
    """Large supports are read from a Gaussian pyramid (cv2.pyrDown), whose pixel i lies on
    full-resolution pixel 2^l i; reading it as 2^l i + (2^l - 1) / 2 moved every patch 0.5, 1.5 or 3.5 px
    along the image's (+x, +y) at levels 1, 2, 3, so that a patch of the image rotated by 90 degrees about
    the keypoint was another patch."""
    rng = np.random.default_rng(0)
    import cv2

    image = cv2.GaussianBlur(rng.uniform(0, 1, (257, 257)).astype(np.float32), (0, 0), 4.0)
    xy = np.array([[128.0, 128.0]])
    grid = cartesian_grid(16)
    p0 = sample_patches(image, xy, np.array([30.0]), np.array([radius]), grid)
    rot = np.ascontiguousarray(np.rot90(image))  # about the keypoint: 257 = 2^8 + 1 keeps every level's grid
    p1 = sample_patches(rot, xy, np.array([30.0 - 90.0]), np.array([radius]), grid)
    np.testing.assert_allclose(p1, p0, atol=1e-4)


@pytest.mark.parametrize("name", ["tfeat-sim", "logpolar-sim"])
def test_describe_refuses_patches_of_another_size(name):
    """logpolar-sim's convolutional head turned (N, 64, 64) patches into (N, 10368) descriptors without a
    word, tfeat-sim failed inside torch; both take (N, 32, 32) patches, an empty set too."""
    d = geofeat.make_descriptor(name)
    rng = np.random.default_rng(0)
    assert d.describe(rng.random((2, 32, 32), np.float32)).shape == (2, 128)
    assert d.describe(np.zeros((0, 32, 32), np.float32)).shape == (0, 128)
    for shape in [(2, 64, 64), (32, 32), (2, 1, 32, 32)]:
        with pytest.raises(ValueError, match=r"^patches: expected shape \(N, 32, 32\)"):
            d.describe(rng.random(shape, np.float32))
