"""Features / Matches records and their .npz / .h5 round trips."""

from __future__ import annotations

import warnings

import h5py
import numpy as np
import pytest

import geofeat
from geofeat.features import Features, Matches, list_names, load_features, load_matches, save_features, save_matches


def make_features(n=7, seed=0, with_extras=True):
    rng = np.random.default_rng(seed)
    return Features(
        keypoints=rng.random((n, 2)) * 100,
        descriptors=rng.integers(0, 256, (n, 16, 64), dtype=np.uint8),
        valid=rng.random(n) < 0.7,
        angles=rng.random(n) * 360 if with_extras else None,
        sizes=rng.random(n) * 10 if with_extras else None,
    )


def assert_same(a: Features, b: Features, kp_tol=0.0):
    assert np.allclose(a.keypoints, b.keypoints, atol=kp_tol, rtol=0)
    assert a.descriptors.dtype == b.descriptors.dtype and np.array_equal(a.descriptors, b.descriptors)
    assert np.array_equal(a.valid, b.valid)
    for name in ("angles", "sizes"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None and y is None) or np.array_equal(x, y)


@pytest.mark.parametrize("extras", [True, False])
def test_features_npz_round_trip(tmp_path, extras):
    f = make_features(with_extras=extras)
    save_features(tmp_path / "a.npz", f)
    assert_same(f, load_features(tmp_path / "a.npz"))


def test_features_h5_round_trip_hloc_layout(tmp_path):
    path = tmp_path / "features.h5"
    fa, fb = make_features(5, 1), make_features(0, 2, with_extras=False)
    fb_float = Features(np.zeros((3, 2)), np.ones((3, 128), np.float32), np.ones(3, bool))
    save_features(path, fa, name="seq/a.png")
    save_features(path, fb, name="b.png")
    save_features(path, fb_float, name="c.png")
    assert sorted(list_names(path)) == ["b.png", "c.png", "seq/a.png"]
    with h5py.File(path, "r") as fd:  # hloc layout: group per image, plain datasets
        assert set(fd["seq/a.png"].keys()) >= {"keypoints", "descriptors", "valid"}
        assert fd["seq/a.png/descriptors"].shape == (5, 16, 64)
    assert_same(fa, load_features(path, "seq/a.png"), kp_tol=1e-4)  # float32 keypoints as in hloc
    assert_same(fb, load_features(path, "b.png"))
    assert_same(fb_float, load_features(path, "c.png"))
    # overwrite replaces, and a single-image file needs no name
    save_features(path, fb_float, name="seq/a.png")
    assert_same(fb_float, load_features(path, "seq/a.png"))
    single = tmp_path / "single.h5"
    save_features(single, fa, name="x")
    assert_same(fa, load_features(single), kp_tol=1e-4)
    with pytest.raises(ValueError, match="name"):
        load_features(path)
    with pytest.raises(ValueError, match=r"name: .*features.h5' has no group 'missing.png'; it holds ") as error:
        load_features(path, "missing.png")  # was a KeyError
    assert all(repr(name) in str(error.value) for name in ("seq/a.png", "b.png", "c.png"))
    with pytest.raises(ValueError, match="name"):
        save_features(path, fa)


def test_matches_round_trips(tmp_path):
    m = Matches(np.array([3, -1, 0, 2]), np.array([10.0, np.inf, 0.0, 7.5]))
    save_matches(tmp_path / "m.npz", m)
    save_matches(tmp_path / "m.h5", m, name="a.png/b.png")
    for got in (load_matches(tmp_path / "m.npz"), load_matches(tmp_path / "m.h5", "a.png/b.png")):
        assert got.matches0.dtype == np.int64 and np.array_equal(got.matches0, m.matches0)
        assert np.array_equal(got.distances0, m.distances0)
    assert m.pairs.tolist() == [[0, 3], [2, 0], [3, 2]]


def test_bad_inputs():
    with pytest.raises(ValueError, match="descriptors"):
        Features(np.zeros((3, 2)), np.zeros((4, 8), np.uint8), np.ones(3, bool))
    with pytest.raises(ValueError, match="keypoints"):
        Features(np.zeros((3, 3)), np.zeros((3, 8), np.uint8), np.ones(3, bool))
    with pytest.raises(ValueError, match="valid"):
        Features(np.zeros((3, 2)), np.zeros((3, 8), np.uint8), np.ones(2, bool))
    with pytest.raises(ValueError, match=".npz or .h5"):
        save_features("x.txt", make_features())


def test_npz_names_in_upper_case_round_trip(tmp_path):
    """np.savez appends ".npz" to a name that does not end so in lower case: "A.NPZ" was written as
    "A.NPZ.npz", and loading "A.NPZ" failed."""
    f, m = make_features(), Matches([1, -1, 0], [0.5, np.inf, 2.0])
    save_features(tmp_path / "A.NPZ", f)
    save_matches(tmp_path / "M.Npz", m)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["A.NPZ", "M.Npz"]
    assert_same(load_features(tmp_path / "A.NPZ"), f)
    assert load_matches(tmp_path / "M.Npz").matches0.tolist() == [1, -1, 0]


def test_h5_nested_names_are_kept_and_folders_are_not_images(tmp_path):
    path = tmp_path / "f.h5"
    a, ab = make_features(seed=1), make_features(n=4, seed=2)
    save_features(path, ab, "a/b.png")
    save_features(path, a, "a")  # replaced "a" whole, deleting the other image "a/b.png"
    save_features(path, a, "a")  # and again: only a's own datasets are replaced
    assert_same(load_features(path, "a"), a, kp_tol=1e-4)  # a's datasets only, not the group "b.png" in it
    assert_same(load_features(path, "a/b.png"), ab, kp_tol=1e-4)
    save_features(tmp_path / "g.h5", a, "seq/img.png")
    with pytest.raises(ValueError, match="no group 'seq'.*seq/img.png"):  # was h5py's "Accessing a group is done with..."
        load_features(tmp_path / "g.h5", "seq")
    save_features(path, a, 7)  # a name that is not a string is stored under str(name) and loads back by it
    assert_same(load_features(path, 7), a, kp_tol=1e-4)


def test_external_hloc_descriptors_are_read_as_d_by_n_even_when_square(tmp_path):
    """hloc writes float descriptors (D, N) and no `valid`: with 128 keypoints of 128-d descriptors
    the layout cannot be told by shape, so such a group is read as hloc's."""
    import h5py

    from geofeat.bench.external import ExternalFeatures

    rng = np.random.default_rng(0)
    kp = rng.uniform(0, 100, (128, 2)).astype(np.float32)
    desc = rng.normal(size=(128, 128)).astype(np.float32)  # (N, D)
    path = tmp_path / "hloc.h5"
    with h5py.File(path, "w") as fd:
        fd.create_group("seq/f0")
        fd["seq/f0/keypoints"] = kp
        fd["seq/f0/descriptors"] = desc.T  # hloc's (D, N)
    got = ExternalFeatures("m", path).load("seq", "f0", shape=(120, 160))
    np.testing.assert_array_equal(got.descriptors, desc)


@pytest.mark.parametrize("n, dim", [(300, 256), (128, 128)])
def test_load_features_reads_hloc_groups_descriptors_as_n_by_d(tmp_path, n, dim):
    """hloc writes float descriptors (D, N) and no `valid`: load_features raised "descriptors: expected
    first axis" for them, and with D = N returned the transposed matrix without a word."""
    rng = np.random.default_rng(0)
    kp = rng.uniform(0, 100, (n, 2)).astype(np.float32)
    desc = rng.normal(size=(n, dim)).astype(np.float32)
    with h5py.File(tmp_path / "hloc.h5", "w") as fd:
        fd["img.png/keypoints"] = kp
        fd["img.png/descriptors"] = desc.T
        fd["img.png/scores"] = rng.random(n).astype(np.float32)
    got = load_features(tmp_path / "hloc.h5", "img.png")
    np.testing.assert_array_equal(got.descriptors, desc)
    assert got.valid.all()
    square = Features(kp[:dim], desc[:dim], np.ones(dim, bool))  # geofeat's own files (with `valid`) are (N, D)
    save_features(tmp_path / "own.h5", square, "img.png")
    np.testing.assert_array_equal(load_features(tmp_path / "own.h5").descriptors, desc[:dim])


def test_loading_the_wrong_kind_of_file_names_it(tmp_path):
    """A matches file given to load_features (and the reverse) was a bare KeyError: 'keypoints'."""
    save_matches(tmp_path / "m.npz", Matches([0, -1], [1.0, np.inf]))
    save_features(tmp_path / "f.npz", make_features())
    with pytest.raises(ValueError, match=r"m.npz' holds no 'keypoints' or 'descriptors', so it is not a features"):
        load_features(tmp_path / "m.npz")
    with pytest.raises(ValueError, match=r"f.npz' holds no 'matches0', so it is not a matches file"):
        load_matches(tmp_path / "f.npz")


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_a_truncated_or_foreign_file_is_refused_by_name(tmp_path, suffix):
    """A truncated .npz raised a bare BadZipFile ("File is not a zip file"), a foreign one numpy's
    advice to unpickle it, a truncated .h5 h5py's OSError: none named the file."""
    good = tmp_path / f"good{suffix}"
    save_features(good, make_features(), name="img")
    save_matches(tmp_path / f"m{suffix}", Matches([0, -1], [1.0, np.inf]), name="a/b")
    data = good.read_bytes()
    (tmp_path / f"cut{suffix}").write_bytes(data[: len(data) // 2])
    (tmp_path / f"text{suffix}").write_text("keypoints,descriptors\n")
    for bad in ("cut", "text"):
        path = tmp_path / f"{bad}{suffix}"
        with pytest.raises(ValueError, match=f"path: cannot read '.*{bad}{suffix}' as"):
            load_features(path)
        with pytest.raises(ValueError, match=f"path: cannot read '.*{bad}{suffix}' as"):
            load_matches(path)
    if suffix == ".h5":  # adding to a damaged file
        with pytest.raises(ValueError, match="path: cannot read '.*cut.h5' as HDF5"):
            save_features(tmp_path / "cut.h5", make_features(), name="img")
    else:
        np.save(tmp_path / "arr.npy", np.zeros(3))
        (tmp_path / "arr.npy").rename(tmp_path / "arr.npz")
        with pytest.raises(ValueError, match="arr.npz' as an .npz archive .*single .npy array"):
            load_features(tmp_path / "arr.npz")
    with pytest.raises(FileNotFoundError, match=f"path: '.*missing{suffix}' does not exist"):
        load_features(tmp_path / f"missing{suffix}")


def test_valid_flags_that_are_not_flags_are_refused(tmp_path):
    """A `valid` array of scores (or visibility codes) from another tool was cast to bool: every
    keypoint with a score above 0, however low, was read as valid."""
    np.savez(tmp_path / "scores.npz", keypoints=np.zeros((3, 2)), descriptors=np.zeros((3, 4), np.float32),
             valid=np.array([0.1, 0.9, 0.0]))
    with pytest.raises(ValueError, match=r"valid: expected flags \(bool, or 0 and 1\), got float64 values such as "
                                         r"\[0.1, 0.9\]"):
        load_features(tmp_path / "scores.npz")
    f = Features(np.zeros((3, 2)), np.zeros((3, 4), np.float32), np.array([1, 0, 1], np.uint8))  # 0/1 still read
    assert f.valid.tolist() == [True, False, True]


@pytest.mark.parametrize("name", ["brand", "dali", "tfeat-sim", "orb", "geobit"])
def test_descriptors_record_the_keypoints_sizes_as_given(name, tmp_path):
    """`Features.sizes` is the detector's keypoint diameter. BRAND, DaLI and the image-patch nets
    recorded their 8 px stand-in for bare (N, 2) positions, which no detector gave (the other
    descriptors recorded NaN), and a file written from them read back as if a detector had measured 8 px;
    sizes and angles that were given come back as given, in the documented units."""
    import warnings

    from geofeat.descriptors import make_descriptor
    from geofeat.frame import RGBDFrame
    from geofeat.keypoints import Keypoints

    rng = np.random.default_rng(0)
    K = np.array([[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]])
    frame = RGBDFrame(rng.random((120, 160)).astype(np.float32), np.full((120, 160), 0.5, np.float32), K)
    xy = np.array([[80.0, 60.0], [60.0, 50.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        descriptor = make_descriptor(name)
        bare = descriptor.compute(frame, xy)
        given = descriptor.compute(frame, Keypoints(xy, [30.0, 300.0], [5.0, 12.0], [2.0, 1.0]))
    assert np.isnan(bare.sizes).all()
    path = tmp_path / "f.npz"
    save_features(path, given)
    back = load_features(path)
    np.testing.assert_array_equal(back.sizes, [5.0, 12.0])
    np.testing.assert_array_equal(back.angles, [30.0, 300.0])


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_extract_keeps_the_detector_scores_through_a_file(tmp_path, suffix):
    """`geofeat.extract` and the descriptors dropped the detector's scores: a features file could not be
    cut to its best n later (hloc's `scores`, which `geofeat bench --features` reads)."""
    frame = geofeat.read_demo_frame()
    features = geofeat.extract(frame, n=200)
    kps = geofeat.detect(frame, 200)
    np.testing.assert_array_equal(features.scores, kps.responses)  # best first, as detected
    assert (np.diff(features.scores) <= 0).all()
    path = tmp_path / f"f{suffix}"
    geofeat.save_features(path, features, name="cloud" if suffix == ".h5" else None)
    back = geofeat.load_features(path, name="cloud" if suffix == ".h5" else None)
    np.testing.assert_array_equal(back.scores, features.scores)
    # bare pixels carry no detector score: none is written
    bare = geofeat.make_descriptor("orb").compute(frame, kps.xy)
    assert bare.scores is None


@pytest.mark.parametrize("name", [".", "..", "/img.png", "dir//img.png", "dir/./img.png", "img.png/"])
def test_an_h5_name_that_hdf5_reads_as_another_path_is_refused(tmp_path, name):
    """HDF5 takes names as paths: '.' wrote the features into the file's root group, which the name
    listing did not show, and '/img.png' or 'dir//img.png' were listed under other names."""
    f = Features(np.zeros((2, 2)), np.zeros((2, 4), np.float32), np.ones(2, bool))
    with pytest.raises(ValueError, match="name: .* relative path"):
        save_features(tmp_path / "f.h5", f, name=name)
    save_features(tmp_path / "f.h5", f, name="dir/sub/img.png")
    assert list_names(tmp_path / "f.h5") == ["dir/sub/img.png"]


def test_an_npz_file_read_by_another_name_is_refused(tmp_path):
    """save_features / save_matches ignored `name` for an .npz file (one image per file), and the
    loaders ignored it too: frames saved in a loop to one .npz "with their names", as to an .h5 file,
    left the last one only, and load_features(path, name="frame-000") returned frame-001's features
    without a word. The name is kept with the file and checked; the file still reads without one."""
    first, second = make_features(seed=0), make_features(seed=1)
    path = tmp_path / "f.npz"
    save_features(path, first, name="frame-000")
    assert_same(first, load_features(path, name="frame-000"))
    save_features(path, second, name="frame-001")  # replaces the file: one image per .npz
    with pytest.raises(ValueError, match="holds 'frame-001', not 'frame-000'"):
        load_features(path, name="frame-000")
    assert_same(second, load_features(path, name="frame-001"))
    assert_same(second, load_features(path))
    save_features(tmp_path / "plain.npz", first)  # saved without a name: any name reads it
    assert_same(first, load_features(tmp_path / "plain.npz", name="frame-000"))
    matches = Matches(np.array([1, -1, 0]), np.array([3.0, np.inf, 5.0]))
    save_matches(tmp_path / "m.npz", matches, name="a/b")
    assert load_matches(tmp_path / "m.npz", name="a/b") == matches == load_matches(tmp_path / "m.npz")
    with pytest.raises(ValueError, match="holds 'a/b', not 'a/c'"):
        load_matches(tmp_path / "m.npz", name="a/c")


@pytest.mark.parametrize("n", [64, 128])  # 128 keypoints of 128 dimensions: the square case
def test_float_descriptors_go_into_h5_as_hloc_stores_them_and_come_back(tmp_path, n):
    """hloc's matchers read an .h5 group's float descriptors as (D, N); written as (N, D), two images
    with the same keypoint count were matched with N taken for the descriptor length, without an
    error. The file holds (D, N) and says so; geofeat reads it back as (N, D), and a file written
    before (N, D, no attribute) still reads right."""
    rng = np.random.default_rng(3)
    desc = rng.normal(size=(n, 128)).astype(np.float32)
    features = Features(rng.uniform(0, 50, (n, 2)), desc, np.ones(n, bool))
    path = tmp_path / "features.h5"
    save_features(path, features, name="img.png")
    with h5py.File(path, "r") as fd:
        stored = fd["img.png/descriptors"]
        assert stored.shape == (128, n)
        np.testing.assert_array_equal(stored[()], desc.T)  # what an hloc matcher sees: column j = keypoint j
    assert_same(features, load_features(path, "img.png"), kp_tol=1e-4)
    from geofeat.bench.external import ExternalFeatures  # bench --features reads the same groups

    np.testing.assert_array_equal(ExternalFeatures("x", path).load("seq", "img.png").descriptors, desc)
    old = tmp_path / "old.h5"  # a file of the earlier layout: (N, D), no attribute
    with h5py.File(old, "w") as fd:
        grp = fd.create_group("img.png")
        grp["keypoints"], grp["descriptors"], grp["valid"] = features.keypoints.astype(np.float32), desc, features.valid
    np.testing.assert_array_equal(load_features(old, "img.png").descriptors, desc)
    binary = Features(np.zeros((4, 2)), np.ones((4, 32), np.uint8), np.ones(4, bool))
    save_features(path, binary, name="orb.png")  # binary descriptors are not hloc's: stored as they are
    with h5py.File(path, "r") as fd:
        assert fd["orb.png/descriptors"].shape == (4, 32)


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_features_with_keypoints_that_are_not_finite_are_refused(tmp_path, suffix):
    """A file whose keypoints hold NaN (another tool's 'no keypoint' marker) was loaded as it was, and
    the NaN positions went on into matching, pictures and fits; the record refuses them by name."""
    import h5py

    kp = np.array([[3.0, 4.0], [np.nan, 5.0], [6.0, np.inf]])
    with pytest.raises(ValueError, match=r"keypoints: 2 not finite .*keypoint 1 at \[nan, 5.0\]"):
        Features(kp, np.zeros((3, 8), np.float32), np.ones(3, bool))
    path = tmp_path / f"f{suffix}"
    if suffix == ".npz":
        np.savez(path, keypoints=kp, descriptors=np.zeros((3, 8), np.float32), valid=np.ones(3, bool))
    else:
        with h5py.File(path, "w") as fd:
            fd["img/keypoints"], fd["img/descriptors"] = kp, np.zeros((3, 8), np.float32)
    with pytest.raises(ValueError, match="keypoints: 2 not finite"):
        load_features(path)


def test_float16_keypoints_far_enough_from_the_origin_to_be_rounded_are_read_with_a_warning(tmp_path):
    """hloc's `as_half` stores keypoints as float16: from x = 512 their positions are rounded to 0.5 px,
    from 1024 to 1 px, from 2048 to 2 px, and the 3 px protocol scored the rounded positions without a
    word. They are still read as stored, with a warning naming the file, the group and the largest step."""
    rng = np.random.default_rng(0)
    near = rng.uniform(0, 500, (20, 2)).astype(np.float16)  # under 512 px: 0.25 px steps at most, no warning
    far = near.copy()
    far[3] = (2100.3, 40.0)  # 2 px apart there: stored as 2100
    path = tmp_path / "hloc.h5"
    with h5py.File(path, "w") as fd:
        for name, kp in (("near", near), ("far", far)):
            fd[f"{name}/keypoints"] = kp
            fd[f"{name}/descriptors"] = rng.normal(size=(64, 20)).astype(np.float16)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(load_features(path, "near").keypoints, near.astype(np.float64))
    with pytest.warns(UserWarning, match=r"hloc.h5', group 'far': keypoints stored as float16.* up to 2 px "
                                         r"\(1 of 20 keypoints have a coordinate >= 512 px"):
        f = load_features(path, "far")
    assert f.keypoints[3, 0] == 2100.0  # read as stored


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_descriptors_that_are_not_numbers_are_refused_before_a_file_is_written(tmp_path, suffix):
    """An object array (a pandas column of per-keypoint arrays) was taken: its .npz was written pickled
    and then refused by load_features ("Object arrays cannot be loaded"), and its .h5 write raised
    h5py's bare TypeError after the group's old datasets were deleted."""
    rng = np.random.default_rng(0)
    kept = make_features()
    kept.keypoints = kept.keypoints.astype(np.float32).astype(np.float64)  # as an .h5 file stores them
    path = tmp_path / f"f{suffix}"
    save_features(path, kept, "img")
    per_keypoint = np.empty(len(kept), dtype=object)
    per_keypoint[:] = list(rng.random((len(kept), 8)).astype(np.float32))
    for descriptors, message in ((per_keypoint, r"dtype object; .*np.stack\(descriptors\)"),
                                 (np.full((len(kept), 4), "a"), "dtype <U1"),
                                 (np.ones((len(kept), 4), complex), "dtype complex128")):
        with pytest.raises(TypeError, match="descriptors: expected an .* array of numbers.*" + message):
            save_features(path, Features(kept.keypoints, descriptors, None), "img")
    assert load_features(path, "img") == kept  # the file as it was
    stacked = Features(kept.keypoints, np.stack(per_keypoint), None)
    save_features(path, stacked, "img")
    assert load_features(path, "img") == stacked


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_a_record_changed_after_it_was_made_is_not_saved_unreadable(tmp_path, suffix):
    """The records are mutable: keypoints filtered without their descriptors, or a NaN written in place,
    were saved without a word, and load_features / load_matches then refused the file."""
    path = tmp_path / f"f{suffix}"
    features = make_features()
    features.keypoints = features.keypoints[features.valid]  # the descriptors and flags left as they were
    with pytest.raises(ValueError, match=r"features: descriptors: expected first axis N=\d, got shape \(7, 16, 64\) "
                                         r"\(changed after the record was made\?"):
        save_features(path, features, "img")
    features = make_features()
    features.keypoints[2] = np.nan
    with pytest.raises(ValueError, match="features: keypoints: 1 not finite"):
        save_features(path, features, "img")
    matches = Matches(np.array([0, -1, 1]), np.array([1.0, np.inf, 2.0]))
    matches.matches0 = np.array([0, 1])
    with pytest.raises(ValueError, match=r"matches: distances0: expected shape \(2,\)"):
        save_matches(tmp_path / f"m{suffix}", matches, "a/b")
    assert not path.exists() and not (tmp_path / f"m{suffix}").exists()


def test_a_features_path_that_is_a_folder_is_named_before_anything_is_written(tmp_path):
    """`save_features("f.npz", ...)` where f.npz is a folder: the write went through and the last
    step, replacing the path by the finished file, failed with IsADirectoryError naming the hidden
    temporary file, not the path given."""
    folder = tmp_path / "f.npz"
    folder.mkdir()
    with pytest.raises(IsADirectoryError, match=r"f\.npz is a folder; expected the path of a file"):
        save_features(folder, make_features(), "img")
    assert list(tmp_path.iterdir()) == [folder] and not any(folder.iterdir())
