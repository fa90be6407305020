import numpy as np
import pytest

from geofeat.imagequality import mean_ssim, ssim_map


def _texture(seed=0, shape=(60, 80)):
    import cv2

    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 2.0)
    return (t - t.min()) / (t.max() - t.min())  # full contrast in [0, 1]


def test_ssim_is_one_for_identical_images_and_drops_with_change():
    a = _texture()
    assert mean_ssim(a, a) == pytest.approx(1.0, abs=1e-4)
    noise = np.random.default_rng(1).normal(0, 1, a.shape).astype(np.float32)
    scores = [mean_ssim(a, np.clip(a + s * noise, 0, 1)) for s in (0.005, 0.02, 0.08)]
    assert 1.0 > scores[0] > scores[1] > scores[2]  # more noise, less similar
    noisy = np.clip(a + 0.02 * noise, 0, 1)
    assert mean_ssim(a, 1 - a) < 0  # inverted contrast: negative correlation
    assert mean_ssim(a, noisy) == pytest.approx(mean_ssim(noisy, a), abs=1e-5)  # symmetric


def test_ssim_mask_and_bad_input():
    a, b = _texture(0), _texture(1)
    mask = np.zeros(a.shape, bool)
    assert np.isnan(mean_ssim(a, b, mask))
    mask[10:30, 10:30] = True
    assert mean_ssim(a, b, mask) == pytest.approx(float(ssim_map(a, b)[mask].mean()))
    with pytest.raises(ValueError, match="ssim"):
        ssim_map(a, b[:-1])


def test_ssim_reads_8_bit_images_as_fractions_of_255():
    """A uint8 image given for one in [0, 1] was scaled by 255 once more: SSIM's constants became
    negligible and a low-contrast pair read as 0.004 instead of 0.82, without a word."""
    rng = np.random.default_rng(0)
    a, b = (np.round(np.clip(0.5 + 0.01 * rng.standard_normal((60, 80)), 0, 1) * 255).astype(np.uint8)
            for _ in range(2))
    assert mean_ssim(a, b) == pytest.approx(mean_ssim(a / 255.0, b / 255.0), abs=1e-6)


@pytest.mark.parametrize("scale, message", [(255.0, "in \\[0, 1\\]"), (float("nan"), "NaN")])
def test_ssim_refuses_float_images_outside_0_1(scale, message):
    a = _texture()
    with pytest.raises(ValueError, match=message):
        mean_ssim(a * scale, a)


def test_ssim_refuses_empty_images_and_a_mask_of_another_shape():
    # OpenCV's "(-215:Assertion failed) !_src.empty()" and numpy's "boolean index did not match"
    a = _texture()
    with pytest.raises(ValueError, match="empty"):
        ssim_map(a[:0], a[:0])
    with pytest.raises(ValueError, match="mask"):
        mean_ssim(a, a, np.ones((10, 10), bool))
