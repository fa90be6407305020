"""match(): nearest neighbours against a brute-force numpy reference, for every metric."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geofeat.features import Features
from geofeat.matching import match


def popcount_bytes(x: np.ndarray) -> np.ndarray:
    return np.unpackbits(x, axis=-1).sum(axis=-1)


def reference_distances(d0: np.ndarray, d1: np.ndarray, metric: str) -> np.ndarray:
    """(N0, N1) distance matrix, brute force."""
    if metric == "l2":
        return np.sqrt(((d0[:, None, :].astype(np.float64) - d1[None, :, :]) ** 2).sum(-1))
    if metric == "hamming":
        return popcount_bytes(d0[:, None, :] ^ d1[None, :, :]).astype(np.float64)
    # hamming-rot: query rotation 0 against every rotation of the target
    return popcount_bytes(d0[:, None, None, 0, :] ^ d1[None, :, :, :]).min(axis=2).astype(np.float64)


def reference_match(f0: Features, f1: Features, metric: str, mutual=False, ratio=None):
    D = reference_distances(f0.descriptors, f1.descriptors, metric)
    D[~f0.valid] = np.inf
    D[:, ~f1.valid] = np.inf
    n0 = len(f0)
    m = np.full(n0, -1)
    dist = np.full(n0, np.inf)
    for i in range(n0):
        if not np.isfinite(D[i]).any():
            continue
        j = int(np.argmin(D[i]))  # first minimum = lowest index
        others = np.delete(D[i], j)
        second = others.min() if len(others) else np.inf
        if ratio is not None and not (D[i, j] < ratio * second):
            continue
        if mutual and int(np.argmin(D[:, j])) != i:
            continue
        m[i], dist[i] = j, D[i, j]
    return m, dist


def random_features(rng, n, metric, valid_frac=0.8, n_bytes=8, n_rot=4, dim=6):
    if metric == "l2":
        desc = rng.standard_normal((n, dim))
    elif metric == "hamming":
        # few distinct values: plenty of exact ties, so the tie rule is exercised
        desc = rng.integers(0, 4, size=(n, n_bytes), dtype=np.uint8)
    else:
        desc = rng.integers(0, 256, size=(n, n_rot, n_bytes), dtype=np.uint8)
    return Features(rng.random((n, 2)) * 100, desc, rng.random(n) < valid_frac)


@settings(max_examples=60, deadline=None)
@given(
    metric=st.sampled_from(["l2", "hamming", "hamming-rot"]),
    n0=st.integers(0, 12),
    n1=st.integers(0, 12),
    n_bytes=st.sampled_from([1, 3, 8, 13, 64, 100]),  # 100 bytes: the generic (> 8 words) kernel
    mutual=st.booleans(),
    ratio=st.sampled_from([None, 0.8, 1.0]),
    seed=st.integers(0, 2**31 - 1),
)
def test_match_equals_brute_force(metric, n0, n1, n_bytes, mutual, ratio, seed):
    rng = np.random.default_rng(seed)
    f0 = random_features(rng, n0, metric, n_bytes=n_bytes)
    f1 = random_features(rng, n1, metric, n_bytes=n_bytes)
    with warnings.catch_warnings():  # bytes 0-3 (for ties) look like a quantised histogram, and say so
        warnings.filterwarnings("ignore", "descriptors: uint8 .* quantised histogram", UserWarning)
        got = match(f0, f1, mutual=mutual, ratio=ratio)
    assert got.matches0.dtype == np.int64 and got.matches0.shape == (n0,)
    m, dist = reference_match(f0, f1, metric, mutual=mutual, ratio=ratio)
    assert np.array_equal(got.matches0, m)
    assert np.array_equal(np.isinf(got.distances0), np.isinf(dist))
    assert np.allclose(got.distances0[np.isfinite(dist)], dist[np.isfinite(dist)], rtol=1e-9, atol=1e-9)
    # invalid keypoints never match, on either side
    assert (got.matches0[~f0.valid] == -1).all()
    assert not np.isin(got.matches0, np.flatnonzero(~f1.valid)).any()


def test_hamming_rot_on_geobit_sized_descriptors():
    rng = np.random.default_rng(1)
    f0 = random_features(rng, 40, "hamming-rot", n_bytes=64, n_rot=16)
    f1 = random_features(rng, 50, "hamming-rot", n_bytes=64, n_rot=16)
    got = match(f0, f1)
    m, dist = reference_match(f0, f1, "hamming-rot")
    assert np.array_equal(got.matches0, m) and np.allclose(got.distances0[m >= 0], dist[m >= 0])


def test_hamming_rot_finds_a_rotated_copy():
    rng = np.random.default_rng(2)
    d1 = rng.integers(0, 256, size=(30, 16, 64), dtype=np.uint8)
    # query i = target i seen at rotation (i mod 16): its rotation 0 equals target rotation k
    d0 = np.stack([d1[i, i % 16] for i in range(30)])[:, None, :].repeat(16, axis=1)
    got = match(d0, d1)
    assert np.array_equal(got.matches0, np.arange(30)) and (got.distances0 == 0).all()
    # plain Hamming on rotation 0 only does not find most of them
    plain = match(np.ascontiguousarray(d0[:, 0]), np.ascontiguousarray(d1[:, 0]))
    assert (plain.matches0 == np.arange(30)).mean() < 0.2


def test_ties_go_to_lowest_index_and_metric_override():
    d1 = np.zeros((5, 4), np.uint8)
    got = match(np.zeros((2, 4), np.uint8), d1)
    assert got.matches0.tolist() == [0, 0]
    f1 = Features(np.zeros((5, 2)), d1, np.array([False, False, True, True, True]))
    assert match(np.zeros((1, 4), np.uint8), f1).matches0.tolist() == [2]
    # uint8 with explicit l2
    got = match(np.array([[0, 9]], np.uint8), np.array([[0, 0], [0, 10]], np.uint8), metric="l2")
    assert got.matches0.tolist() == [1] and got.distances0[0] == pytest.approx(1.0)


def test_empty_and_all_invalid_inputs():
    for metric_shape in [(0, 8), (0, 16, 64), (0, 5)]:
        dtype = np.float32 if len(metric_shape) == 2 and metric_shape[1] == 5 else np.uint8
        e = np.zeros(metric_shape, dtype)
        full = np.ones((3,) + metric_shape[1:], dtype)
        assert match(e, full).matches0.shape == (0,)
        r = match(full, e)
        assert r.matches0.tolist() == [-1, -1, -1] and np.isinf(r.distances0).all()
        assert match(e, e).matches0.shape == (0,)
    f = Features(np.zeros((3, 2)), np.ones((3, 16, 64), np.uint8), np.zeros(3, bool))
    assert match(f, f).matches0.tolist() == [-1, -1, -1]


def test_mismatched_descriptors_raise():
    with pytest.raises(ValueError, match="trailing shapes"):
        match(np.zeros((2, 16, 64), np.uint8), np.zeros((2, 16, 32), np.uint8))
    with pytest.raises(ValueError, match="trailing shapes"):
        match(np.zeros((2, 8), np.uint8), np.zeros((2, 16, 8), np.uint8))
    with pytest.raises(TypeError, match="uint8"):
        match(np.zeros((2, 8), np.float32), np.zeros((2, 8), np.float32), metric="hamming")
    with pytest.raises(ValueError, match="metric"):
        match(np.zeros((2, 8), np.uint8), np.zeros((2, 8), np.uint8), metric="cosine")
    with pytest.raises(ValueError, match="hamming-rot"):
        match(np.zeros((2, 8), np.uint8), np.zeros((2, 8), np.uint8), metric="hamming-rot")
    with pytest.raises(ValueError, match="ratio"):
        match(np.zeros((2, 8), np.uint8), np.zeros((2, 8), np.uint8), ratio=1.5)


def test_descriptors_without_values_are_refused():
    """(N, 0) descriptors (a slice past the end, an empty dataset) had every distance 0: each keypoint
    matched the first one of the other image, at distance 0, without a word."""
    from geofeat.matching import distance_matrix

    for dtype in (np.float32, np.uint8):
        empty = np.zeros((5, 0), dtype)
        with pytest.raises(ValueError, match=r"shape \(5, 0\) holds no values per keypoint"):
            match(empty, np.zeros((4, 0), dtype))
        with pytest.raises(ValueError, match="holds no values per keypoint"):
            distance_matrix(empty, np.zeros((4, 0), dtype))
    with pytest.raises(ValueError, match="holds no values per keypoint"):
        match(np.zeros((3, 16, 0), np.uint8), np.zeros((2, 16, 0), np.uint8))
    assert match(np.zeros((0, 0), np.float32), np.zeros((0, 0), np.float32)).matches0.shape == (0,)  # nothing to match


def test_nan_descriptors_at_valid_keypoints_raise_but_invalid_ones_are_ignored():
    d = np.random.default_rng(0).normal(size=(4, 8)).astype(np.float32)
    bad = d.copy()
    bad[2, 3] = np.nan
    with pytest.raises(ValueError, match=r"features1 has NaN.*\[2\]"):
        match(d, bad)
    valid = np.array([True, True, False, True])  # a NaN row marked invalid is not looked at
    m = match(d, Features(np.zeros((4, 2)), bad, valid)).matches0
    assert m[[0, 1, 3]].tolist() == [0, 1, 3] and m[2] in (0, 1, 3)


def test_distance_matrix_refuses_what_match_refuses():
    """`distance_matrix` ("the same metrics as match") gave a row and a column of NaN for a NaN
    descriptor, which np.argmin reads as the smallest distance (a NaN target was every query's
    nearest), and failed inside numpy's einsum on (N, R, D) float descriptors; both are now the
    ValueError that `match` gives."""
    from geofeat.matching import distance_matrix

    d = np.random.default_rng(0).normal(size=(4, 8)).astype(np.float32)
    bad = d.copy()
    bad[2, 3] = np.nan
    with pytest.raises(ValueError, match=r"descriptors1 has NaN.*\[2\]"):
        distance_matrix(d, bad)
    with pytest.raises(ValueError, match=r"descriptors0 has NaN"):
        distance_matrix(bad, d)
    with pytest.raises(ValueError, match=r"metric 'l2' expects \(N, D\)"):
        distance_matrix(d.reshape(4, 2, 4), d.reshape(4, 2, 4))
    assert distance_matrix(d, d).argmin(axis=1).tolist() == [0, 1, 2, 3]
    # a NaN row marked invalid is not looked at (its distances are the caller's to mask)
    valid = np.array([True, True, False, True])
    D = distance_matrix(d, bad, valid1=valid)
    assert np.isnan(D[:, 2]).all() and np.isfinite(np.delete(D, 2, axis=1)).all()
    with pytest.raises(ValueError, match="valid1: expected one flag per row"):
        distance_matrix(d, bad, valid1=valid[:3])


@pytest.mark.parametrize("mutual", [False, True])
@pytest.mark.parametrize("ratio", [None, 0.9])
@pytest.mark.parametrize("n_rot", [3, 16])
def test_pruned_rotation_kernel_equals_brute_force(mutual, ratio, n_rot):
    """Several target blocks, many exact ties (descriptors from a few patterns with a few bits
    flipped), invalid keypoints: the pruned kernel gives exactly the brute-force matches."""
    rng = np.random.default_rng(n_rot + 10 * mutual)
    base = rng.integers(0, 256, size=(5, n_rot, 64), dtype=np.uint8)

    def make(n):
        desc = base[rng.integers(0, 5, n)].copy()
        flips = rng.integers(0, 64, size=(n, 3))
        for b in range(3):
            desc[np.arange(n), rng.integers(0, n_rot, n), flips[:, b]] ^= np.uint8(1 << b)
        return Features(rng.random((n, 2)), desc, rng.random(n) < 0.9)

    f0, f1 = make(150), make(400)  # 400 targets: more than one cache block of 16-rotation targets
    got = match(f0, f1, mutual=mutual, ratio=ratio)
    m, dist = reference_match(f0, f1, "hamming-rot", mutual=mutual, ratio=ratio)
    assert np.array_equal(got.matches0, m)
    assert np.array_equal(got.distances0[m >= 0], dist[m >= 0])


@pytest.mark.parametrize("mutual", [False, True])
@pytest.mark.parametrize("ratio", [None, 0.8])
def test_rotation_matching_equals_brute_force_on_real_geobit(real_geobit, mutual, ratio):
    f0, f1 = real_geobit
    got = match(f0, f1, mutual=mutual, ratio=ratio)
    m, dist = reference_match(f0, f1, "hamming-rot", mutual=mutual, ratio=ratio)
    assert (m >= 0).sum() > 0.3 * len(m)  # a real matching problem, not all rejected
    assert np.array_equal(got.matches0, m)
    assert np.array_equal(got.distances0[m >= 0], dist[m >= 0])


@pytest.fixture(scope="module")
def real_geobit():
    """GeoBit features of 300 SIFT keypoints of the Kinect frame and of its 90-degree roll."""
    import geofeat
    from geofeat.descriptors.geobit import GeoBit
    from geofeat.keypoints import detect

    frame = geofeat.read_demo_frame()
    rolled = frame.rotated90(1)
    gb = GeoBit()
    return gb.compute(frame, detect(frame, 300, detector="sift")), gb.compute(rolled, detect(rolled, 300, detector="sift"))


@pytest.mark.parametrize("mutual", [False, True])
@pytest.mark.parametrize("ratio", [None, 0.9])
@pytest.mark.parametrize("metric,n_rot", [("hamming-rot", 16), ("hamming-rot", 3), ("hamming", 1)])
def test_matrix_product_path_equals_brute_force(metric, n_rot, mutual, ratio):
    """The torch matrix-product path (meant for CUDA; run here on the CPU) matches brute force,
    ties and invalid keypoints included, across several query blocks."""
    pytest.importorskip("torch")
    rng = np.random.default_rng(n_rot + 2 * mutual)
    shape = (n_rot, 64) if metric == "hamming-rot" else (64,)
    base = rng.integers(0, 256, size=(4, *shape), dtype=np.uint8)
    f = [Features(rng.random((n, 2)), base[rng.integers(0, 4, n)] ^ (rng.random((n, *shape)) < 0.02).astype(np.uint8),
                  rng.random(n) < 0.9) for n in (300, 170)]
    got = match(f[0], f[1], metric=metric, mutual=mutual, ratio=ratio, device="cpu")
    m, dist = reference_match(f[0], f[1], metric, mutual=mutual, ratio=ratio)
    assert np.array_equal(got.matches0, m)
    assert np.array_equal(got.distances0[m >= 0], dist[m >= 0])
    cpu = match(f[0], f[1], metric=metric, mutual=mutual, ratio=ratio)
    assert np.array_equal(cpu.matches0, m)


def search_matches(f0, f1, method, mutual, ratio):
    """match() through one method of the rotation search (`_hamming_search`)."""
    from geofeat.matching import _finish_matches, _hamming_search

    res = _hamming_search(f0.descriptors, f1.descriptors, f0.valid, f1.valid, mutual, ratio, method=method)
    return _finish_matches(*res, ratio=ratio, mutual=mutual)


@settings(max_examples=80, deadline=None)
@given(
    method=st.sampled_from(["two-stage", "blocked", "auto"]),
    n0=st.integers(1, 40),
    n1=st.integers(1, 40),
    n_rot=st.sampled_from([2, 3, 16]),
    n_bytes=st.sampled_from([1, 8, 33, 64]),
    levels=st.sampled_from([2, 4, 256]),  # few byte values: many exact ties and distances above 127
    valid_frac=st.sampled_from([0.0, 0.5, 1.0]),
    mutual=st.booleans(),
    ratio=st.sampled_from([None, 1e-300, 0.5, 0.8, 1.0]),  # 1e-300: best / ratio far beyond uint64
    seed=st.integers(0, 2**31 - 1),
)
def test_rotation_search_methods_equal_brute_force(method, n0, n1, n_rot, n_bytes, levels, valid_frac, mutual,
                                                   ratio, seed):
    """Every rotation search method gives the brute-force matches and distances: tiny N, ties,
    all-invalid sides, 2-16 rotations, descriptors shorter than the bound's 256 bits."""
    rng = np.random.default_rng(seed)

    def make(n):
        desc = rng.integers(0, levels, size=(n, n_rot, n_bytes), dtype=np.uint8)
        return Features(rng.random((n, 2)), desc, rng.random(n) < valid_frac)

    f0, f1 = make(n0), make(n1)
    got = search_matches(f0, f1, method, mutual, ratio)
    m, dist = reference_match(f0, f1, "hamming-rot", mutual=mutual, ratio=ratio)
    assert np.array_equal(got.matches0, m)
    assert np.array_equal(got.distances0[m >= 0], dist[m >= 0])


@pytest.mark.parametrize("method", ["two-stage", "blocked"])
@pytest.mark.parametrize("mutual", [False, True])
@pytest.mark.parametrize("ratio", [None, 0.8, 1.0])
def test_rotation_search_methods_on_clustered_descriptors(method, mutual, ratio):
    """Descriptors near a few patterns (tight bounds, many exact ties) across several target blocks
    and more than one word of bounds per row: each method equals brute force."""
    rng = np.random.default_rng(7 + mutual)
    base = rng.integers(0, 256, size=(6, 16, 64), dtype=np.uint8)

    def make(n):
        desc = base[rng.integers(0, 6, n)].copy()
        for b in range(4):
            desc[np.arange(n), rng.integers(0, 16, n), rng.integers(0, 64, n)] ^= np.uint8(1 << b)
        return Features(rng.random((n, 2)), desc, rng.random(n) < 0.9)

    f0, f1 = make(203), make(301)
    got = search_matches(f0, f1, method, mutual, ratio)
    m, dist = reference_match(f0, f1, "hamming-rot", mutual=mutual, ratio=ratio)
    assert np.array_equal(got.matches0, m)
    assert np.array_equal(got.distances0[m >= 0], dist[m >= 0])


@pytest.mark.parametrize("mutual", [False, True])
@pytest.mark.parametrize("ratio", [None, 0.8])
def test_two_stage_search_on_real_geobit(real_geobit, mutual, ratio):
    f0, f1 = real_geobit
    got = search_matches(f0, f1, "two-stage", mutual, ratio)
    m, dist = reference_match(f0, f1, "hamming-rot", mutual=mutual, ratio=ratio)
    assert (m >= 0).sum() > 0.3 * len(m)
    assert np.array_equal(got.matches0, m)
    assert np.array_equal(got.distances0[m >= 0], dist[m >= 0])


def test_auto_method_choice(real_geobit):
    """The automatic choice: two-stage on real GeoBit descriptors (bounds rule out most pairs),
    blocked on uniformly random bits (they rule out none); invalid methods raise."""
    from geofeat.matching import _as_words, _choose_method, _hamming_search

    def words(f):
        q = np.ascontiguousarray(_as_words(f.descriptors[:, 0]))
        t = np.ascontiguousarray(_as_words(f.descriptors).transpose(0, 2, 1))
        return q, t

    f0, f1 = real_geobit
    q, _ = words(f0)
    _, t = words(f1)
    assert _choose_method(q, t, f0.valid, f1.valid, None) == "two-stage"
    rng = np.random.default_rng(3)
    r, s = (Features(np.zeros((300, 2)), rng.integers(0, 256, (300, 16, 64), dtype=np.uint8), np.ones(300, bool))
            for _ in range(2))
    q, _ = words(r)
    _, t = words(s)
    assert _choose_method(q, t, r.valid, s.valid, None) == "blocked"
    with pytest.raises(ValueError, match="method"):
        _hamming_search(r.descriptors, r.descriptors, r.valid, r.valid, False, None, method="fast")


def test_l2_search_in_blocks_equals_brute_force():
    """Queries split into blocks (the column minimum then spans blocks) give the brute-force matches,
    ties included (quantised descriptors), with the mutual check and the ratio test."""
    from geofeat.matching import _finish_matches, _l2_search

    rng = np.random.default_rng(5)
    for dtype in (np.float32, np.float64):
        f0 = Features(np.zeros((37, 2)), rng.integers(0, 3, (37, 5)).astype(dtype), rng.random(37) < 0.9)
        f1 = Features(np.zeros((23, 2)), rng.integers(0, 3, (23, 5)).astype(dtype), rng.random(23) < 0.9)
        for mutual, ratio in ((False, None), (True, None), (True, 0.9)):
            got = _finish_matches(*_l2_search(f0.descriptors, f1.descriptors, f0.valid, f1.valid, mutual, block=4),
                                  ratio=ratio, mutual=mutual)
            m, dist = reference_match(f0, f1, "l2", mutual=mutual, ratio=ratio)
            assert np.array_equal(got.matches0, m), (dtype, mutual, ratio)
            assert np.allclose(got.distances0[m >= 0], dist[m >= 0], rtol=1e-6)


def test_features_whose_fields_disagree_are_refused_by_name():
    rng = np.random.default_rng(0)
    f0 = Features(np.zeros((6, 2)), rng.standard_normal((6, 8)).astype(np.float32), None)
    f1 = Features(np.zeros((7, 2)), rng.standard_normal((7, 8)).astype(np.float32), None)
    f0.valid = np.ones(3, bool)  # replaced after construction: numpy's "boolean index did not match"
    with pytest.raises(ValueError, match="features0: keypoints, descriptors and valid"):
        match(f0, f1)
    f0.valid, f1.descriptors = np.ones(6, bool), f1.descriptors[:4]
    with pytest.raises(ValueError, match="features1: keypoints, descriptors and valid"):
        match(f0, f1)


def test_float_and_binary_descriptors_are_not_matched_together():
    rng = np.random.default_rng(0)
    floats = rng.standard_normal((6, 32)).astype(np.float32)
    bits = rng.integers(0, 256, (7, 32), dtype=np.uint8)
    for a, b in ((floats, bits), (bits, floats)):  # float first was matched by L2 to the bytes
        with pytest.raises(ValueError, match="different kinds"):
            match(a, b)
    assert len(match(floats, bits.astype(np.float32))) == 6  # float32 with float64/float32: one kind
    assert len(match(floats, bits, metric="l2")) == 6  # asked for


@pytest.mark.parametrize("device", [None, "cpu"])
def test_l2_matching_of_descriptors_with_a_large_common_part(device):
    """|a|^2 + |b|^2 - 2 a.b in float32 cancelled the differences of descriptors that share a large
    common part (mean 100, differences of 0.01) away: 0.5 % of the true nearest neighbours were found,
    with distance 0. The searches subtract the (whole-number) mean first."""
    if device is not None:
        pytest.importorskip("torch")
    rng = np.random.default_rng(0)
    a = (rng.standard_normal((200, 128)) * 0.01 + 100).astype(np.float32)
    b = a + (rng.standard_normal(a.shape) * 0.001).astype(np.float32)
    got = match(a, b, device=device)
    assert np.array_equal(got.matches0, np.arange(200))
    exact = np.linalg.norm(a.astype(np.float64) - b.astype(np.float64), axis=1)
    np.testing.assert_allclose(got.distances0, exact, rtol=1e-3)


@pytest.mark.parametrize("kwargs, message", [
    (dict(ratio=True), "ratio: expected a number"),  # ran as ratio 1.0
    (dict(ratio="0.8"), "ratio: expected a number"),  # a TypeError from the comparison
    (dict(mutual="no"), "mutual: expected True or False"),  # a non-empty string is truthy: mutual ran
    (dict(mutual=None), "mutual: expected True or False"),
])
def test_match_options_are_checked_by_name(kwargs, message):
    rng = np.random.default_rng(0)
    f0 = Features(rng.random((5, 2)), rng.random((5, 8)).astype(np.float32), np.ones(5, bool))
    f1 = Features(rng.random((6, 2)), rng.random((6, 8)).astype(np.float32), np.ones(6, bool))
    with pytest.raises(ValueError, match=message):
        match(f0, f1, **kwargs)
    assert (match(f0, f1, mutual=np.bool_(True), ratio=np.float64(0.9)).matches0 >= -1).all()  # numpy scalars pass


def _demo_gray() -> np.ndarray:
    import geofeat

    return (np.clip(geofeat.read_demo_frame().image, 0, 1) * 255).astype(np.uint8)


def test_uint8_sift_matched_by_hamming_is_warned_of_and_bits_are_not():
    """uint8 (N, 128) SIFT (COLMAP's L2-normalised x 512, or OpenCV's values cast) was matched by Hamming
    distance without a word; packed bits (ORB, GeoBit, random bytes) and unpacked 0/1 bits must not warn."""
    import cv2

    import geofeat

    gray = _demo_gray()
    _, sift = cv2.SIFT_create(500).detectAndCompute(gray, None)
    unit = sift / np.linalg.norm(sift, axis=1, keepdims=True)
    colmap = np.clip(np.round(unit * 512), 0, 255).astype(np.uint8)
    for quantised in (colmap, sift.astype(np.uint8)):
        with pytest.warns(UserWarning, match=r"zero bytes .*quantised histogram.*metric=\"l2\"") as record:
            match(quantised[:250], quantised[250:])
        assert record[0].filename == __file__  # points at the caller of match
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            match(quantised[:250], quantised[250:], metric="l2")  # the metric named: nothing to say
    _, orb = cv2.ORB_create(500).detectAndCompute(gray, None)
    frame = geofeat.read_demo_frame()
    geobit = geofeat.extract(frame, 300, descriptor="geobit")
    ours = geofeat.extract(frame, 300, descriptor="orb")
    random = np.random.default_rng(0).integers(0, 256, (300, 128), dtype=np.uint8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        match(orb[:250], orb[250:])
        match(geobit, geobit)  # (N, 16, 64): every rotation
        match(geobit.descriptors[:, 0], geobit.descriptors[:, 3])  # one rotation as (N, 64) bits
        match(ours, ours)
        match(random[:150], random[150:])
        match(np.unpackbits(orb[:50], axis=1), np.unpackbits(orb[50:100], axis=1))
        # invalid rows (zeros, as descriptors that could not be computed) are not judged
        padded = Features(np.zeros((600, 2)), np.concatenate([orb[:300], np.zeros((300, 32), np.uint8)]),
                          np.r_[np.ones(300, bool), np.zeros(300, bool)])
        match(padded, padded)


# --- ties and degenerate inputs: every path against the brute-force rule (lowest index wins) -------------

#: Whole-number 3-D points. From the origin, A and B are at squared distances 4204753 and 4204754, whose
#: float32 square roots are equal (a float32 distance made them a tie, and the lower index won); (4, 4, 0)
#: and (5, 5, 0) are at sqrt(32) = 0.8 sqrt(50) (the ratio test's threshold); (3, 4, 0) and (5, 0, 0)
#: tie at 5; (-0.0, 0, -0.0) is the origin again.
TIE_POINTS = np.array([[0, 0, 0], [2049, 73, 32], [2049, 76, 24], [4, 4, 0], [5, 5, 0], [3, 4, 0], [5, 0, 0],
                       [-0.0, 0, -0.0]])


def _tie_features(rows, valid, dtype, offset):
    return Features(np.zeros((len(rows), 2)), (TIE_POINTS[np.asarray(rows, int)] + offset).astype(dtype),
                    np.asarray(valid, bool))


@pytest.mark.parametrize("device", [None, "cpu"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_l2_whole_number_ties_and_ratio_threshold(device, dtype):
    """Squared distances are exact for whole-number descriptors: the nearest neighbour, the column's
    nearest query and the ratio test follow them, as brute force does. A float32 square root made
    squared distances 4204753 and 4204754 equal (the lower index won, in rows and in the mutual check),
    and sqrt(32) >= 0.8 sqrt(50) false in float32 (and in torch's float64 sqrt)."""
    if device is not None:
        pytest.importorskip("torch")
    origin = np.zeros((1, 3), dtype)
    far = TIE_POINTS[[1, 2]].astype(dtype)  # B (4204754) before A (4204753)
    got = match(origin, far, device=device)
    assert got.matches0.tolist() == [1] and got.distances0[0] == np.sqrt(4204753.0)
    got = match(far, origin, mutual=True, device=device)  # the origin's nearest query is A, not B
    assert got.matches0.tolist() == [-1, 0]
    got = match(origin, TIE_POINTS[[3, 4]].astype(dtype), ratio=0.8, device=device)
    assert got.matches0.tolist() == [-1]  # sqrt(32) < 0.8 sqrt(50) is false
    got = match(origin, TIE_POINTS[[5, 6, 6, 0, 7]].astype(dtype), device=device)
    assert got.matches0.tolist() == [3] and got.distances0[0] == 0.0


@settings(max_examples=120, deadline=None)
@given(
    rows0=st.lists(st.integers(0, len(TIE_POINTS) - 1), max_size=9),
    rows1=st.lists(st.integers(0, len(TIE_POINTS) - 1), max_size=9),
    invalid=st.sets(st.integers(0, 17), max_size=4),
    dtype=st.sampled_from([np.float32, np.float64]),
    offset=st.sampled_from([0.0, 2.0**20, -3e6]),  # a large common part, taken away by the centring
    mutual=st.booleans(),
    ratio=st.sampled_from([None, 1e-300, 0.5, 0.8, 1.0]),  # 1e-300: best / ratio far beyond uint64
    device=st.sampled_from([None, "cpu"]),
)
def test_l2_ties_equal_brute_force(rows0, rows1, invalid, dtype, offset, mutual, ratio, device):
    """Duplicate rows, exact ties, the ratio threshold, distances whose float32 square roots tie,
    -0.0, invalid rows, a large common offset, empty sides: both L2 paths give the brute-force matches
    (exact squared distances, lowest index first) and its distances."""
    if device is not None:
        pytest.importorskip("torch")
    n0 = len(rows0)
    f0 = _tie_features(rows0, [i not in invalid for i in range(n0)], dtype, offset)
    f1 = _tie_features(rows1, [n0 + j not in invalid for j in range(len(rows1))], dtype, offset)
    got = match(f0, f1, mutual=mutual, ratio=ratio, device=device)
    m, dist = reference_match(f0, f1, "l2", mutual=mutual, ratio=ratio)
    assert np.array_equal(got.matches0, m)
    assert np.array_equal(got.distances0, dist)


_POPCOUNT8 = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1).sum(1)


def hamming_matrix(d0, d1, valid0, valid1):
    """(N0, N1) Hamming distances, min over rotations for (N, R, B) (query rotation 0), brute force;
    inf where either side is invalid."""
    q = d0[:, 0] if d0.ndim == 3 else d0
    t = d1 if d1.ndim == 3 else d1[:, None]
    D = np.concatenate([_POPCOUNT8[q[s:s + 32, None, None] ^ t[None]].sum(-1).min(-1) for s in range(0, len(q), 32)])
    return np.where(valid0[:, None] & valid1[None, :], D.astype(np.float64), np.inf)


def brute_force(D, mutual, ratio):
    """The documented rule on a full distance matrix, vectorised: np.argmin (first index) of each row
    and column, the ratio test against the best of the other valid targets."""
    rows = np.arange(len(D))
    j = D.argmin(1)
    best = D[rows, j]
    others = D.copy()
    others[rows, j] = np.inf
    keep = np.isfinite(best)
    if ratio is not None:
        keep &= best < ratio * others.min(1)
    if mutual:
        keep &= D.argmin(0)[j] == rows
    return np.where(keep, j, -1), np.where(keep, best, np.inf)


# hamming; > 8 words (the generic kernel); GeoBit; 3 rotations; > 16 rotations; > 8 words with rotations
@pytest.mark.parametrize("shape", [(32,), (72,), (16, 64), (3, 64), (20, 8), (2, 72)])
def test_hamming_duplicates_tie_alike_on_every_path(shape):
    """Many duplicate rows built of bytes 0, 1 and 255 (rotations shifted, so ties also come from other
    rotations), all-zero rows, invalid rows at both ends and in the middle, N0 != N1 across query
    chunks and target blocks: every path (numba kernels with 1 and 2 threads, both rotation searches,
    torch on the CPU) gives brute force's matches, the lowest index winning every tie."""
    import numba

    from geofeat.matching import _finish_matches, _hamming_search

    rng = np.random.default_rng(len(shape) + shape[0])
    base = rng.choice(np.array([0, 1, 255], np.uint8), size=(4, *shape))
    base[0] = 0

    def make(n):
        d = base[rng.integers(0, 4, n)]
        if len(shape) == 2:  # the same descriptor seen at another rotation
            d = np.stack([np.roll(r, k, axis=0) for r, k in zip(d, rng.integers(0, shape[0], n))])
        valid = rng.random(n) < 0.9
        valid[[0, n // 2, -1]] = False
        return Features(np.zeros((n, 2)), d, valid)

    f0, f1 = (make(1025), make(300)) if shape[0] <= 3 or len(shape) == 1 else (make(300), make(257))
    metric = "hamming" if len(shape) == 1 else "hamming-rot"
    D = hamming_matrix(f0.descriptors, f1.descriptors, f0.valid, f1.valid)
    try:
        import torch  # noqa: F401
    except ImportError:
        torch = None
    threads = numba.get_num_threads()
    try:
        for mutual, ratio in ((False, None), (True, None), (False, 1.0), (True, 0.8)):
            want, dist = brute_force(D, mutual, ratio)
            got = {}
            for n_threads in sorted({1, threads}):
                numba.set_num_threads(n_threads)
                got[f"numba{n_threads}"] = match(f0, f1, metric=metric, mutual=mutual, ratio=ratio)
                if metric == "hamming-rot" and shape[0] <= 16:
                    for method in ("two-stage", "blocked"):
                        res = _hamming_search(f0.descriptors, f1.descriptors, f0.valid, f1.valid, mutual, ratio,
                                              method=method)
                        got[f"{method}{n_threads}"] = _finish_matches(*res, ratio=ratio, mutual=mutual)
            if torch is not None:
                got["torch"] = match(f0, f1, metric=metric, mutual=mutual, ratio=ratio, device="cpu")
            for path, g in got.items():
                assert np.array_equal(g.matches0, want), (path, mutual, ratio)
                assert np.array_equal(g.distances0, dist), (path, mutual, ratio)
    finally:
        numba.set_num_threads(threads)


@settings(max_examples=60, deadline=None)
@given(
    n0=st.integers(0, 3),
    n1=st.integers(0, 3),
    shape=st.sampled_from([(1,), (8,), (16, 64), (3, 9)]),
    data=st.data(),
    mutual=st.booleans(),
    ratio=st.sampled_from([None, 0.5, 1.0]),
    device=st.sampled_from([None, "cpu"]),
)
def test_hamming_degenerate_inputs_equal_brute_force(n0, n1, shape, data, mutual, ratio, device):
    """Zero, one or a few rows of bytes 0, 1 and 255 (all-zero rows, duplicates, single bytes), any
    valid mask: the numba and torch paths give brute force's matches and distances."""
    if device is not None:
        pytest.importorskip("torch")
    byte = st.sampled_from([0, 1, 255])

    def make(n):
        d = np.array(data.draw(st.lists(byte, min_size=n * int(np.prod(shape)), max_size=n * int(np.prod(shape)))),
                     np.uint8).reshape(n, *shape)
        valid = np.array(data.draw(st.lists(st.booleans(), min_size=n, max_size=n)), bool)
        return Features(np.zeros((n, 2)), d, valid)

    f0, f1 = make(n0), make(n1)
    metric = "hamming" if len(shape) == 1 else "hamming-rot"  # named: bytes 0 and 1 look like a histogram
    got = match(f0, f1, metric=metric, mutual=mutual, ratio=ratio, device=device)
    if n0 == 0 or n1 == 0:
        want, dist = np.full(n0, -1), np.full(n0, np.inf)
    else:
        want, dist = brute_force(hamming_matrix(f0.descriptors, f1.descriptors, f0.valid, f1.valid), mutual, ratio)
    assert np.array_equal(got.matches0, want)
    assert np.array_equal(got.distances0, dist)


def test_l2_descriptors_whose_squared_distances_overflow_are_refused():
    """Finite float32 descriptors of size 1e20 gave inf - inf = NaN squared distances (numpy's
    RuntimeWarning only): every keypoint came back unmatched, and float64 ones of 1e160 likewise; in
    distance_matrix they were NaN. Invalid rows are not looked at; float64 matches what float32 cannot."""
    from geofeat.matching import distance_matrix

    rng = np.random.default_rng(0)
    d0 = (rng.normal(size=(20, 32)) * 1e20).astype(np.float32)
    d1 = (d0 + rng.normal(size=(20, 32)).astype(np.float32) * 1e18).astype(np.float32)
    with pytest.raises(ValueError, match=r"features0 has a row of squared norm \d.*e\+41: its squared L2 distances .*"
                                         r"overflow float32 .*divide them by their largest norm\), or pass them as float64"):
        match(d0, d1)
    with pytest.raises(ValueError, match=r"features1 .*overflow float64"):
        match(d0.astype(np.float64), d1.astype(np.float64) * 1e140)
    with pytest.raises(ValueError, match=r"descriptors0 .*overflow the float32 distance matrix"):
        distance_matrix(d0.astype(np.float64) * 1e140, d1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning on the way
        assert (match(d0.astype(np.float64), d1).matches0 == np.arange(20)).all()  # float64 holds them
        assert (distance_matrix(d0, d1).argmin(axis=1) == np.arange(20)).all()  # squared in float64
        valid = np.ones(20, bool)
        valid[3] = False
        huge = d0.astype(np.float64) / 1e20
        huge[3] = 1e200  # finite, on an invalid keypoint: not looked at
        assert match(Features(np.zeros((20, 2)), huge, valid), d0.astype(np.float64) / 1e20).matches0[3] == -1
