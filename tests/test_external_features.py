"""`geofeat bench --features NAME=PATH`: feature files written elsewhere that used to give wrong numbers
without a word (geofeat.bench.external)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from geofeat.bench.external import ExternalFeatures

SHAPE = (120, 160)  # (H, W)


def _frame(n=40, seed=0):
    rng = np.random.default_rng(seed)
    kp = rng.uniform(5, 110, (n, 2)).astype(np.float32)
    return kp, rng.normal(size=(n, 32)).astype(np.float32), rng.uniform(0, 1, n).astype(np.float32)


def _h5(path, groups):
    with h5py.File(path, "w") as fd:
        for g, arrays in groups.items():
            for k, v in arrays.items():
                fd[f"{g}/{k}"] = v
    return path


def _load(path, frame="f0", n=None, sequence="seq"):
    return ExternalFeatures("m", path).load(sequence, frame, n, shape=SHAPE)


def test_more_keypoints_than_the_budget_without_scores_are_refused(tmp_path):
    """Without `scores` nothing was cut to --keypoints: the method was scored at a larger budget than
    the others (120 keypoints against 64), unsaid."""
    kp, desc, scores = _frame()
    path = _h5(tmp_path / "f.h5", {"f0": {"keypoints": kp, "descriptors": desc.T}})
    with pytest.raises(ValueError, match="40 keypoints and no 'scores'.*--keypoints 20"):
        _load(path, n=20)
    assert len(_load(path, n=40)) == 40  # within the budget: kept as they are, in their order
    _h5(path, {"f0": {"keypoints": kp, "descriptors": desc.T, "scores": scores}})
    got = _load(path, n=20)
    np.testing.assert_array_equal(got.keypoints, kp[np.sort(np.argsort(-scores)[:20])])


@pytest.mark.parametrize("name, field", [("score", "scores"), ("Metric", "metric"), ("descriptor", "descriptors")])
def test_a_misspelled_field_is_refused_not_ignored(tmp_path, name, field):
    kp, desc, scores = _frame()
    arrays = {"keypoints": kp, "descriptors": desc.T, "scores": scores}
    arrays[name] = arrays.pop(field) if field in arrays else np.bytes_("l2")
    if field == "descriptors":
        arrays["descriptors"] = desc.T
    with pytest.raises(ValueError, match=f"holds '{name}', which is not read; did you mean '{field}'"):
        _load(_h5(tmp_path / "f.h5", {"f0": arrays}))
    arrays.pop(name)
    arrays["image_size"] = np.array([SHAPE[1], SHAPE[0]])  # hloc's other field is no near miss
    _load(_h5(tmp_path / "g.h5", {"f0": arrays}))


def test_sift_stored_as_uint8_without_metric_is_refused(tmp_path):
    """Matched as packed bits by Hamming: another distance than SIFT's L2, and another score."""
    kp, _, _ = _frame()
    rng = np.random.default_rng(1)
    sift = np.where(rng.uniform(size=(40, 128)) < 0.3, 0, rng.integers(1, 120, (40, 128))).astype(np.uint8)
    with pytest.raises(ValueError, match="uint8 descriptors without 'metric', 3.% of their bytes 0"):
        _load(_h5(tmp_path / "f.h5", {"f0": {"keypoints": kp, "descriptors": sift}}))
    ex = ExternalFeatures("m", _h5(tmp_path / "g.h5", {"f0": {"keypoints": kp, "descriptors": sift, "metric": np.bytes_("l2")}}))
    assert len(ex.load("seq", "f0", shape=SHAPE)) == 40 and ex.metric == "l2"
    bits = rng.integers(0, 256, (40, 32)).astype(np.uint8)  # packed bits (ORB): read as before
    _load(_h5(tmp_path / "h.h5", {"f0": {"keypoints": kp, "descriptors": bits}}))
    unpacked = np.unpackbits(bits, axis=1)  # 0/1 bytes: Hamming over bytes equals Hamming over the bits
    _load(_h5(tmp_path / "i.h5", {"f0": {"keypoints": kp, "descriptors": unpacked}}))


def test_normalised_keypoints_and_another_image_size_are_refused(tmp_path):
    """Keypoints in [0, 1] passed the on-image check and scored 0 (none on the object); keypoints of a
    half-size image (hloc's image_size says so) scored near 0."""
    kp, desc, scores = _frame()
    with pytest.raises(ValueError, match="all 40 keypoints lie within 1 px of the origin: normalised"):
        _load(_h5(tmp_path / "f.h5", {"f0": {"keypoints": kp / [160, 120], "descriptors": desc.T}}))
    with pytest.raises(ValueError, match=r"image_size \[80, 60\] \(hloc's \(W, H\)\) is not the frame's \[160, 120\]"):
        _load(_h5(tmp_path / "g.h5", {"f0": {"keypoints": kp / 2, "descriptors": desc.T, "image_size": np.array([80, 60])}}))
    _load(_h5(tmp_path / "h.h5", {"f0": {"keypoints": kp, "descriptors": desc.T, "image_size": np.array([160, 120])}}))
    _load(_h5(tmp_path / "i.h5", {"f0": {"keypoints": kp[:3] / 200, "descriptors": desc[:3].T}}))  # too few to tell


def test_a_keypoint_stored_twice_is_refused(tmp_path):
    """Copies took half the --keypoints budget and tied in matching: the matching score halved."""
    kp, desc, scores = _frame()
    with pytest.raises(ValueError, match="40 of 80 keypoints repeat an earlier one.*--keypoint-set unique"):
        _load(_h5(tmp_path / "f.h5", {"f0": {"keypoints": np.r_[kp, kp], "descriptors": np.r_[desc, desc].T}}))
    other = desc.copy()
    other[:, 0] += 1  # one position, another descriptor (SIFT's second orientation): kept
    assert len(_load(_h5(tmp_path / "g.h5", {"f0": {"keypoints": np.r_[kp, kp], "descriptors": np.r_[desc, other].T}}))) == 80


def test_groups_named_by_image_file_as_hloc_names_them(tmp_path):
    kp, desc, _ = _frame()
    for key in ("seq/f0-rgb.png", "f0-rgb.png"):
        path = _h5(tmp_path / f"{key.replace('/', '_')}.h5", {key: {"keypoints": kp, "descriptors": desc.T}})
        np.testing.assert_array_equal(_load(path).keypoints, kp)
    path = _h5(tmp_path / "upper.h5", {"F0": {"keypoints": kp, "descriptors": desc.T}})
    with pytest.raises(ValueError, match=r"no group 'seq/f0'.*holds e.g. \['F0'\]"):
        _load(path)


@pytest.mark.parametrize("npz", [False, True])
def test_frames_without_the_sequence_in_their_name_serve_one_sequence_only(tmp_path, npz):
    """Two sequences with the same frame names (every simulated one has frame-000-master...): the
    second was scored with the first one's features, near 0, without a word."""
    from geofeat.bench.external import check_one_source_per_frame

    kp, desc, _ = _frame()
    frames = ["frame-000-master", "frame-001"]
    if npz:
        path = tmp_path / "npz"
        path.mkdir()
        for f in frames:
            np.savez(path / f"{f}.npz", keypoints=kp, descriptors=desc)
    else:
        path = _h5(tmp_path / "f.h5", {f: {"keypoints": kp, "descriptors": desc.T} for f in frames})
    ex = ExternalFeatures("m", path)
    check_one_source_per_frame([ex], {"a": frames})  # one sequence: fine
    with pytest.raises(ValueError, match="frame-000-master of a and of b would both be read from"):
        check_one_source_per_frame([ex], {"a": frames, "b": frames})
    if not npz:
        path = _h5(tmp_path / "g.h5", {f"{s}/{f}": {"keypoints": kp, "descriptors": desc.T} for s in "ab" for f in frames})
        check_one_source_per_frame([ExternalFeatures("m", path)], {"a": frames, "b": frames})


def test_bench_refuses_two_sequences_read_from_one_set_of_groups(tmp_path):
    """The check runs in run_benchmark, before any sequence is read."""
    from geofeat.bench.runner import BenchConfig, run_benchmark

    kp, desc, _ = _frame()
    for s in ("a", "b"):
        for f in ("frame-000-master", "frame-001"):
            (tmp_path / "data" / s).mkdir(parents=True, exist_ok=True)
            (tmp_path / "data" / s / f"{f}-rgb.png").write_bytes(b"")
    path = _h5(tmp_path / "f.h5", {f: {"keypoints": kp, "descriptors": desc.T} for f in ("frame-000-master", "frame-001")})
    config = BenchConfig(descriptors=(), features=(f"m={path}",))
    with pytest.raises(ValueError, match="would both be read from 'frame-000-master'"):
        run_benchmark(tmp_path / "data", tmp_path / "out", config, progress=False)


@pytest.mark.parametrize("layout", ["h5", "npz", "extract"])
def test_a_frame_missing_under_its_sequence_is_not_read_from_a_name_without_it(tmp_path, layout):
    """Features named '<sequence>/<frame>' for every frame but one, which a name without the sequence
    (left from a run on another sequence) still served: that frame was scored with another image's
    features (MS 0) without a word. A sequence read from both kinds of names is refused."""
    from geofeat.bench.external import check_one_source_per_frame

    kp, desc, _ = _frame()
    frames = ["frame-000-master", "frame-001", "frame-002"]
    qualified, bare = frames[:2], frames[2:]
    if layout == "h5":
        groups = {f"a/{f}": {"keypoints": kp, "descriptors": desc.T} for f in qualified}
        groups.update({f: {"keypoints": kp, "descriptors": desc.T} for f in bare})
        path = _h5(tmp_path / "f.h5", groups)
    else:
        root = tmp_path / "feats"
        (root / "a").mkdir(parents=True)
        name = (lambda f: f"{f}.npz") if layout == "npz" else (lambda f: f"m-{f}.npz")
        for f in qualified:
            np.savez(root / "a" / name(f), keypoints=kp, descriptors=desc)
        for f in bare:
            np.savez(root / name(f), keypoints=kp, descriptors=desc)
        path = root if layout == "npz" else root / "m.npz"
    ex = ExternalFeatures("m", path)
    with pytest.raises(ValueError, match=r"a: frame-002 would be read from .* without the sequence"):
        check_one_source_per_frame([ex], {"a": frames})
    check_one_source_per_frame([ex], {"a": qualified})  # every frame under the sequence's name: fine
    check_one_source_per_frame([ex], {"b": bare})  # every frame without it, one sequence: fine


@pytest.mark.parametrize("metric", [None, "l2"])
def test_frames_with_descriptors_of_another_kind_are_refused_by_name(tmp_path, metric):
    """A set whose reference frame holds uint8 descriptors and a target float ones (two exports mixed):
    without `metric` the sequence failed with match's "features0 (uint8) and features1 (float32) are of
    different kinds ... pass metric=", naming neither the set nor the frame; with `metric` 'l2' stored,
    the bytes were matched against the floats and scored without a word."""
    from geofeat.bench.runner import BenchConfig, evaluate_external
    from geofeat.groundtruth.sources import GroundTruth
    from geofeat.io import read_sequence, write_frame, write_intrinsics, write_landmarks

    H, W = SHAPE
    folder = tmp_path / "seq"
    folder.mkdir()
    write_intrinsics(folder / "intrinsics.xml", np.array([[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]]))
    gx, gy = np.meshgrid(np.linspace(10, W - 10, 5), np.linspace(10, H - 10, 4))
    landmarks = np.stack([gx.ravel(), gy.ravel()], 1)
    rng = np.random.default_rng(0)
    frames = ("frame-000-master", "frame-001")
    for name in frames:
        write_frame(folder, name, rng.integers(0, 255, (H, W, 3), dtype=np.uint8), np.ones((H, W)))
        write_landmarks(folder / f"{name}.csv", np.arange(len(landmarks)), landmarks, np.ones(len(landmarks), bool))
    kp, _, _ = _frame()
    bits = rng.integers(0, 256, (len(kp), 32)).astype(np.uint8)
    extra = {} if metric is None else {"metric": np.bytes_(metric)}
    path = _h5(tmp_path / "f.h5", {"frame-000-master": {"keypoints": kp, "descriptors": bits, "valid": np.ones(len(kp), bool), **extra},
                                   "frame-001": {"keypoints": kp, "descriptors": bits.astype(np.float32),
                                                 "valid": np.ones(len(kp), bool), **extra}})
    seq = read_sequence(folder)
    config = BenchConfig(descriptors=(), features=(f"m={path}",))
    with pytest.raises(ValueError, match=r"features m: seq/frame-001 has float32 descriptors of shape \(32,\), "
                                         r"frame-000-master uint8 of \(32,\); every frame's must be of one kind"):
        evaluate_external(seq, GroundTruth(seq, None), ExternalFeatures("m", path), config)
    _h5(path, {f: {"keypoints": kp, "descriptors": bits, "valid": np.ones(len(kp), bool), **extra} for f in frames})
    rows = evaluate_external(seq, GroundTruth(seq, None), ExternalFeatures("m", path), config)
    assert len(rows) == 1 and rows[0]["ms"] == 1.0  # one kind: scored (the same features, landmarks and pixels)


def test_float16_keypoints_rounded_by_half_a_pixel_or_more_are_scored_with_a_warning(tmp_path):
    """`bench --features` on an hloc .h5 written with `as_half`: float16 keypoints at x >= 1024 are 1 px
    apart, so the 3 px protocol scored rounded positions without a word. One warning per file and step
    (not per frame), naming the file and the step; the features are still read."""
    import warnings

    kp, desc, scores = _frame()
    wide = (kp + [1100, 0]).astype(np.float16)  # x in 1105..1210: 1 px steps
    path = _h5(tmp_path / "f.h5", {"seq/f0": {"keypoints": wide, "descriptors": desc.T},
                                   "seq/f1": {"keypoints": wide, "descriptors": desc.T},
                                   "seq/f2": {"keypoints": kp.astype(np.float16), "descriptors": desc.T}})
    features = ExternalFeatures("m", path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        first = features.load("seq", "f0", shape=(240, 1280))
        features.load("seq", "f1", shape=(240, 1280))
        features.load("seq", "f2", shape=(240, 1280))  # under 512 px: nothing to say
    messages = [str(w.message) for w in caught]
    assert len(messages) == 1 and "features m: seq/f0" in messages[0] and str(path) in messages[0]
    assert "float16" in messages[0] and "up to 1 px" in messages[0]
    np.testing.assert_array_equal(first.keypoints, wide.astype(np.float64))
