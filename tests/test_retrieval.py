"""Retrieval: K-medoids vocabulary, histograms, search, Acc@K, and the whole run on simulated objects."""

import csv

import cv2
import numpy as np
import pytest

from geofeat.features import Features
from geofeat.matching import distance_matrix, match
from geofeat.apps.retrieval import (
    DEFAULT_WEIGHTING, WEIGHTINGS, accuracy_at_k, bootstrap_interval, exclusion_mask, histogram,
    inverse_document_frequency, nearest_words, per_query_accuracy, rank_distances, read_classes, rerank,
    run_retrieval, search, split_queries, verified_matches, vocabulary, weight_histograms, word_counts,
)


def binary_rotations(bits: np.ndarray) -> np.ndarray:
    """(N, 512) bool -> (N, 16, 64) uint8: 16 circular shifts by 32 bits (GeoBit-like rotations)."""
    return np.stack([np.packbits(np.roll(bits, 32 * k, axis=1), axis=1) for k in range(16)], axis=1)


def objects(kind: str, seed: int = 0):
    """Three objects, four images each: every object draws its descriptors from its own 3 of 9
    word prototypes (noisy copies). Returns per-image descriptors and the images' classes."""
    rng = np.random.default_rng(seed)
    if kind == "l2":
        protos = rng.normal(size=(9, 32))
    else:
        protos = rng.random((9, 512)) < 0.5
    images, classes = [], []
    for obj in range(3):
        for _ in range(4):
            word = rng.choice(np.arange(3 * obj, 3 * obj + 3), size=60)
            if kind == "l2":
                d = (protos[word] + 0.1 * rng.normal(size=(60, 32))).astype(np.float32)
            else:
                bits = protos[word] ^ (rng.random((60, 512)) < 0.05)
                d = np.packbits(bits, axis=1) if kind == "hamming" else binary_rotations(bits)
            images.append(d)
            classes.append(f"object{obj}")
    return images, classes


@pytest.mark.parametrize("weighting", list(WEIGHTINGS))
@pytest.mark.parametrize("kind", ["l2", "hamming", "hamming-rot"])
def test_every_query_finds_its_class_first(kind, weighting):
    images, classes = objects(kind)
    vocab = vocabulary(np.concatenate(images), words=9, seed=0)
    assert vocab.metric == kind and len(vocab) == 9
    hist = np.stack([histogram(d, vocab) for d in images])
    np.testing.assert_allclose(hist.sum(axis=1), 1.0)
    counts = np.stack([word_counts(d, vocab) for d in images])
    assert (counts.sum(axis=1) == 60).all()
    np.testing.assert_allclose(counts / 60.0, hist)
    vectors = weight_histograms(counts, weighting)
    queries = np.array([0, 4, 8])  # the first image of each object
    nn, dist = search(vectors[queries], vectors, k=3, exclude=queries, distance=WEIGHTINGS[weighting])
    assert all(q not in row for q, row in zip(queries, nn))  # the query itself is excluded
    acc = accuracy_at_k(nn, classes, np.asarray(classes)[queries])
    assert acc[0] == 1.0 and acc[2] == 1.0
    assert (np.diff(dist, axis=1) >= 0).all()


def test_tfidf_weights_and_normalisation():
    counts = np.array([[5, 2, 0, 0],
                       [3, 0, 4, 0],
                       [1, 2, 0, 0],
                       [7, 0, 1, 0],
                       [0, 0, 0, 0]])  # word 0 in 4 of 5 frames, word 1 in 2, word 2 in 2, word 3 in none
    idf = inverse_document_frequency(counts[:4])
    assert idf[0] == 0.0 and idf[3] == 0.0  # a word in every frame (or in none) weighs nothing
    np.testing.assert_allclose(idf[1:3], np.log(2))
    for weighting in ("tfidf", "tfidf-sqrt", "tfidf-l1"):
        v = weight_histograms(counts[:4], weighting)
        np.testing.assert_array_equal(v[:, 0], 0.0)  # the word in every database frame adds nothing
        order = 1 if weighting == "tfidf-l1" else 2
        np.testing.assert_allclose(np.linalg.norm(v, ord=order, axis=1), 1.0)
    # idf from the database (the 5 frames): word 0 is then informative, and a frame of no words stays zero
    v = weight_histograms(counts, "tfidf")
    assert (v[:4, 0] > 0).all() and (v[4] == 0).all()
    tf = counts[:4] / counts[:4].sum(1, keepdims=True)
    np.testing.assert_allclose(weight_histograms(counts[:4], "none"), tf)
    np.testing.assert_allclose(weight_histograms(counts[:4], "hellinger"), np.sqrt(tf))
    np.testing.assert_allclose(np.linalg.norm(weight_histograms(counts[:4], "hellinger"), axis=1), 1.0)
    # the same counts scaled (a frame with more keypoints) give the same vector
    np.testing.assert_allclose(weight_histograms(3 * counts[:4], DEFAULT_WEIGHTING, idf),
                               weight_histograms(counts[:4], DEFAULT_WEIGHTING, idf))
    with pytest.raises(ValueError, match="weighting"):
        weight_histograms(counts, "bm25")
    with pytest.raises(ValueError, match="idf"):
        weight_histograms(counts, "tfidf", idf[:2])


def test_search_distances_agree_with_brute_force():
    rng = np.random.default_rng(4)
    q, db = rng.random((7, 5)), rng.random((11, 5))
    for distance, order in (("l2", 2), ("l1", 1)):
        nn, d = search(q, db, k=11, distance=distance)
        brute = np.linalg.norm(q[:, None] - db[None], ord=order, axis=-1)
        np.testing.assert_array_equal(nn, np.argsort(brute, axis=1, kind="stable"))
        np.testing.assert_allclose(d, np.sort(brute, axis=1))
    # on L2-normalised vectors the L2 ranking is the cosine-similarity ranking
    u, w = q / np.linalg.norm(q, axis=1, keepdims=True), db / np.linalg.norm(db, axis=1, keepdims=True)
    nn, _ = search(u, w, k=11)
    np.testing.assert_array_equal(np.take_along_axis(u @ w.T, nn, axis=1), -np.sort(-(u @ w.T), axis=1))
    with pytest.raises(ValueError, match="distance"):
        search(q, db, distance="cosine")
    # the same ranking of a precomputed matrix (benchmarks/retrieval_asmk.py ranks minus ASMK's
    # similarities), which it leaves as it was
    brute = np.abs(q[:, None] - db[None]).sum(-1)
    kept = brute.copy()
    exclude = np.array([3, -1, 0, 5, 5, 5, 10])
    np.testing.assert_array_equal(rank_distances(brute, 4, exclude)[0], search(q, db, 4, exclude, "l1")[0])
    np.testing.assert_array_equal(brute, kept)
    with pytest.raises(ValueError, match="d: expected a"):
        rank_distances(brute[0], 4)


def test_distance_matrix_agrees_with_match():
    images, _ = objects("hamming-rot")
    a, b = images[0], images[5]
    D = distance_matrix(a, b)
    m = match(a, b)
    np.testing.assert_array_equal(D.min(axis=1), m.distances0)
    bits_a = np.unpackbits(a[:3, 0], axis=1)
    bits_b = np.unpackbits(b[:4], axis=2)
    brute = (bits_a[:, None, None, :] != bits_b[None]).sum(-1).min(-1)
    np.testing.assert_array_equal(D[:3, :4], brute)
    x = np.random.default_rng(1).normal(size=(5, 8))
    np.testing.assert_allclose(distance_matrix(x, x[:3]), np.linalg.norm(x[:, None] - x[None, :3], axis=-1), atol=1e-5)


def test_histogram_ignores_invalid_and_vocabulary_bad_input():
    images, _ = objects("l2")
    vocab = vocabulary(np.concatenate(images), words=9)
    f = Features(np.zeros((60, 2)), images[0], np.zeros(60, bool))
    assert histogram(f, vocab).sum() == 0
    assert (nearest_words(f, vocab) == -1).all()  # no word for an invalid descriptor
    with pytest.raises(ValueError, match="too few"):
        vocabulary(images[0][:10], words=10)
    with pytest.raises(ValueError, match="words"):
        vocabulary(images[0], words=1)


def test_rerank_puts_the_frame_with_verified_matches_first():
    """A bent copy of the query's surface (same descriptors, keypoints moved by a smooth bend) has many
    verified matches; the same descriptors at shuffled positions match but fail the local affine
    check; unrelated descriptors do not match."""
    rng = np.random.default_rng(0)
    n = 150
    xy = rng.uniform(0, 300, (n, 2))
    desc = rng.normal(size=(n, 32)).astype(np.float32)
    query = Features(xy, desc, np.ones(n, bool))
    bent_xy = np.stack([xy[:, 0] + 6 * np.sin(xy[:, 1] / 50), xy[:, 1] + 4 * np.cos(xy[:, 0] / 60)], axis=1)
    noisy = (desc + 0.05 * rng.normal(size=desc.shape)).astype(np.float32)
    bent = Features(bent_xy, noisy, np.ones(n, bool))
    shuffled = Features(rng.permutation(bent_xy), noisy, np.ones(n, bool))
    unrelated = Features(rng.uniform(0, 300, (n, 2)), rng.normal(size=(n, 32)).astype(np.float32), np.ones(n, bool))
    features = [query, unrelated, shuffled, bent]
    counts = [verified_matches(query, f) for f in features[1:]]
    assert counts[2] > 0.8 * n and counts[1] < 0.1 * counts[2] and counts[0] < 0.1 * counts[2], counts
    words_order = np.array([[1, 2, 3]])
    np.testing.assert_array_equal(rerank(words_order, np.array([0]), features, top=3)[0, 0], 3)
    np.testing.assert_array_equal(rerank(words_order, np.array([0]), features, top=2), [[1, 2, 3]])  # 3 not in reach
    np.testing.assert_array_equal(rerank(words_order, np.array([0]), features, top=0), words_order)
    with pytest.raises(ValueError, match="top"):
        rerank(words_order, np.array([0]), features, top=-1)
    with pytest.raises(ValueError, match="neighbours"):
        rerank(words_order, np.array([0, 1]), features)


def test_read_classes(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("sequence,class\na,cloth\nb,cloth\nc,paper\n")
    assert read_classes(p) == {"a": "cloth", "b": "cloth", "c": "paper"}
    p.write_text("a\n")
    with pytest.raises(ValueError, match="classes"):
        read_classes(p)


def texture(kind: int, size: int = 512) -> np.ndarray:
    """Three visibly different synthetic textures (BGR uint8): blobs, checkers, line drawing."""
    rng = np.random.default_rng(kind)
    img = np.full((size, size, 3), 255, np.uint8)
    if kind == 0:
        for _ in range(250):
            c = tuple(int(v) for v in rng.integers(0, 200, 3))
            cv2.circle(img, tuple(int(v) for v in rng.integers(0, size, 2)), int(rng.integers(3, 14)), c, -1)
    elif kind == 1:
        yy, xx = np.mgrid[:size, :size]
        img[((yy // 24 + xx // 24) % 2) == 0] = (30, 30, 30)
        img[(yy // 24) % 3 == 0] //= 2
    else:
        for _ in range(120):
            p = rng.integers(0, size, 4)
            cv2.line(img, (int(p[0]), int(p[1])), (int(p[2]), int(p[3])), (0, 0, 0), 2)
    return img


@pytest.fixture(scope="module")
def three_objects(tmp_path_factory):
    from geofeat.sim import simulate_sequence

    root = tmp_path_factory.mktemp("retrieval")
    for k, name in enumerate(["blobs", "checkers", "lines"]):
        simulate_sequence(root / name, scenario="deform", n_frames=3, seed=30 + k, texture=texture(k), width=320,
                          height=240, progress=False)
    return root


def test_retrieval_on_three_simulated_objects(three_objects, tmp_path):
    # 40 words: with tf-idf weighting a word found in every one of the 9 frames weighs nothing, and with
    # 10 words nearly all of them are (then every vector is zero: validation rejects such small K)
    res, db = run_retrieval([three_objects], tmp_path, ("sift", "orb"), words=40, n_samples=2000, n_keypoints=300,
                            max_k=2, include_own_sequence=True, progress=False)
    assert db.is_query.sum() == 3 and len(db.frames) == 9
    for name in ("sift", "orb"):
        assert res[name].accuracy[0] == 1.0, (name, res[name].accuracy)  # every query's own class first
        assert (res[name].low <= res[name].accuracy).all() and (res[name].accuracy <= res[name].high).all()
    rows = list(csv.DictReader(open(tmp_path / "retrieval.csv")))
    assert [r["descriptor"] for r in rows] == ["sift", "sift", "orb", "orb"]
    assert {r["weighting"] for r in rows} == {DEFAULT_WEIGHTING} and {r["words"] for r in rows} == {"40"}
    # the accuracy is after re-ranking (the default): the csv says by how many results, as the table does
    assert res["sift"].rerank > 0 and {r["rerank"] for r in rows} == {str(res["sift"].rerank)}
    assert (tmp_path / "acc_at_k.png").is_file() and cv2.imread(str(tmp_path / "top6.png")) is not None
    assert "object masks: simulator, for all 3 sequences" in (tmp_path / "retrieval.md").read_text()
    # the profile the sequences were described with (the simulator's geofeat.json names it)
    assert "depth profile: clean, for all 3 sequences" in (tmp_path / "retrieval.md").read_text()


def test_retrieval_bad_input(three_objects, tmp_path):
    with pytest.raises(ValueError, match="descriptor"):
        run_retrieval([three_objects], tmp_path, ("nope",), progress=False)
    with pytest.raises(ValueError, match="too few"):
        run_retrieval([three_objects / "lines"], tmp_path, ("sift",), words=10, n_keypoints=2,
                      include_own_sequence=True, progress=False)
    classes = tmp_path / "classes.csv"
    classes.write_text("blobs,a\n")
    with pytest.raises(ValueError, match="no class"):
        run_retrieval([three_objects], tmp_path / "out", ("sift",), classes_file=str(classes), progress=False)
    # the paper's setting with one sequence per class: no query can be answered
    with pytest.raises(ValueError, match="include-own-sequence"):
        run_retrieval([three_objects], tmp_path / "out2", ("sift",), n_keypoints=300, progress=False)


def test_retrieval_command(three_objects, tmp_path, capsys):
    from geofeat.cli import main

    args = ["retrieval", str(three_objects), "--descriptors", "sift", "--keypoints", "300", "--samples", "1000",
            "--include-own-sequence", "--out", str(tmp_path)]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "Acc@1" in out and "object masks" in out and "chosen by validation" in out
    assert f"word weighting {DEFAULT_WEIGHTING}" in out
    assert "640:" in out and "1280:" not in out  # candidates below the 1000 sampled descriptors only
    assert str(tmp_path / "retrieval.md") in out  # the summary names every file written (it left out retrieval.md)
    assert main(args[:-2] + ["--words", "100000", "--out", str(tmp_path)]) == 2  # non-empty OUT refused
    assert "--overwrite" in capsys.readouterr().err
    assert main(args[:-2] + ["--words", "100000", "--out", str(tmp_path), "--overwrite"]) == 2
    assert "too few" in capsys.readouterr().err
    assert (tmp_path / "retrieval.csv").is_file()  # the failed run left the earlier results in place
    assert main(args[:-2] + ["--words", "10", "--weighting", "none", "--out", str(tmp_path), "--overwrite"]) == 0
    assert "word weighting none (l2 distance)" in capsys.readouterr().out


def test_object_mask_sources(three_objects, tmp_path):
    from geofeat.io import read_sequence
    from geofeat.apps.objectmask import foreground_from_depth, object_mask

    depth = np.full((60, 80), 2.5, np.float32)  # a wall 2.5 m away
    depth[10:40, 20:60] = 1.0 + np.linspace(0, 0.1, 40)[None, :]  # a slanted object at 1 m
    depth[0, 0] = 0  # a hole
    expected = np.zeros(depth.shape, bool)
    expected[10:40, 20:60] = True
    np.testing.assert_array_equal(foreground_from_depth(depth), expected)
    # no ground-truth files: the depth foreground, which on the simulator's frames is the cloth
    seq_dir = tmp_path / "plain"
    seq_dir.mkdir()
    for f in (three_objects / "blobs").iterdir():
        if not f.name.endswith("-gt.npz"):
            (seq_dir / f.name).write_bytes(f.read_bytes())
    mask, source = object_mask(read_sequence(seq_dir), "frame-000-master")
    truth, truth_source = object_mask(read_sequence(three_objects / "blobs"), "frame-000-master")
    assert source == "depth" and truth_source == "simulator"
    assert (mask & truth).sum() / (mask | truth).sum() > 0.95


def test_exclusion_split_and_bootstrap():
    seqs = ["a", "a", "b", "b", "b"]
    m = exclusion_mask(seqs, np.array([0, 2]))
    np.testing.assert_array_equal(m, [[1, 1, 0, 0, 0], [0, 0, 1, 1, 1]])
    np.testing.assert_array_equal(exclusion_mask(seqs, np.array([0, 2]), include_own_sequence=True),
                                  [[1, 0, 0, 0, 0], [0, 0, 1, 0, 0]])
    hist = np.eye(5)
    nn, _ = search(hist[[0, 2]], hist, k=10, exclude=m)
    assert nn.shape == (2, 2) and set(nn[0]) == {2, 3} and set(nn[1]) == {0, 1}
    val, test = split_queries(7, seed=3)
    assert len(val) == 3 and len(test) == 4 and not set(val) & set(test)
    per_query = np.array([[1.0, 0.5]] * 6 + [[0.0, 0.5]] * 4)
    low, high = bootstrap_interval(per_query)
    assert low[0] < 0.6 < high[0] and 0.25 < low[0] and high[0] < 0.95  # a real interval around the mean 0.6
    np.testing.assert_allclose([low[1], high[1]], 0.5)  # no spread, no interval


def test_search_k_and_accuracy_read_only_real_results():
    """An (Q,) exclude of -1 everywhere (nothing excluded) still lowered k by one; a -1 (padding)
    among the neighbours of `per_query_accuracy` / `accuracy_at_k` silently read the last database
    frame's class."""
    q, db = np.array([[0.0, 0.0]]), np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    nn, d = search(q, db, k=3, exclude=np.array([-1]))
    assert nn.tolist() == [[0, 1, 2]]  # ties: lowest index first
    assert search(q, db, k=3, exclude=np.array([1]))[0].tolist() == [[0, 2]]
    for bad in ([[0, -1]], [[0, 3]]):
        with pytest.raises(ValueError, match="neighbours"):
            per_query_accuracy(np.array(bad), ["a", "b", "a"], ["a"])
        with pytest.raises(ValueError, match="neighbours"):
            accuracy_at_k(np.array(bad), ["a", "b", "a"], ["a"])
    np.testing.assert_allclose(per_query_accuracy(np.array([[0, 1]]), ["a", "b", "a"], ["a"]), [[1.0, 0.5]])


@pytest.fixture(scope="module")
def deformed_copy(tmp_path_factory):
    """The 'blobs' object of `three_objects` again, in another sequence: hard preset (strong folds)."""
    from geofeat.sim import simulate_sequence

    root = tmp_path_factory.mktemp("retrieval_copy")
    simulate_sequence(root / "blobs_folded", scenario="deform", preset="hard", n_frames=3, seed=31,
                      texture=texture(0), width=320, height=240, progress=False)
    return root


@pytest.mark.parametrize("weighting, words, rerank_top", [("none", 10, 0), (DEFAULT_WEIGHTING, 40, 0),
                                                        (DEFAULT_WEIGHTING, 40, 5)])
def test_retrieval_leaves_out_the_query_sequence_and_ranks_the_deformed_copy_first(three_objects, deformed_copy,
                                                                                   tmp_path, weighting, words,
                                                                                   rerank_top):
    classes = tmp_path / "classes.csv"
    classes.write_text("sequence,class\nblobs,blobs\nblobs_folded,blobs\ncheckers,checkers\nlines,lines\n")
    res, db = run_retrieval([three_objects, deformed_copy], tmp_path / "out", ("geopatch",), words=words,
                            n_samples=2000, n_keypoints=300, max_k=10, classes_file=str(classes), progress=False,
                            weighting=weighting, rerank_top=rerank_top)
    r = res["geopatch"]
    seqs = np.asarray(db.sequences)
    # only the two 'blobs' sequences have a class mate; checkers and lines are reported and skipped
    assert sorted(seqs[r.queries]) == ["blobs", "blobs_folded"]
    assert "skipped 2 queries" in (tmp_path / "out" / "retrieval.md").read_text()
    for q, row in zip(r.queries, r.neighbours):
        assert not (seqs[row] == seqs[q]).any()  # the query's own sequence is left out
        assert len(row) == len(seqs) - (seqs == seqs[q]).sum()  # everything else is ranked
        # the deformed copy (the other blobs sequence) comes before every distractor frame
        is_copy = np.asarray(db.classes)[row] == "blobs"
        assert is_copy.sum() == 3 and is_copy[:3].all(), seqs[row]  # 3 frames of the copy, then 6 distractors


def test_retrieval_with_geokey_keypoints(three_objects, tmp_path):
    from geofeat.apps.retrieval import run_retrieval

    res, db = run_retrieval([three_objects], tmp_path / "r", ("geobit",), words=5, n_samples=1000, n_keypoints=300,
                            include_own_sequence=True, progress=False, detector="geokey")
    # every frame described with GeoKey's keypoints (inside the object mask), each query answered
    assert all(len(f) > 0 for f in db.features["geobit"])
    assert res["geobit"].accuracy[0] > 0.5


def test_each_descriptor_gets_its_own_detector_by_default(three_objects):
    """Without a detector, GeoBit is described on GeoKey's keypoints and ORB on SIFT's (it needs their
    orientation), each as `geofeat.detect` gives them inside the object mask; a named detector is
    used for both."""
    from geofeat.apps.objectmask import object_mask
    from geofeat.apps.retrieval import describe_datasets
    from geofeat.io import read_sequence
    from geofeat.keypoints import detect

    db = describe_datasets([three_objects / "blobs"], ("geobit", "orb"), n_keypoints=200, progress=False)
    assert db.detectors == {"geobit": "geokey", "orb": "sift"}
    seq = read_sequence(three_objects / "blobs")
    name = db.frames[0]
    frame, (mask, _) = seq.frame(name), object_mask(seq, name, None)
    for descriptor, detector in db.detectors.items():
        expected = detect(frame, 200, detector=detector, mask=mask).xy
        np.testing.assert_array_equal(db.features[descriptor][0].keypoints, expected)
    assert not np.array_equal(db.features["geobit"][0].keypoints, db.features["orb"][0].keypoints)
    named = describe_datasets([three_objects / "blobs"], ("geobit", "orb"), n_keypoints=200, progress=False,
                              detector="sift")
    assert named.detectors == {"geobit": "sift", "orb": "sift"}
    np.testing.assert_array_equal(named.features["geobit"][0].keypoints, named.features["orb"][0].keypoints)


def test_read_classes_of_a_spreadsheet_export(tmp_path):
    """A byte-order mark (Excel's "CSV UTF-8") hid the header: '\\ufeffsequence' became a sequence of
    class 'class'; a file that is not UTF-8 was a UnicodeDecodeError."""
    p = tmp_path / "c.csv"
    p.write_bytes("\ufeffsequence,class\na,cloth\n".encode("utf-8"))
    assert read_classes(p) == {"a": "cloth"}
    p.write_bytes(b"\xff\xfe\x00a,b\n")
    with pytest.raises(ValueError, match="classes: .* UTF-8"):
        read_classes(p)


def test_split_weighting_and_vocabulary_check_their_input():
    """split_queries(-1) split nothing silently and 2.5 was a numpy AxisError; negative or NaN counts
    and a negative idf gave vectors with NaN or negative weights; a distance matrix of another sample
    picked medoids by the wrong rows; records of two descriptors were concatenated (uint8 bits cast
    to floats) and counted against the other descriptor's words."""
    from geofeat.apps.retrieval import sample_descriptors

    for n in (-1, 2.5, True):
        with pytest.raises(ValueError, match="n: expected"):
            split_queries(n)
    val, test = split_queries(9)
    assert sorted(np.concatenate([val, test]).tolist()) == list(range(9))
    counts = np.array([[1, 0, 2], [0, 3, 1]])
    for bad in (np.array([[1, -2, 3]]), np.array([[1.0, np.nan, 3.0]]), np.ones((2, 2, 2))):
        with pytest.raises(ValueError, match="counts"):
            weight_histograms(bad, "none")
    with pytest.raises(ValueError, match="idf"):
        weight_histograms(counts, "tfidf", idf=np.array([1.0, -1.0, 1.0]))
    assert weight_histograms(np.zeros((0, 3))).shape == (0, 3)
    rng = np.random.default_rng(0)
    floats = rng.standard_normal((30, 16)).astype(np.float32)
    with pytest.raises(ValueError, match="distances"):
        vocabulary(floats, 4, distances=np.zeros((10, 10), np.float32))
    vocab = vocabulary(floats, 4)
    with pytest.raises(ValueError, match="NaN"):  # NaN distances gave words without a word
        vocabulary(np.where(np.arange(30)[:, None] == 7, np.nan, floats), 4)
    bits = rng.integers(0, 256, (30, 16), dtype=np.uint8)
    with pytest.raises(ValueError, match="features"):
        word_counts(bits, vocab)
    f = [Features(np.zeros((30, 2)), d, np.ones(30, bool)) for d in (floats, bits)]
    with pytest.raises(ValueError, match="different kinds"):
        sample_descriptors(f)


def test_retrieval_names_the_results_it_really_reranked(three_objects, tmp_path):
    """With 9 frames a query has at most 8 results: retrieval.md said "each query's best 80 frames by
    the words reordered" (the --rerank default) although only 8 were."""
    res, _ = run_retrieval([three_objects], tmp_path, ("sift",), words=40, n_samples=2000, n_keypoints=300,
                           include_own_sequence=True, progress=False)
    md = (tmp_path / "retrieval.md").read_text()
    assert res["sift"].rerank == 8 and "each query's best 8 frames by the words" in md, md


def test_report_notes_count_in_words():
    """retrieval.md said "2 frames of 1 sequences, 1 classes" and "for all 1 sequences"."""
    from geofeat.apps.retrieval import DescriptorResult, RetrievalDatabase, _report

    n = 3
    features = [Features(np.zeros((2, 2)), np.zeros((2, 8), np.uint8), np.ones(2, bool)) for _ in range(n)]
    db = RetrievalDatabase(sequences=["s"] * n, frames=["a-ref", "b", "c"], classes=["cloth"] * n,
                           is_query=np.array([True, False, False]), folders=[], mask_sources={"s": "simulator"},
                           features={"orb": features}, depth_profiles={"s": "clean"})
    per_query = np.ones((1, 2))
    result = DescriptorResult(words=2, validation={}, queries=np.array([0]), neighbours=np.array([[1, 2]]),
                              per_query=per_query, accuracy=np.ones(2), low=np.ones(2), high=np.ones(2),
                              rerank=1, per_query_words=per_query)
    notes = _report(db, {"orb": result}, skipped=["s/x (class y)"], words=2, n_samples=1, include_own_sequence=True)
    assert "3 frames of 1 sequence, 1 class;" in notes
    assert "vocabulary from 1 sampled descriptor;" in notes
    assert "each query's best 1 frame by the words" in notes
    assert "skipped 1 query whose class" in notes
    assert "object masks: simulator, for 1 sequence" in notes and "depth profile: clean, for 1 sequence" in notes
    assert "for all 1" not in notes and "1 sequences" not in notes and "1 classes" not in notes


def test_a_database_of_one_class_is_flagged_as_telling_descriptors_nothing(three_objects, tmp_path):
    """Two sequences of one object (the docs' example): every frame a query may return is of its class,
    so Acc@K was 1 for any descriptor, reported like a real result without a word."""
    classes = tmp_path / "classes.csv"
    classes.write_text("sequence,class\nblobs,cloth\ncheckers,cloth\n")
    res, _ = run_retrieval([three_objects / "blobs", three_objects / "checkers"], tmp_path / "out", ("orb",),
                           words=5, n_samples=500, n_keypoints=200, classes_file=str(classes), rerank_top=0,
                           progress=False)
    assert (res["orb"].accuracy == 1.0).all()
    md = (tmp_path / "out" / "retrieval.md").read_text()
    assert "1 whatever the descriptor" in md and "checkers/" in md and "blobs/" in md, md
    # with a distractor of another class in the database nothing is flagged
    classes.write_text("sequence,class\nblobs,cloth\ncheckers,cloth\nlines,tiles\n")
    run_retrieval([three_objects], tmp_path / "out2", ("orb",), words=5, n_samples=500, n_keypoints=200,
                  classes_file=str(classes), rerank_top=0, progress=False)
    assert "whatever the descriptor" not in (tmp_path / "out2" / "retrieval.md").read_text()


def test_classes_that_leave_no_query_are_named_not_answered_with_pass_classes(three_objects, tmp_path):
    """--classes given with 'Cloth' and 'cloth': every query was skipped and the error said the classes
    default to the folder names and to pass --classes."""
    classes = tmp_path / "classes.csv"
    classes.write_text("sequence,class\nblobs, Cloth\ncheckers,cloth\nlines,tiles\n")
    with pytest.raises(ValueError) as error:
        run_retrieval([three_objects], tmp_path / "out", ("orb",), words=5, n_samples=500, n_keypoints=200,
                      classes_file=str(classes), rerank_top=0, progress=False)
    message = str(error.value)
    assert "pass --classes" not in message and "default to the sequence folder name" not in message
    assert "blobs: 'Cloth'" in message and "checkers: 'cloth'" in message and "case-sensitive" in message


def test_a_single_test_query_gets_no_interval(three_objects, tmp_path):
    """Two sequences of one class: K chosen on one query, Acc@K reported on the other, with a 95 %
    bootstrap interval of [1.00, 1.00] (every resample of one query is that query) that read as certainty."""
    assert all(np.isnan(v).all() for v in bootstrap_interval(np.array([[1.0, 0.5]])))
    classes = tmp_path / "classes.csv"
    classes.write_text("sequence,class\nblobs,cloth\ncheckers,cloth\nlines,tiles\n")
    res, _ = run_retrieval([three_objects], tmp_path / "out", ("orb",), n_samples=300, n_keypoints=200,
                           classes_file=str(classes), rerank_top=0, progress=False)
    assert len(res["orb"].queries) == 1 and np.isnan(res["orb"].low).all() and np.isnan(res["orb"].high).all()
    md = (tmp_path / "out" / "retrieval.md").read_text()
    table = md.splitlines()[2]
    assert "[–]" in table and "[1.00, 1.00]" not in table and "[0.00, 0.00]" not in table, md


def test_classes_naming_sequences_not_given_are_reported(three_objects, tmp_path):
    """A classes file that names a sequence the datasets lack (a folder left out of the command) was
    ignored without a word; the run goes on, and says which ones it left out."""
    classes = tmp_path / "classes.csv"
    classes.write_text("sequence,class\nblobs,cloth\ncheckers,cloth\nlines,tiles\n")
    with pytest.warns(UserWarning, match=r"1 sequence named in the classes file is not among the datasets.*: lines$"):
        run_retrieval([three_objects / "blobs", three_objects / "checkers"], tmp_path / "out", ("orb",), words=5,
                      n_samples=500, n_keypoints=200, classes_file=str(classes), rerank_top=0, progress=False)


def test_report_gives_each_descriptors_vocabulary_sample():
    """"vocabulary from N sampled descriptors" counted the first descriptor's valid descriptors only:
    a second descriptor with fewer (its own detector, invalid patches) was said to have as many."""
    from geofeat.apps.retrieval import DescriptorResult, RetrievalDatabase, _report, sample_descriptors

    def frames(valid):
        return [Features(np.zeros((4, 2)), np.zeros((4, 8), np.uint8), np.arange(4) < valid) for _ in range(3)]

    features = {"orb": frames(4), "sift": frames(2)}
    db = RetrievalDatabase(sequences=["s", "s", "t"], frames=["a-ref", "b", "c"], classes=["cloth"] * 3,
                           is_query=np.array([True, False, False]), folders=[], mask_sources={"s": "simulator"},
                           features=features)
    per_query = np.ones((1, 2))
    result = DescriptorResult(words=2, validation={}, queries=np.array([0]), neighbours=np.array([[1, 2]]),
                              per_query=per_query, accuracy=np.ones(2), low=np.ones(2), high=np.ones(2))
    notes = _report(db, {"orb": result, "sift": result}, skipped=[], words=2, n_samples=10, include_own_sequence=True)
    sampled = {n: len(sample_descriptors(f, 10)) for n, f in features.items()}
    assert sampled == {"orb": 10, "sift": 6}
    assert "vocabulary from 10 sampled descriptors (orb), 6 (sift);" in notes


def test_top6_picture_names_its_columns(three_objects, tmp_path):
    """top6.png marked the query only by its border colour: a header row now names the columns
    (query, top 1-6) above the tiles and the colours' meaning, in dark text on white."""
    from geofeat.apps.retrieval import TOP6_HEADER_PX

    run_retrieval([three_objects], tmp_path, ("orb",), words=40, n_samples=2000, n_keypoints=300, max_k=2,
                  include_own_sequence=True, rerank_top=0, progress=False)
    picture = cv2.imread(str(tmp_path / "top6.png"))
    rows = (picture.shape[0] - TOP6_HEADER_PX) / 120  # thumbnails 160 x 120, one row per (descriptor, query)
    assert rows == int(rows) and rows >= 1, picture.shape
    header = picture[:TOP6_HEADER_PX]
    query_label = header[:20, 110:270]  # above the query's column
    assert (query_label.min(axis=2) < 100).any() and (header[20:, 110:] < 100).any()
    assert (picture[TOP6_HEADER_PX:TOP6_HEADER_PX + 120, 110:270, 0] > 200).any()  # the query tile's blue border below it


def test_retrieval_without_class_mates_is_refused_before_describing(three_objects, tmp_path, monkeypatch):
    """Without --classes every sequence is a class of its own, so no query can be answered: the command
    said so only after detecting and describing every frame of every sequence (minutes on a real set).
    Classes given that put every sequence in a class of its own are refused as early."""
    import geofeat.apps.retrieval as retrieval

    def no_describing(*args, **kwargs):
        raise AssertionError("described the frames first")

    monkeypatch.setattr(retrieval, "describe_datasets", no_describing)
    with pytest.raises(ValueError, match=r"no query has another sequence .*pass --classes .* or --include-own-sequence"):
        run_retrieval([three_objects], tmp_path / "a", ("sift",), progress=False)
    classes = tmp_path / "classes.csv"
    classes.write_text("blobs,a\ncheckers,b\nlines,c\n")
    with pytest.raises(ValueError, match=r"classes: no query has another sequence of its class"):
        run_retrieval([three_objects], tmp_path / "b", ("sift",), classes_file=str(classes), progress=False)
    with pytest.raises(ValueError, match="descriptor"):  # a bad name is still the first error
        run_retrieval([three_objects], tmp_path / "c", ("nope",), progress=False)


def test_ties_do_not_follow_the_order_the_folders_were_given_in():
    """Frames with equal word vectors (here identical frames; in practice all-zero tf-idf vectors, each
    word in every frame) tie, and ties went to the lowest database index: a query of object a found
    object a first when its folders came first and object b first when they came last."""
    from geofeat.apps.retrieval import RetrievalDatabase, eligible_queries, evaluate_descriptor

    rng = np.random.default_rng(0)
    desc = (rng.normal(size=(3, 16))[np.repeat(np.arange(3), 20)] + 0.05 * rng.normal(size=(60, 16))).astype(np.float32)
    frame = Features(np.zeros((60, 2)), desc, np.ones(60, bool))

    def results(seq_order):
        seqs = [s for s in seq_order for _ in range(2)]
        frames = [f for _ in seq_order for f in ("f0-ref", "f1")]
        db = RetrievalDatabase(sequences=seqs, frames=frames, classes=[s[0] for s in seqs],
                               is_query=np.array([f == "f0-ref" for f in frames]), folders=[], mask_sources={},
                               features={"x": [frame] * len(seqs)})
        q, ex, _ = eligible_queries(db)
        r = evaluate_descriptor(db.features["x"], db, q, ex, words=3, n_samples=60, weighting="none", rerank_top=0)
        return {db.sequences[i]: ([f"{db.sequences[j]}/{db.frames[j]}" for j in row], acc.tolist())
                for i, row, acc in zip(r.queries, r.neighbours, r.per_query)}

    forward = results(["a0", "a1", "b0", "b1"])
    assert forward == results(["b1", "b0", "a1", "a0"]) == results(["a1", "b0", "a0", "b1"])


def test_k_chosen_on_queries_of_the_test_queries_own_object_is_flagged(three_objects, tmp_path):
    """Queries of one class (one object in two sequences, plus a distractor): `split_queries` splits them
    one by one, so K is chosen on a query of the test query's own object, which the help says never
    happens; retrieval.md reported that Acc@K like any other."""
    classes = tmp_path / "classes.csv"
    classes.write_text("sequence,class\nblobs,cloth\ncheckers,cloth\nlines,tiles\n")
    run_retrieval([three_objects], tmp_path / "out", ("orb",), n_samples=300, n_keypoints=200,
                  classes_file=str(classes), rerank_top=0, progress=False)
    md = (tmp_path / "out" / "retrieval.md").read_text()
    assert "chosen on queries of the test queries' own object" in md, md
    run_retrieval([three_objects], tmp_path / "out2", ("orb",), words=5, n_samples=300, n_keypoints=200,
                  classes_file=str(classes), rerank_top=0, progress=False)  # K given: nothing chosen
    assert "own object" not in (tmp_path / "out2" / "retrieval.md").read_text()


def test_search_refuses_an_exclude_list_of_another_length():
    """An (Q,) exclude shorter than the queries left the last queries free to return themselves."""
    db = np.eye(3)
    with pytest.raises(ValueError, match="exclude"):
        search(db, db, k=2, exclude=np.array([0, 1]))
    with pytest.raises(ValueError, match="exclude"):
        search(db, db, k=2, exclude=np.array([0, 1, 2, 0]))
    nn, _ = search(db, db, k=2, exclude=np.array([0, 1, 2]))
    assert all(q not in row for q, row in enumerate(nn))


def test_the_vocabulary_does_not_depend_on_the_order_the_folders_were_given_in():
    """The vocabulary sample was drawn, and FasterPAM run, in the order the folders were given, so
    `geofeat retrieval B A` scored every query differently from `geofeat retrieval A B`."""
    from geofeat.apps.retrieval import RetrievalDatabase, eligible_queries, evaluate_descriptor

    rng = np.random.default_rng(1)
    protos = rng.normal(size=(12, 16))
    seqs_ab = ["a0", "a1", "b0", "b1", "c0", "c1"]
    frame = {}
    for s in seqs_ab:
        for f in ("f0-ref", "f1"):
            obj = "abc".index(s[0])
            word = rng.choice(np.arange(4 * obj, 4 * obj + 6) % 12, size=40)
            desc = (protos[word] + 0.6 * rng.normal(size=(40, 16))).astype(np.float32)
            frame[s, f] = Features(np.zeros((40, 2)), desc, np.ones(40, bool))

    def results(seq_order, n_samples):
        pairs = [(s, f) for s in seq_order for f in ("f0-ref", "f1")]
        db = RetrievalDatabase(sequences=[s for s, _ in pairs], frames=[f for _, f in pairs],
                               classes=[s[0] for s, _ in pairs], is_query=np.array([f == "f0-ref" for _, f in pairs]),
                               folders=[], mask_sources={}, features={"x": [frame[p] for p in pairs]})
        q, ex, _ = eligible_queries(db)
        r = evaluate_descriptor(db.features["x"], db, q, ex, words=8, n_samples=n_samples, rerank_top=0)
        return {db.sequences[i]: acc.tolist() for i, acc in zip(r.queries, r.per_query)}

    for n_samples in (100, 1000):  # a random subset of the descriptors, and all of them
        forward = results(seqs_ab, n_samples)
        assert forward == results(seqs_ab[::-1], n_samples) == results(["b1", "c0", "a0", "c1", "a1", "b0"], n_samples)


def test_intervals_and_the_validation_split_do_not_depend_on_the_order_the_folders_were_given_in():
    """The queries were taken in the order the folders were given, and the bootstrap resamples (and,
    with one class, `split_queries`) draw them by position: the same queries, scored the same, got
    other 95 % intervals, and with one class another K and other test queries, from `geofeat
    retrieval B A` than from `geofeat retrieval A B`."""
    from geofeat.apps.retrieval import RetrievalDatabase, eligible_queries, evaluate_descriptor

    rng = np.random.default_rng(2)
    protos = rng.normal(size=(24, 16))
    objects = [f"o{k:02d}" for k in range(12)]
    seqs = [f"{o}-{i}" for o in objects for i in range(2)]
    frame = {}
    for s in seqs:
        for f in ("f0-ref", "f1"):
            obj = objects.index(s[:3])
            word = rng.choice(np.arange(2 * obj, 2 * obj + 5) % 24, size=30)
            desc = (protos[word] + 0.9 * rng.normal(size=(30, 16))).astype(np.float32)
            frame[s, f] = Features(np.zeros((30, 2)), desc, np.ones(30, bool))

    def results(seq_order, one_class, words):
        pairs = [(s, f) for s in seq_order for f in ("f0-ref", "f1")]
        db = RetrievalDatabase(sequences=[s for s, _ in pairs], frames=[f for _, f in pairs],
                               classes=["x" if one_class else s[:3] for s, _ in pairs],
                               is_query=np.array([f == "f0-ref" for _, f in pairs]),
                               folders=[], mask_sources={}, features={"x": [frame[p] for p in pairs]})
        q, ex, _ = eligible_queries(db, include_own_sequence=one_class)
        r = evaluate_descriptor(db.features["x"], db, q, ex, words=words, n_samples=600, rerank_top=0,
                                candidates=(5, 10, 20))
        return (r.words, sorted(db.sequences[i] for i in r.queries), r.accuracy.round(12).tolist(),
                r.low.tolist(), r.high.tolist())

    shuffled = [seqs[i] for i in np.random.default_rng(0).permutation(len(seqs))]
    for one_class, words in ((False, 10), (True, None)):
        forward = results(seqs, one_class, words)
        if not one_class:  # a real interval (one class: every result is right, and the test queries matter)
            assert np.isfinite(forward[3]).all() and forward[3] != forward[4]
        assert results(seqs[::-1], one_class, words) == forward == results(shuffled, one_class, words)


def test_acc_at_k_plot_says_when_its_curves_are_re_ranked(tmp_path, monkeypatch):
    """acc_at_k.png draws the accuracies after `rerank` (the default re-ranks each query's best 80),
    but its title said "bag of visual words" alone, as for the paper's words-only curves."""
    import geofeat.viz
    from geofeat.apps.retrieval import _plot

    figures = []
    real = geofeat.viz.plot_figure
    monkeypatch.setattr(geofeat.viz, "plot_figure", lambda size: figures.append(real(size)) or figures[-1])
    acc = {"orb": np.array([0.5, 0.6])}
    _plot(acc, tmp_path / "words.png")
    _plot(acc, tmp_path / "reranked.png", rerank=80)
    words, reranked = (ax.get_title() for _, ax in figures)
    assert "re-ranked" not in words
    assert "best 80 re-ranked by verified matches" in reranked
