"""ASMK and ASMK* as benchmarks/retrieval_asmk.py measures them: the kernel's normalisation, and a
frame told from a distractor that holds the same words."""

import numpy as np
import pytest

from benchmark_scripts import import_benchmarks
from geofeat.apps.retrieval import (
    Vocabulary, inverse_document_frequency, nearest_words, search, weight_histograms, word_counts,
)
from geofeat.features import Features

retrieval_asmk = import_benchmarks("retrieval_asmk")[0]
aggregate_residuals, asmk_similarities = retrieval_asmk.aggregate_residuals, retrieval_asmk.asmk_similarities

WORDS = 12
DIM = 32


def centres(seed: int = 0) -> np.ndarray:
    """(WORDS, DIM) unit words, far apart."""
    c = np.random.default_rng(seed).normal(size=(WORDS, DIM))
    return (c / np.linalg.norm(c, axis=1, keepdims=True)).astype(np.float32)


def frame_near(c: np.ndarray, words: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """(n, DIM) float32 descriptors c[words] + residuals (small: each stays nearest its own word)."""
    return (c[words] + residuals).astype(np.float32)


def nearest(c: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.argmin(((x[:, None] - c[None]) ** 2).sum(-1), axis=1)


@pytest.mark.parametrize("binary", [False, True])
def test_a_frame_is_most_similar_to_itself_and_a_frame_of_other_words_scores_zero(binary):
    rng = np.random.default_rng(1)
    c = centres()
    frames = []
    for k in range(6):  # frames 0-4 draw from words 0-7, frame 5 from words 8-11 only
        words = rng.integers(0, 8, 40) if k < 5 else rng.integers(8, WORDS, 40)
        x = frame_near(c, words, 0.1 * rng.normal(size=(40, DIM)))
        frames.append(aggregate_residuals(x, nearest(c, x), c, binary))
    for weights in (np.ones(WORDS), rng.uniform(0.1, 2.0, WORDS)):
        s = asmk_similarities(frames, frames, weights, kernels=((3.0, 0.0), (1.0, 0.0), (5.0, 0.2)))  # (3, 6, 6)
        for per_kernel in s:
            np.testing.assert_allclose(np.diag(per_kernel), 1.0, atol=1e-5)  # gamma normalises self-similarity
            assert per_kernel.max() <= 1 + 1e-5
            off = per_kernel[~np.eye(6, dtype=bool)]
            assert (off < 1 - 1e-3).all()  # no other frame is as similar as the frame itself
            assert (per_kernel[5, :5] == 0).all() and (per_kernel[:5, 5] == 0).all()  # no shared word: 0
    # a word of weight 0 (in every frame: idf 0) counts for nothing
    only = np.zeros(WORDS)
    only[9] = 1.0
    s = asmk_similarities(frames, frames, only)[0]
    assert (s[:5] == 0).all() and s[5, 5] == pytest.approx(1.0)


def test_aggregated_residuals_are_unit_sums_and_signs():
    c = centres()
    residuals = np.eye(DIM, dtype=np.float32)[[0, 1, 2, 5]] * [[0.2], [0.2], [-0.2], [0.2]]
    x = frame_near(c, np.array([3, 3, 7, 0]), residuals)
    x[3] = c[0]  # the word itself: a zero residual has no direction and is left out
    words, v = aggregate_residuals(x, np.array([3, 3, 7, 0]), c)
    np.testing.assert_array_equal(words, [3, 7])
    np.testing.assert_allclose(v[0], np.eye(DIM)[0] / np.sqrt(2) + np.eye(DIM)[1] / np.sqrt(2), atol=1e-6)
    np.testing.assert_allclose(v[1], -np.eye(DIM)[2], atol=1e-6)
    words_b, b = aggregate_residuals(x, np.array([3, 3, 7, -1]), c, binary=True)  # -1: left out
    np.testing.assert_array_equal(words_b, [3, 7])
    # sign codes of unit norm: <b, b'> = 1 - 2 h / DIM, h the Hamming distance (+1 for a zero component)
    np.testing.assert_allclose(b * np.sqrt(DIM), [np.ones(DIM), np.where(np.arange(DIM) == 2, -1, 1)], atol=1e-6)
    assert b[0] @ b[1] == pytest.approx(1 - 2 * 1 / DIM)
    with pytest.raises(ValueError, match="descriptors"):
        aggregate_residuals(np.zeros((4, 8), np.uint8), np.zeros(4, int), c[:, :8])  # bits have no residuals
    with pytest.raises(ValueError, match="words"):
        aggregate_residuals(x, np.array([3, 3, 7]), c)
    with pytest.raises(ValueError, match="weights"):
        asmk_similarities([(words, v)], [(words, v)], -np.ones(WORDS))


@pytest.mark.parametrize("binary", [False, True])
def test_a_perturbed_copy_outranks_a_distractor_with_the_same_words(binary):
    """The distractor holds exactly the query's words, so the bag of words cannot tell it from the
    query's perturbed copy (equal word counts, equal vectors); ASMK compares where in each word's
    cell the descriptors fall, and ranks the copy first."""
    rng = np.random.default_rng(2)
    c = centres()
    words = rng.integers(0, 8, 200)  # words 8-11 only in `other`: each word is missing from some frame (idf > 0)
    residuals = 0.15 * rng.normal(size=(200, DIM))
    query = frame_near(c, words, residuals)
    copy = frame_near(c, words, residuals + 0.05 * rng.normal(size=(200, DIM)))  # a deformed view: noisy descriptors
    distractor = frame_near(c, words, 0.15 * rng.normal(size=(200, DIM)))  # same words, other surface
    other = frame_near(c, rng.integers(8, WORDS, 200), 0.15 * rng.normal(size=(200, DIM)))
    features = [Features(np.zeros((200, 2)), d, np.ones(200, bool)) for d in (query, distractor, other, copy)]
    vocab = Vocabulary(c, "l2")
    counts = np.stack([word_counts(f, vocab) for f in features])
    np.testing.assert_array_equal(counts[1], counts[3])  # the copy and the distractor: the same word counts
    vectors = weight_histograms(counts, "tfidf-l1")
    _, bow = search(vectors[:1], vectors, k=3, exclude=np.array([0]), distance="l1")
    assert bow[0, 0] == bow[0, 1]  # the bag of words ties them
    frames = [aggregate_residuals(f.descriptors, nearest_words(f, vocab), c, binary) for f in features]
    held = np.zeros((4, WORDS))
    for i, (words_i, _) in enumerate(frames):
        held[i, words_i] = 1
    sim = asmk_similarities(frames[:1], frames, inverse_document_frequency(held))[0, 0]  # (4,)
    assert sim[3] > sim[1] + 0.1 and sim[1] < 0.05 and sim[2] == 0, sim  # the copy, far above the distractor
