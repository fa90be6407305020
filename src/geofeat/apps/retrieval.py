"""Object retrieval with a bag of visual words (the paper's first application, its retrieval figure).

1. keypoints (the 2048 best; by default each descriptor's own detector, GeoKey for GeoPatch and
   GeoBit and SIFT for the others, `describe_datasets`) are detected inside the object mask of every
   frame of every sequence (`geofeat.apps.objectmask.object_mask`) and described;
2. `vocabulary`: K visual words (paper: 10) are the K-medoids (FasterPAM, `kmedoids` package) of
   10,000 descriptors sampled at random from all frames (taken in sequence-name order, whatever the
   order the folders were given in), under each descriptor's own distance
   (L2; Hamming; GeoBit: the minimum Hamming distance over its 16 rotations), the distance matrix
   symmetrised as (D + D^T) / 2;
3. `word_counts`: each frame becomes the counts of its descriptors' nearest words (`histogram`: the
   same L1-normalised, the paper's), and `weight_histograms` turns the (N, K) counts of the N
   database frames into vectors: by default (DEFAULT_WEIGHTING, "tfidf-l1", Nister & Stewenius)
   the term frequencies times the inverse document frequency over the database frames
   (`inverse_document_frequency`: a word in every frame weighs nothing), L1-normalised; also
   "none" (the paper's histograms), "hellinger", "tfidf" and "tfidf-sqrt" (WEIGHTINGS; the
   comparison on 20 objects, which chose the default on validation queries, is in BENCHMARKS.md);
4. `search`: k-nearest neighbours of the query vectors among the database vectors under the
   weighting's distance: L1 for "tfidf-l1", else L2 (which on the L2-normalised tf-idf vectors
   ranks as cosine similarity); frames at equal distance are ranked by `tie_keys` (a fixed
   pseudo-random order of their names), not in the order the folders were given;
5. `accuracy_at_k`: queries are the reference frames; as in the paper the database holds the frames of
   the *other* sequences (`exclusion_mask`; the query's own sequence is left out unless
   `include_own_sequence`, and then only the query itself is), so that a query must find its object
   under another deformation. A query whose class has no other sequence is reported and skipped.
   Acc@K is the fraction of the top K results of the query's class, averaged over queries, with a
   95 % bootstrap interval over queries (`bootstrap_interval`).
6. `evaluate_descriptor`: unless K is given, it is chosen per descriptor by validation: the queries
   are split at random in two halves by class (all queries of one object fall in one half, so that
   no test query's object informs K; one class alone is split query by query); the K of `WORD_CANDIDATES` (5 to 2560 words, those below the
   number of sampled descriptors) with the best mean Acc@1..10 on the validation half is kept, and
   Acc@K is reported on the other (test) half only.
7. `rerank`: each test query's best RERANK database frames by the words are then reordered by
   `verified_matches`, the number of its keypoints' matches to the frame (mutual nearest
   neighbours passing Lowe's ratio test) that the local affine map of their neighbours confirms
   (`geofeat.apps.localfit.locally_consistent`): the words say which frames look alike, the
   matches which show the same surface, however it deforms. `rerank=0` keeps the words' order (the
   paper's setting). The measured gain is in BENCHMARKS.md ("Re-ranking by verified matches").
"""

from __future__ import annotations

import csv
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..constants import N_KEYPOINTS
from ..features import Features
from ..inputs import check_in_range, check_whole
from ..outputs import plural, write_picture

__all__ = [
    "Vocabulary", "vocabulary", "sample_descriptors", "histogram", "search", "accuracy_at_k", "read_classes",
    "RetrievalDatabase", "describe_datasets", "run_retrieval", "exclusion_mask", "per_query_accuracy",
    "bootstrap_interval", "split_queries", "WORD_CANDIDATES", "DescriptorResult", "evaluate_descriptor",
    "sample_distances", "eligible_queries", "word_counts", "inverse_document_frequency", "weight_histograms", "WEIGHTINGS",
    "DEFAULT_WEIGHTING", "tie_keys", "rerank", "verified_matches", "match_counts", "RERANK", "RERANK_RATIO",
    "nearest_words", "rank_distances",
]

#: Database frames per query that `rerank` reorders (0: none, the paper's setting); chosen on the
#: validation queries of the 60-object set among 10, 20, 40 and 80, each better than the one before
#: (BENCHMARKS.md, "Re-ranking by verified matches", "Re-ranking 80 results").
RERANK = 80
#: Lowe's ratio test of `verified_matches` (chosen with RERANK).
RERANK_RATIO = 0.9
#: Visual words (the paper's K).
N_WORDS = 10
#: Descriptors sampled for the vocabulary (the paper's).
N_VOCABULARY_SAMPLES = 10_000
#: Largest K of Acc@K.
MAX_K = 10
#: Vocabulary sizes tried by validation when K is not given.
WORD_CANDIDATES = (5, 10, 20, 40, 80, 160, 320, 640, 1280, 2560)
#: Word weightings of `weight_histograms`, and the distance `search` compares their vectors with.
WEIGHTINGS = {"none": "l2", "hellinger": "l2", "tfidf": "l2", "tfidf-sqrt": "l2", "tfidf-l1": "l1"}
#: The weighting used unless one is given (chosen on validation queries, see BENCHMARKS.md).
DEFAULT_WEIGHTING = "tfidf-l1"
#: Bootstrap resamples of the queries for the 95 % intervals.
N_BOOTSTRAP = 2000
#: The files `run_retrieval` writes into its output folder.
RESULT_FILES = ("retrieval.csv", "retrieval.md", "acc_at_k.png", "top6.png")


@dataclass
class Vocabulary:
    """K visual words: medoids (K, ...) descriptors (a subset of the sample) and the metric of
    `geofeat.match` ("l2", "hamming", "hamming-rot") that compares descriptors to them."""

    medoids: np.ndarray
    metric: str

    def __len__(self) -> int:
        return int(self.medoids.shape[0])


def _metric_of(descriptors: np.ndarray) -> str:
    from ..matching import _default_metric

    return _default_metric(descriptors)


def sample_descriptors(features: list[Features], n: int = N_VOCABULARY_SAMPLES, seed: int | np.random.Generator = 0
                       ) -> np.ndarray:
    """(min(n, total), ...) valid descriptors drawn at random, without replacement, from all records
    (all of one descriptor: the same dtype and trailing shape)."""
    valid = [np.asarray(f.descriptors)[f.valid] for f in features]
    if not valid:
        raise ValueError("features: expected at least one Features record")
    kinds = {f"{v.dtype} (N, {', '.join(map(str, v.shape[1:]))})" for v in valid}
    if len(kinds) > 1:  # np.concatenate would cast uint8 bits to floats, or fail on the widths
        raise ValueError(f"features: descriptors of different kinds: {', '.join(sorted(kinds))}; sample one "
                         "descriptor's")
    pool = np.concatenate(valid, axis=0)
    rng = np.random.default_rng(seed)
    if len(pool) <= n:
        return pool
    return pool[np.sort(rng.choice(len(pool), n, replace=False))]


def sample_distances(descriptors: np.ndarray, metric: str | None = None) -> np.ndarray:
    """(N, N) float32 symmetrised distance matrix (D + D^T) / 2 of (N, ...) descriptors under `metric`."""
    from ..matching import check_finite_descriptors, distance_matrix

    descriptors = np.asarray(descriptors)
    check_finite_descriptors(descriptors)  # NaN distances would give K-medoids words without a word
    metric = _metric_of(descriptors) if metric is None else metric
    D = distance_matrix(descriptors, descriptors, metric)
    return (D + D.T) * np.float32(0.5)


def vocabulary(descriptors: np.ndarray, words: int = N_WORDS, metric: str | None = None,
               seed: int = 0, distances: np.ndarray | None = None) -> Vocabulary:
    """K-medoids visual words of (N, ...) descriptors (FasterPAM on the full distance matrix).

    Args:
        descriptors: (N, D) float, (N, B) uint8 or (N, R, B) uint8 descriptors (N > words).
        words: K, the number of visual words.
        metric: see `geofeat.matching.distance_matrix`; None chooses from dtype and rank.
        seed: FasterPAM's random initialisation and processing order.
        distances: optional precomputed (N, N) `sample_distances(descriptors, metric)` (to try
            several K on one sample without recomputing it).
    """
    import kmedoids

    descriptors = np.asarray(descriptors)
    if isinstance(words, bool) or not isinstance(words, (int, np.integer)) or words < 2:
        raise ValueError(f"words: expected an integer >= 2, got {words!r}")
    if descriptors.ndim < 2 or len(descriptors) <= words:
        raise ValueError(f"descriptors: too few for {words} visual words: got {len(descriptors)} "
                         f"(shape {descriptors.shape}), expected more than {words}")
    metric = _metric_of(descriptors) if metric is None else metric
    D = sample_distances(descriptors, metric) if distances is None else np.asarray(distances)
    if D.shape != (len(descriptors),) * 2:  # another sample's matrix would pick medoids of the wrong rows
        raise ValueError(f"distances: expected the ({len(descriptors)}, {len(descriptors)}) matrix of these "
                         f"descriptors, got shape {D.shape}")
    seed = check_whole(seed, "seed", 0)  # 2.5 was truncated to 2 without a word
    result = kmedoids.fasterpam(D, int(words), init="random", random_state=seed, n_cpu=1)
    medoids = np.sort(np.asarray(result.medoids, np.int64))
    return Vocabulary(descriptors[medoids].copy(), metric)


def nearest_words(features: Features | np.ndarray, vocab: Vocabulary) -> np.ndarray:
    """(n,) int64 nearest visual word of each of the n descriptors of `features` under the
    vocabulary's metric (-1 for an invalid one)."""
    from ..matching import match, metric_of_pair

    descriptors = np.asarray(features.descriptors if isinstance(features, Features) else features)
    metric_of_pair(descriptors, vocab.medoids, ("features", "vocabulary"))  # bits against float words: no distance
    return np.asarray(match(features, vocab.medoids, metric=vocab.metric).matches0, np.int64)


def word_counts(features: Features | np.ndarray, vocab: Vocabulary) -> np.ndarray:
    """(K,) int64 number of valid descriptors of `features` whose nearest visual word is each word."""
    words = nearest_words(features, vocab)
    return np.bincount(words[words >= 0], minlength=len(vocab)).astype(np.int64)


def histogram(features: Features | np.ndarray, vocab: Vocabulary) -> np.ndarray:
    """(K,) float64 L1-normalised histogram of the nearest visual word of each valid descriptor
    (all zeros when there is none)."""
    h = word_counts(features, vocab).astype(np.float64)
    return h / h.sum() if h.sum() > 0 else h


def inverse_document_frequency(counts: np.ndarray) -> np.ndarray:
    """(K,) float64 idf of each word over the (N, K) word counts of N database frames:
    log(N / n_w), n_w the number of frames holding word w (0 for a word in every frame or in none)."""
    counts = np.atleast_2d(np.asarray(counts))
    frames_with = (counts > 0).sum(axis=0)
    if len(counts) == 0:  # no frames: no word is in any (log 0 would give NaN weights)
        return np.zeros(counts.shape[1])
    return np.log(len(counts) / np.maximum(frames_with, 1)) * (frames_with > 0)


def _check_weighting(weighting: str) -> None:
    """ValueError unless `weighting` is one of WEIGHTINGS (checked before any costly work)."""
    if weighting not in WEIGHTINGS:
        raise ValueError(f"weighting: expected one of {', '.join(WEIGHTINGS)}, got {weighting!r}")


def _normalise(v: np.ndarray, order: int) -> np.ndarray:
    """Rows of (N, K) `v` divided by their L1 or L2 norm (rows of zeros stay zero)."""
    norm = np.linalg.norm(v, ord=order, axis=1, keepdims=True)
    return np.divide(v, norm, out=np.zeros_like(v), where=norm > 0)


def weight_histograms(counts: np.ndarray, weighting: str = DEFAULT_WEIGHTING, idf: np.ndarray | None = None
                      ) -> np.ndarray:
    """(N, K) float64 vectors of (N, K) word counts, compared by `search` under WEIGHTINGS[weighting].

    With tf the L1-normalised counts (the term frequencies of `histogram`):
      - "none": tf (the paper's histograms; L2 distance);
      - "hellinger": sqrt(tf) (L2 distance between them is the Hellinger distance, up to sqrt 2);
      - "tfidf": tf * idf, L2-normalised (L2 distance ranks as cosine similarity; Sivic & Zisserman);
      - "tfidf-sqrt": sqrt(tf) * idf, L2-normalised (square roots damp repeated words, burstiness);
      - "tfidf-l1": tf * idf, L1-normalised, compared by L1 distance (Nister & Stewenius).
    idf: (K,) `inverse_document_frequency`; None computes it from `counts` (all of them the database).
    """
    _check_weighting(weighting)
    counts = np.atleast_2d(np.asarray(counts, np.float64))
    if counts.ndim != 2 or not (np.isfinite(counts) & (counts >= 0)).all():
        raise ValueError(f"counts: expected (N, K) word counts >= 0 (`word_counts`), got shape {counts.shape}"
                         f"{'' if counts.ndim != 2 else ' with negative, NaN or infinite values'}")
    tf = _normalise(counts, 1)
    if weighting == "none":
        return tf
    if weighting == "hellinger":
        return np.sqrt(tf)
    if idf is None:
        idf = inverse_document_frequency(counts)
    else:
        idf = np.asarray(idf, np.float64)
        if idf.shape != counts.shape[1:] or not (np.isfinite(idf) & (idf >= 0)).all():
            raise ValueError(f"idf: expected shape {counts.shape[1:]} of finite values >= 0 "
                             f"(`inverse_document_frequency`), got shape {idf.shape}")
    if weighting == "tfidf-l1":
        return _normalise(tf * idf, 1)
    return _normalise((np.sqrt(tf) if weighting == "tfidf-sqrt" else tf) * idf, 2)


def _distances(queries: np.ndarray, database: np.ndarray, distance: str) -> np.ndarray:
    """(Q, N) float64 L2 or L1 distances between (Q, K) and (N, K) vectors, from the differences
    themselves (exact for equal vectors), in blocks of queries of at most ~2**24 differences."""
    if distance not in ("l2", "l1"):
        raise ValueError(f"distance: expected 'l2' or 'l1', got {distance!r}")
    step = max(1, 2 ** 24 // max(database.size, 1))
    out = np.empty((len(queries), len(database)))
    for i in range(0, len(queries), step):
        diff = queries[i:i + step, None, :] - database[None, :, :]  # (step, N, K)
        out[i:i + step] = np.sqrt((diff ** 2).sum(-1)) if distance == "l2" else np.abs(diff).sum(-1)
    return out


def search(queries: np.ndarray, database: np.ndarray, k: int = MAX_K, exclude: np.ndarray | None = None,
           distance: str = "l2", order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """k-nearest neighbours of (Q, K) query vectors among (N, K) database vectors (histograms or
    `weight_histograms`).

    Args:
        exclude: optional database entries never returned: (Q,) one index per query (the query
            itself; -1 = none), or a (Q, N) bool mask (True = excluded, see `exclusion_mask`).
        distance: "l2" (Euclidean; on L2-normalised vectors it ranks as cosine similarity) or "l1".
        order: optional (N,) keys of the database entries: of entries at equal distance (ties), the
            lowest key first (then the lowest index); None: the lowest index first. `evaluate_descriptor`
            passes `tie_keys`, so that ties do not follow the order the folders were listed in.
    Returns:
        indices (Q, k) int64 and distances (Q, k) float64, nearest first (ties: see `order`);
        k is lowered to the fewest database entries any query may return.
    """
    queries = np.atleast_2d(np.asarray(queries, np.float64))
    database = np.atleast_2d(np.asarray(database, np.float64))
    if queries.shape[1] != database.shape[1]:
        raise ValueError(f"queries, database: histograms of different lengths {queries.shape} and {database.shape}")
    return rank_distances(_distances(queries, database, distance), k, exclude, order)


def rank_distances(d: np.ndarray, k: int = MAX_K, exclude: np.ndarray | None = None,
                   order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest of each row of a (Q, N) distance matrix (smaller first): `search`'s ranking, for
    any score (e.g. minus a similarity). `exclude`, `order` and the result as in `search`; `d` is
    not changed."""
    k = check_whole(k, "k", 1)  # k=0 returned no neighbours, and every Acc@K of them was 0
    d = np.array(d, np.float64)  # a copy: excluded entries are set to inf
    if d.ndim != 2:
        raise ValueError(f"d: expected a (Q, N) distance matrix, got shape {d.shape}")
    allowed = d.shape[1]
    if exclude is not None:
        exclude = np.asarray(exclude)
        if exclude.dtype == bool:
            if exclude.shape != d.shape:
                raise ValueError(f"exclude: expected a {d.shape} bool mask, got shape {exclude.shape}")
            d[exclude] = np.inf
            allowed -= int(exclude.sum(axis=1).max()) if len(exclude) else 0
        else:
            exclude = exclude.astype(np.int64).reshape(-1)
            if exclude.shape != (len(d),) or (exclude >= d.shape[1]).any():  # a short one left the last queries free
                raise ValueError(f"exclude: expected {len(d)} database indices (or -1), one per query, below "
                                 f"{d.shape[1]}; got shape {exclude.shape}")
            rows = np.flatnonzero(exclude >= 0)
            d[rows, exclude[rows]] = np.inf
            allowed -= 1 if len(rows) else 0  # -1 everywhere excludes nothing
    k = max(min(k, allowed), 0)
    if order is None:
        idx = np.argsort(d, axis=1, kind="stable")[:, :k]
    else:
        order = np.asarray(order).reshape(-1)
        if order.shape != (d.shape[1],):
            raise ValueError(f"order: expected {d.shape[1]} keys, one per database entry, got shape {order.shape}")
        perm = np.lexsort((np.arange(len(order)), order))  # the database in key order
        idx = perm[np.argsort(d[:, perm], axis=1, kind="stable")[:, :k]]
    return idx, np.take_along_axis(d, idx, axis=1)


def tie_keys(sequences, frames) -> np.ndarray:
    """(N,) int64 keys that order database entries at equal distance in `search`: the CRC-32 of
    "sequence/frame", a fixed pseudo-random order of the frames that does not depend on the order
    the folders were given or listed in, nor on their class. (By index, as before, two frames whose
    word vectors are equal, e.g. all zeros when each of their words is in every frame and weighs
    nothing under tf-idf, were returned in folder order, and the same query scored differently
    when the folders were given in another order.)"""
    import zlib

    return np.array([zlib.crc32(f"{s}/{f}".encode("utf-8")) for s, f in zip(sequences, frames)], np.int64)


def per_query_accuracy(neighbours: np.ndarray, database_classes, query_classes) -> np.ndarray:
    """(Q, k) Acc@K of each query for K = 1..k: the fraction of its top K results (neighbours (Q, k)
    database indices) of its class."""
    db = np.asarray(database_classes)
    neighbours = np.asarray(neighbours)
    if neighbours.size and (neighbours.min() < 0 or neighbours.max() >= len(db)):  # -1 would read the last class
        raise ValueError(f"neighbours: expected database indices in [0, {len(db)}), got values from "
                         f"{neighbours.min()} to {neighbours.max()}")
    correct = db[neighbours] == np.asarray(query_classes)[:, None]  # (Q, k)
    return np.cumsum(correct, axis=1) / np.arange(1, correct.shape[1] + 1)


def accuracy_at_k(neighbours: np.ndarray, database_classes, query_classes) -> np.ndarray:
    """(k,) Acc@K for K = 1..k: fraction of the top K results (neighbours (Q, k) database indices)
    of the query's class, averaged over the Q queries."""
    return per_query_accuracy(neighbours, database_classes, query_classes).mean(axis=0)


def bootstrap_interval(per_query: np.ndarray, n: int = N_BOOTSTRAP, level: float = 0.95,
                       seed: int | np.random.Generator = 0) -> tuple[np.ndarray, np.ndarray]:
    """Percentile bootstrap interval over queries of the mean of (Q, ...) per-query values.

    Returns (low, high), each of shape per_query.shape[1:]: the (1 - level) / 2 and (1 + level) / 2
    quantiles of the means of `n` resamples of the Q queries with replacement; NaN when Q < 2 (every
    resample of one query is that query: a zero-width interval that looked like certainty)."""
    level = check_in_range(level, "level (a fraction, 0.95 for 95 %)", 0.0, 1.0)  # 95 was numpy's quantile error
    per_query = np.asarray(per_query, np.float64)
    if len(per_query) < 2:
        nan = np.full(per_query.shape[1:], np.nan)
        return nan, nan.copy()
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(per_query), (n, len(per_query)))  # (n, Q)
    means = per_query[idx].mean(axis=1)  # (n, ...)
    return (np.quantile(means, (1 - level) / 2, axis=0), np.quantile(means, (1 + level) / 2, axis=0))


def exclusion_mask(sequences, queries: np.ndarray, include_own_sequence: bool = False) -> np.ndarray:
    """(Q, N) bool: the database entries (frames of `sequences`, (N,) sequence names) that query
    `queries[i]` (a database index) may not return: every frame of its own sequence (the paper's
    setting), or with `include_own_sequence` only the query frame itself."""
    seqs = np.asarray(sequences)
    queries = np.asarray(queries, np.int64)
    if include_own_sequence:
        mask = np.zeros((len(queries), len(seqs)), bool)
        mask[np.arange(len(queries)), queries] = True
        return mask
    return seqs[queries][:, None] == seqs[None, :]


def refuse_copied_sequences(folders: list[Path]) -> None:
    """ValueError naming both folders when two of the sequence `folders` have byte-identical reference
    frames (`io.frame_digest` of its colour and depth files): a sequence copied under another folder
    name (a dataset given twice under two names, or two datasets that share a sequence). The query's
    own sequence is left out of its results by name only, so the copy would be found as the query's
    own frame and counted as a correct result, raising Acc@K unsaid; the copy also weighs twice in
    the vocabulary, the idf and the other queries' results, so it is refused rather than left out."""
    from ..io import frame_digest, frame_names, reference_name

    seen: dict[str, Path] = {}
    for folder in folders:
        reference = reference_name(frame_names(folder))  # the name only: no frame is decoded here
        first = seen.setdefault(frame_digest(folder, reference), Path(folder))
        if first != Path(folder):
            raise ValueError(f"datasets: {first} and {folder} hold the same reference frame ({reference}, byte for "
                             "byte: one sequence copied under two folder names?); its query would find its own "
                             "frame in the copy and count it as a correct result, so Acc@K would be too high: "
                             "leave one of them out")


def _check_class_mates(sequences: list[str], classes: dict[str, str] | None, classes_file, every: bool = False) -> None:
    """ValueError when no two of `sequences` share a class (the folder name without `classes`), so that no
    query has an answer in a database of the other sequences; with `every`, whatever the classes (the
    queries were found to have none, e.g. after frames were skipped)."""
    given = {s: (classes[s] if classes is not None else s) for s in dict.fromkeys(sequences)}
    if not every and len(set(given.values())) < len(given):
        return
    if classes is None:
        raise ValueError("datasets: no query has another sequence of its class in the database (classes default to "
                         "the sequence folder name); pass --classes with a 'sequence,class' CSV, or "
                         "--include-own-sequence")
    # the classes were given: say which class each sequence got (it said "pass --classes")
    folded = {}
    for c in dict.fromkeys(given.values()):
        folded.setdefault(c.casefold(), []).append(c)
    same = [" and ".join(repr(c) for c in cs) for cs in folded.values() if len(cs) > 1]
    raise ValueError(f"classes: no query has another sequence of its class in the database; {classes_file} gives "
                     + ", ".join(f"{s}: {c!r}" for s, c in given.items())
                     + (f" (class names are case-sensitive: {'; '.join(same)} are different classes)" if same else "")
                     + "; give sequences of one object the same class, or pass --include-own-sequence")


def eligible_queries(db: "RetrievalDatabase", include_own_sequence: bool = False
                     ) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The queries (reference frames) that still have a frame of their class in the database.

    Returns:
        queries: (Q,) database indices of the eligible queries, in the order of their "sequence/frame"
            names, not the database's (the order the folders were given in): the bootstrap intervals
            and, with one class, the validation split (`split_queries`) draw queries by position, so
            in folder order `geofeat retrieval B A` reported other intervals than `geofeat retrieval A B`;
        exclude: their (Q, N) `exclusion_mask` (the query's own sequence, or the query alone with
            `include_own_sequence`);
        skipped: "sequence/frame (class c)" of each query left out (no other sequence of its class).
    """
    q_all = np.flatnonzero(db.is_query)
    q_all = q_all[sorted(range(len(q_all)), key=lambda i: (db.sequences[q_all[i]], db.frames[q_all[i]]))]
    exclude = exclusion_mask(db.sequences, q_all, include_own_sequence)
    cls = np.asarray(db.classes)
    eligible = ((cls[q_all][:, None] == cls[None, :]) & ~exclude).any(axis=1)  # a frame of its class remains
    skipped = [f"{db.sequences[i]}/{db.frames[i]} (class {db.classes[i]})" for i in q_all[~eligible]]
    return q_all[eligible], exclude[eligible], skipped


def split_queries(n: int, seed: int = 0, groups=None) -> tuple[np.ndarray, np.ndarray]:
    """(validation, test) sorted indices into n queries: a random half (floor(n / 2)) and the rest.

    groups: optional (n,) labels (the queries' classes, i.e. objects). Then whole groups are split: a
    random floor(G / 2) of the G groups give the validation queries and the rest the test queries, so
    that no test query's object also has a query in the validation half (which chooses K). With fewer
    than two groups there is nothing to split by, and the queries are split one by one."""
    n, seed = check_whole(n, "n", 0), check_whole(seed, "seed", 0)
    rng = np.random.default_rng(seed)
    if groups is not None:
        groups = np.asarray(groups)
        if groups.shape != (n,):
            raise ValueError(f"groups: expected {n} labels, one per query, got shape {groups.shape}")
        names, label = np.unique(groups, return_inverse=True)
        if len(names) >= 2:
            held = rng.permutation(len(names))[: len(names) // 2]
            in_val = np.isin(label, held)
            return np.flatnonzero(in_val), np.flatnonzero(~in_val)
    perm = rng.permutation(n)
    return np.sort(perm[: n // 2]), np.sort(perm[n // 2 :])


def read_classes(path: str | Path) -> dict[str, str]:
    """A CSV of `sequence,class` lines (an optional header `sequence,class`) -> {sequence: class}; a
    sequence given two different classes is refused (a repeated identical line is harmless)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"classes: file not found: {path}")
    out = {}
    try:  # utf-8-sig: a spreadsheet's byte-order mark is not part of the first sequence name
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except UnicodeDecodeError as error:
        raise ValueError(f"classes: {path} is not a UTF-8 text file ({error})") from None
    for i, row in enumerate(rows):
        row = [c.strip() for c in row]
        if not row or not any(row) or (i == 0 and row[:2] == ["sequence", "class"]):
            continue
        if len(row) < 2 or not row[0] or not row[1]:
            raise ValueError(f"classes: {path} line {i + 1}: expected 'sequence,class', got {','.join(row)!r}")
        if out.setdefault(row[0], row[1]) != row[1]:
            raise ValueError(f"classes: {path} line {i + 1}: sequence {row[0]!r} has class {out[row[0]]!r} "
                             f"on an earlier line and {row[1]!r} here; give each sequence one class")
    return out


@dataclass
class RetrievalDatabase:
    """Described frames: per frame (sequence, frame name, class, is reference), the masks' sources
    per sequence, and per descriptor the list of Features (one per frame, same order) and the
    detector of its keypoints (`detectors`). `skipped` names ("sequence/frame") the frames that
    could not be read or described (left out); `depth_profiles` the depth profile each sequence was
    described with."""

    sequences: list[str]
    frames: list[str]
    classes: list[str]
    is_query: np.ndarray
    folders: list[Path]
    mask_sources: dict[str, str]
    features: dict[str, list[Features]]
    skipped: list[str] = field(default_factory=list)
    detectors: dict[str, str] = field(default_factory=dict)
    depth_profiles: dict[str, str] = field(default_factory=dict)


def describe_datasets(datasets, descriptors: tuple[str, ...], n_keypoints: int = N_KEYPOINTS,
                      classes: dict[str, str] | None = None, tps_dir: str | None = None,
                      radius: float | None = None, depth_scale: float | None = None,
                      progress: bool = True, detector: str | None = None,
                      device: str | None = None) -> RetrievalDatabase:
    """Detect keypoints inside the object mask of every frame of every sequence and describe them.
    `detector` (as in `geofeat.detect`) for every descriptor, or None for each descriptor's own
    (`keypoints.detector_for`: GeoKey for GeoPatch and GeoBit, SIFT for the others); descriptors
    with the same detector share its keypoints (and the geodesic ones one mesh and set of patches).
    `device` "cuda" / "cuda:N": GeoPatch described on that GPU, the others on the CPU (`Describer`;
    `geofeat.gpu.gpu_descriptors` refuses a device that no descriptor would use)."""
    from ..descriptors.describer import Describer
    from ..depth import sequence_depth_profile
    from ..descriptors import check_descriptor_names
    from ..gpu import gpu_descriptors
    from ..io import find_sequences, read_sequence, skipped_frame_line
    from ..keypoints import detect, group_by_detector
    from .objectmask import object_mask

    names = check_descriptor_names(descriptors)
    gpu_descriptors(names, device)
    from ..inputs import check_tps_dir, resolve_radius

    folders = find_sequences(datasets, unique_names=True)
    check_tps_dir(tps_dir)
    groups = group_by_detector(names, detector)
    db = RetrievalDatabase([], [], [], np.zeros(0, bool), [], {}, {n: [] for n in names},
                           detectors={n: det for det, group in groups.items() for n in group})
    is_query = []
    seqs = [read_sequence(f, depth_scale=depth_scale) for f in folders]
    if classes is not None:
        missing = [s.name for s in seqs if s.name not in classes]
        if missing:
            raise ValueError(f"classes: no class for sequence(s) {', '.join(missing[:5])}")
        absent = sorted(set(classes) - {s.name for s in seqs})
        if absent:  # harmless for the scores, but a folder the user meant to include may be missing
            warnings.warn(f"classes: {plural(len(absent), 'sequence')} named in the classes file "
                          f"{'is' if len(absent) == 1 else 'are'} not among the datasets and left out: "
                          f"{', '.join(absent[:5])}{', ...' if len(absent) > 5 else ''}", stacklevel=2)
    total = sum(len(s) for s in seqs)
    bar = tqdm(total=total, desc="retrieval: describe", unit="frame", disable=not progress)
    for seq in seqs:
        # the bench's rules for the radius and the depth profile
        radius_m, profile = resolve_radius(radius, seq), sequence_depth_profile(seq)
        describers = {det: Describer(group, radius_m, profile, device=device) for det, group in groups.items()}
        db.depth_profiles[seq.name] = profile
        sources = set()
        for name in seq.names:
            try:
                frame = seq.frame(name)
                mask, source = object_mask(seq, name, tps_dir)
                described = {}
                for det, describe in describers.items():
                    kps = detect(frame, n_keypoints, detector=det, mask=mask)
                    if len(kps) == 0:
                        raise ValueError(f"no keypoints detected ({det})")
                    described.update(describe(frame, kps))
            except ValueError as error:  # reported by name; the other frames go on
                tqdm.write(skipped_frame_line(name, error, seq.name))
                db.skipped.append(f"{seq.name}/{name}")
                bar.update(1)
                continue
            sources.add(source)
            for d, (f, _) in described.items():
                db.features[d].append(f)
            db.sequences.append(seq.name)
            db.frames.append(name)
            db.classes.append(classes[seq.name] if classes is not None else seq.name)
            db.folders.append(seq.folder)
            is_query.append(name == seq.reference)
            bar.update(1)
        db.mask_sources[seq.name] = ",".join(sorted(sources))
    bar.close()
    db.is_query = np.asarray(is_query, bool)
    return db


def _thumbnail(folder: Path, name: str, size: tuple[int, int], colour) -> np.ndarray:
    """(h, w, 3) uint8 BGR: the colour image of frame `name` letterboxed into a cell of `size` (w, h)
    pixels (its aspect ratio kept: it was squashed to 4:3), framed in `colour` (None: no frame)."""
    import cv2

    from ..io import RGB_SUFFIX, read_image
    from ..viz import letterbox

    img = letterbox(read_image(folder / f"{name}{RGB_SUFFIX}"), size)
    if colour is not None:
        cv2.rectangle(img, (0, 0), (size[0] - 1, size[1] - 1), colour, 6)
    return img


#: Height of top6.png's header row (column names and colour key), pixels.
TOP6_HEADER_PX = 42


def _top6_picture(db: RetrievalDatabase, results: dict[str, tuple[np.ndarray, np.ndarray]], path: Path,
                  queries_per: int = 2) -> None:
    """Rows: descriptor x query; query thumbnail (blue frame), then its top 6 (green = same class),
    under a header that names the columns (`TOP6_HEADER_PX` tall) and the colours.

    results: {descriptor: (query database indices (Q,), neighbours (Q, k))}."""
    import cv2

    from ..viz import wrap_text

    size = (160, 120)
    rows = []
    for name, (q_idx, neighbours) in results.items():
        if len(q_idx) == 0:
            continue
        for row_q in np.linspace(0, len(q_idx) - 1, min(queries_per, len(q_idx))).round().astype(int):
            qi = q_idx[row_q]
            tiles = [_thumbnail(db.folders[qi], db.frames[qi], size, (255, 128, 0))]
            for j in neighbours[row_q, :6]:
                ok = db.classes[j] == db.classes[qi]
                tiles.append(_thumbnail(db.folders[j], db.frames[j], size, (0, 200, 0) if ok else (0, 0, 255)))
            while len(tiles) < 7:
                tiles.append(np.zeros((size[1], size[0], 3), np.uint8))
            label = np.full((size[1], 110, 3), 255, np.uint8)
            # the whole name, wrapped: cut to 12 characters, "geopatch=run1/x.pt" and "geopatch=run2/x.pt" read alike
            # (a path too long for the column keeps its start and its end, the file's name)
            lines = wrap_text(name, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 110 - 8)
            fit = size[1] // 18
            if len(lines) > fit:
                lines = lines[:1] + ["..."] + lines[len(lines) - fit + 2:]
            for k, line in enumerate(lines):
                y = (size[1] - 18 * len(lines)) // 2 + 14 + 18 * k  # the lines' baselines, centred
                cv2.putText(label, line, (4, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
            rows.append(np.concatenate([label] + tiles, axis=1))
    if rows:
        # a header names the columns: the query, then its results in rank order, and the colours
        header = np.full((TOP6_HEADER_PX, rows[0].shape[1], 3), 255, np.uint8)
        text = [("descriptor", 4), ("query", 110 + 4)] + [(f"top {k}", 110 + k * size[0] + 4) for k in range(1, 7)]
        for words, x in text:
            cv2.putText(header, words, (x, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(header, "blue: the query; green: the same object; red: another", (110 + 4, 35),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        write_picture(path, np.concatenate([header] + rows, axis=0))


def _plot(acc: dict[str, np.ndarray], path: Path, rerank: int = 0) -> None:
    """acc_at_k.png: Acc@K against K per descriptor ({name: (k,) Acc@1..k}); `rerank` > 0: the
    accuracies are those after `rerank` of each query's best `rerank` frames, which the title says
    (it said "bag of visual words" of the re-ranked curves too)."""
    from ..viz import plot_figure

    fig, ax = plot_figure((5.5, 4))
    styles = [("o", "-", 9), ("s", "--", 7), ("^", ":", 6), ("D", "-.", 4), ("v", "-", 4), ("x", "--", 6)]
    for i, (name, a) in enumerate(acc.items()):  # distinct markers and sizes keep equal curves visible
        marker, line, size = styles[i % len(styles)]
        ax.plot(np.arange(1, len(a) + 1), a, marker=marker, linestyle=line, markersize=size, label=name)
    ax.set_xlabel("K (top results)")
    ax.set_ylabel("Acc@K")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend()
    title = "Object retrieval, bag of visual words"
    if rerank > 0:
        title += f",\nbest {rerank} re-ranked by verified matches"
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def match_counts(features0: Features, features1: Features, ratio: float | None = RERANK_RATIO,
                 device: str | None = None) -> tuple[int, int]:
    """(matches, verified): how many keypoints of frame 0 match frame 1 (mutual nearest neighbours
    passing Lowe's ratio test `ratio`, None for none; `geofeat.match`, on `device`), and how many of
    them the local affine map of their neighbours confirms (`geofeat.apps.localfit.locally_consistent`,
    which needs at least 8 matches; 0 below)."""
    from ..matching import match
    from .localfit import locally_consistent

    m = match(features0, features1, mutual=True, ratio=ratio, device=device).matches0
    i0 = np.flatnonzero(m >= 0)
    if len(i0) < 8:
        return len(i0), 0
    return len(i0), int(locally_consistent(features0.keypoints[i0], features1.keypoints[m[i0]]).sum())


def verified_matches(features0: Features, features1: Features, ratio: float = RERANK_RATIO,
                     device: str | None = None) -> int:
    """How many keypoints of frame 0 match frame 1 where the local affine map of their neighbours
    agrees (`match_counts`' second count): a count of correspondences that a surface keeps when it
    bends."""
    return match_counts(features0, features1, ratio, device)[1]


def rerank(neighbours: np.ndarray, queries: np.ndarray, features: list[Features], top: int = RERANK,
           ratio: float = RERANK_RATIO, progress: bool = False, device: str | None = None) -> np.ndarray:
    """Reorder each query's best `top` results by `verified_matches`, most first.

    Args:
        neighbours: (Q, k) database indices of each query's results, best first (`search`).
        queries: (Q,) database indices of the queries.
        features: one `Features` per database frame.
        top: results reordered per query (the first min(top, k)); 0 returns `neighbours` unchanged.
        device: where the matches are searched (`geofeat.match`; None: the CPU).
    Returns:
        (Q, k) int64: the first `top` of each row sorted by verified matches (ties keep the order
        of `neighbours`), the rest unchanged.
    """
    neighbours = np.asarray(neighbours, np.int64)
    queries = np.asarray(queries, np.int64).reshape(-1)
    if top < 0:
        raise ValueError(f"top: expected >= 0 results to re-rank, got {top}")
    if neighbours.ndim != 2 or len(neighbours) != len(queries):
        raise ValueError(f"neighbours: expected ({len(queries)}, k) database indices, got shape {neighbours.shape}")
    top = min(top, neighbours.shape[1])
    out = neighbours.copy()
    if top < 2:
        return out
    for row in tqdm(range(len(queries)), desc="retrieval: re-rank", unit="query", disable=not progress):
        q = queries[row]
        counts = np.array([verified_matches(features[q], features[j], ratio, device) for j in neighbours[row, :top]])
        out[row, :top] = neighbours[row, :top][np.argsort(-counts, kind="stable")]
    return out


@dataclass
class DescriptorResult:
    """Retrieval outcome of one descriptor.

    Attributes:
        words: the vocabulary size K used.
        validation: {K: mean Acc@1..max_k on the validation queries} (empty when K was given).
        queries: (Q,) database indices of the test queries (all eligible queries when K was given).
        neighbours: (Q, k) their results, database indices, nearest first.
        per_query: (Q, k) each query's Acc@1..k.
        accuracy, low, high: (k,) Acc@K and its 95 % bootstrap interval over the queries.
        weighting: the word weighting of `weight_histograms`.
        rerank: results per query reordered by `rerank` (0: the words' order).
        per_query_words: (Q, k) each query's Acc@1..k in the words' order, before `rerank`.
    """

    words: int
    validation: dict[int, float]
    queries: np.ndarray
    neighbours: np.ndarray
    per_query: np.ndarray
    accuracy: np.ndarray
    low: np.ndarray
    high: np.ndarray
    weighting: str = DEFAULT_WEIGHTING
    rerank: int = 0
    per_query_words: np.ndarray | None = None


def evaluate_descriptor(features: list[Features], db: RetrievalDatabase, queries: np.ndarray,
                        exclude: np.ndarray, words: int | None = None, n_samples: int = N_VOCABULARY_SAMPLES,
                        seed: int = 0, max_k: int = MAX_K, candidates: tuple[int, ...] = WORD_CANDIDATES,
                        weighting: str = DEFAULT_WEIGHTING, rerank_top: int = RERANK,
                        progress: bool = False, device: str | None = None) -> DescriptorResult:
    """Vocabulary, word counts, weighted vectors, search and Acc@K of one descriptor.

    Args:
        features: one Features record per database frame (N frames, the whole database).
        queries: (Q,) database indices of the eligible queries; exclude: their (Q, N) `exclusion_mask`.
        words: K; None chooses it among `candidates` (those below the number of sampled descriptors)
            by validation on the queries of a random half of the classes (objects; `split_queries`)
            and reports Acc@K on the queries of the other half.
        weighting: see `weight_histograms`; the idf comes from the N database frames.
        rerank_top: each test query's best `rerank_top` results by the words are reordered by
            `rerank` (K is chosen on the words' order); 0 keeps the words' order.
        device: where `rerank` searches its matches (`geofeat.match`; None: the CPU); the vocabulary
            and the word counts are computed on the CPU.
    """
    _check_weighting(weighting)
    # the sample drawn from the frames in sequence-name order (a stable sort keeps each sequence's frame
    # order): in the order the folders were given, `geofeat retrieval B A` drew another sample, and
    # FasterPAM another vocabulary, than `geofeat retrieval A B` (one folder of sequences: already so)
    canonical = sorted(range(len(features)), key=lambda i: db.sequences[i])
    sample = sample_descriptors([features[i] for i in canonical], n_samples, seed)
    ks = [int(words)] if words is not None else [k for k in candidates if k < len(sample)]
    if not ks or len(sample) <= min(ks):
        raise ValueError(f"descriptors: {len(sample)} valid descriptors in all, too few for "
                         f"{words if words is not None else min(candidates)} visual words")
    D = sample_distances(sample)

    runs: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    depth = max(max_k, rerank_top)  # results kept per query: enough for `rerank`
    ties = tie_keys(db.sequences, db.frames)  # equal distances: not in folder order

    def run(k: int) -> tuple[np.ndarray, np.ndarray]:
        """(Q, depth) neighbours and (Q, max_k) per-query Acc@K with K visual words (memoised)."""
        if k not in runs:
            vocab = vocabulary(sample, k, seed=seed, distances=D)
            vectors = weight_histograms(np.stack([word_counts(f, vocab) for f in features]), weighting)  # (N, K)
            neighbours, _ = search(vectors[queries], vectors, depth, exclude=exclude, distance=WEIGHTINGS[weighting],
                                   order=ties)
            runs[k] = neighbours, per_query_accuracy(neighbours[:, :max_k], db.classes, np.asarray(db.classes)[queries])
        return runs[k]

    validation: dict[int, float] = {}
    test = np.arange(len(queries))
    if words is None:
        if len(queries) < 2:
            raise ValueError(f"queries: {len(queries)} eligible query, too few to choose K by validation; pass --words")
        val, test = split_queries(len(queries), seed, groups=np.asarray(db.classes)[queries])
        best = None
        for k in ks:
            _, acc = run(k)
            validation[k] = float(acc[val].mean())
            if best is None or validation[k] > validation[best]:  # ties: the smaller K
                best = k
        ks = [best]
    neighbours, acc = run(ks[0])
    neighbours, acc_words = neighbours[test], acc[test]
    acc = acc_words
    # the results `rerank` reorders: no more than the database leaves a query (retrieval.md names them)
    rerank_top = min(rerank_top, neighbours.shape[1]) if rerank_top >= 2 else 0
    if rerank_top > 0:
        neighbours = rerank(neighbours, queries[test], features, rerank_top, progress=progress, device=device)
        acc = per_query_accuracy(neighbours[:, :max_k], db.classes, np.asarray(db.classes)[queries[test]])
    neighbours = neighbours[:, :max_k]
    low, high = bootstrap_interval(acc, seed=seed)
    return DescriptorResult(ks[0], validation, queries[test], neighbours, acc, acc.mean(axis=0), low, high, weighting,
                            rerank_top, acc_words)


def check_samples(n_samples: int, words: int | None, samples_name: str = "samples", words_name: str = "words") -> int:
    """The vocabulary sample must be larger than K: `words`, or when None the smallest of
    `WORD_CANDIDATES` (K is then chosen among those below it). ValueError naming `samples_name`
    (the command line passes its flags) otherwise."""
    check_whole(n_samples, samples_name, 1)
    fewest = words or min(WORD_CANDIDATES)
    if n_samples <= fewest:
        k = f"{words_name} {words}" if words else f"the smallest {words_name} candidate, {fewest}"
        raise ValueError(f"{samples_name}: {n_samples} sampled descriptors are too few for {k}; expected more than "
                         f"{fewest}")
    return n_samples


def run_retrieval(datasets, out: str | Path, descriptors: tuple[str, ...] = ("geopatch", "geobit", "sift"),
                  words: int | None = None, n_samples: int = N_VOCABULARY_SAMPLES, seed: int = 0,
                  classes_file: str | None = None, n_keypoints: int = N_KEYPOINTS, tps_dir: str | None = None,
                  radius: float | None = None, depth_scale: float | None = None, max_k: int = MAX_K,
                  include_own_sequence: bool = False, progress: bool = True, overwrite: bool = False,
                  detector: str | None = None, weighting: str = DEFAULT_WEIGHTING, rerank_top: int = RERANK,
                  device: str | None = None) -> tuple[dict[str, DescriptorResult], RetrievalDatabase]:
    """The whole retrieval experiment; writes into `out`: `retrieval.csv` (descriptor, words, weighting,
    k, accuracy, low, high: Acc@K and its 95 % bootstrap interval, rerank: the results per query
    re-ranked before Acc@K, 0 for the words' order), `acc_at_k.png`, `top6.png` (two
    queries per descriptor) and `retrieval.md` (table, chosen K, skipped queries and frames, mask sources).

    The folder is built aside and moved into place at the end; an existing non-empty `out` needs
    `overwrite` (`geofeat.outputs`). Frames that cannot be described are skipped and named in
    `db.skipped` and in retrieval.md.

    Args:
        words: K; None = chosen per descriptor by validation (see `evaluate_descriptor`).
        include_own_sequence: the database also holds the query's own sequence (the query frame
            itself excluded); by default the query's whole sequence is left out (the paper's setting).
        weighting: the word weighting and distance (`weight_histograms`, WEIGHTINGS).
        rerank_top: results per query reordered by verified matches (`rerank`; 0: none).
        detector: the keypoints of every descriptor; None: each descriptor's own (`describe_datasets`).
        device: None or "cpu": everything on the CPU; "cuda" / "cuda:N": GeoPatch described and its
            `rerank` matches searched on that GPU, the other descriptors on the CPU (ValueError when
            none of `descriptors` is GeoPatch: `geofeat.gpu.gpu_descriptors`).
    Returns ({descriptor: DescriptorResult}, the described database)."""
    from ..io import find_sequences, path_list
    from ..outputs import check_out_dir, output_folder

    _check_weighting(weighting)
    if isinstance(rerank_top, bool) or not isinstance(rerank_top, (int, np.integer)) or rerank_top < 0:
        raise ValueError(f"rerank: expected a whole number of results >= 0 (0 = the words' order), got {rerank_top!r}")
    folders = find_sequences(datasets, unique_names=True)
    out = check_out_dir(out, overwrite, files=RESULT_FILES, inputs=[*path_list(datasets), *folders, tps_dir])
    if n_keypoints is not None:
        check_whole(n_keypoints, "keypoints", 1)
    check_whole(seed, "seed", 0)
    if words is not None:
        check_whole(words, "words", 2)
    check_samples(n_samples, words)
    if device is not None:  # a device that is not one, or that no descriptor would use: before any work
        from ..descriptors import check_descriptor_names
        from ..gpu import gpu_descriptors

        on_gpu = gpu_descriptors(check_descriptor_names(descriptors), device)
    else:
        on_gpu = ()
    classes = read_classes(classes_file) if classes_file else None
    if not include_own_sequence:  # the classes decide now, not after every frame is described, whether a query has an answer
        from ..descriptors import check_descriptor_names
        from ..inputs import check_tps_dir
        from ..keypoints import group_by_detector

        # a bad name, weights file or --tps-dir is the first error, as in describe_datasets
        group_by_detector(check_descriptor_names(descriptors), detector)
        check_tps_dir(tps_dir)
        names = [f.name for f in folders]
        if classes is None or all(n in classes for n in names):  # a sequence without a class: describe_datasets says so
            _check_class_mates(names, classes, classes_file)
    refuse_copied_sequences(folders)  # the last check before the frames are described
    db = describe_datasets(datasets, descriptors, n_keypoints, classes, tps_dir, radius, depth_scale, progress, detector,
                           device)
    if not db.frames:
        raise ValueError(f"datasets: every frame was skipped ({', '.join(db.skipped[:5])}"
                         f"{', ...' if len(db.skipped) > 5 else ''}; see the SKIPPED lines); nothing written")
    if db.is_query.sum() == 0:
        raise ValueError("datasets: no reference frame to query")
    if db.is_query.all():
        raise ValueError(f"datasets: {len(db.frames)} frame(s), all of them reference frames (queries); retrieval "
                         "needs other frames to search among")
    q_idx, exclude, skipped = eligible_queries(db, include_own_sequence)
    if len(q_idx) == 0:
        _check_class_mates(db.sequences, classes, classes_file, every=True)
    res: dict[str, DescriptorResult] = {}
    for name, feats in db.features.items():
        try:
            res[name] = evaluate_descriptor(feats, db, q_idx, exclude, words, n_samples, seed, max_k,
                                            weighting=weighting, rerank_top=rerank_top, progress=progress,
                                            device=device if name in on_gpu else None)
        except ValueError as e:
            raise ValueError(f"{e} (descriptor {name})") from None
    with output_folder(out) as tmp:
        _write_retrieval(tmp, db, res, skipped, words, n_samples, include_own_sequence,
                         _trivial_queries(db, q_idx, exclude), len(set(np.asarray(db.classes)[q_idx])))
    return res, db


def _trivial_queries(db: "RetrievalDatabase", queries: np.ndarray, exclude: np.ndarray) -> list[str]:
    """"sequence/frame" of each query (database indices (Q,), their (Q, N) `exclusion_mask`) whose
    database holds frames of its own class only: every result it can get is correct, so its Acc@K is
    1 whatever the descriptor (one class in the database, e.g. two sequences of one object)."""
    cls = np.asarray(db.classes)
    own = (cls[queries][:, None] == cls[None, :]) | exclude
    return [f"{db.sequences[i]}/{db.frames[i]}" for i in np.asarray(queries)[own.all(axis=1)]]


def _write_retrieval(out: Path, db: RetrievalDatabase, res: dict[str, DescriptorResult], skipped: list[str],
                     words: int | None, n_samples: int, include_own_sequence: bool,
                     trivial: list[str] | None = None, query_classes: int | None = None) -> None:
    """The result files of `run_retrieval`, into `out` (query_classes: the classes of the eligible queries)."""
    with open(out / "retrieval.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["descriptor", "words", "weighting", "k", "accuracy", "low", "high", "rerank"])
        for name, r in res.items():
            w.writerows([name, r.words, r.weighting, k + 1, f"{v:.4f}", f"{lo:.4f}", f"{hi:.4f}", r.rerank]
                        for k, (v, lo, hi) in enumerate(zip(r.accuracy, r.low, r.high)))
    _plot({n: r.accuracy for n, r in res.items()}, out / "acc_at_k.png",
          max((r.rerank for r in res.values()), default=0))
    _top6_picture(db, {n: (r.queries, r.neighbours) for n, r in res.items()}, out / "top6.png")
    (out / "retrieval.md").write_text(_report(db, res, skipped, words, n_samples, include_own_sequence, trivial,
                                              query_classes),
                                       encoding="utf-8")


def _all_sequences(count: int) -> str:
    """"all 3 sequences", but "1 sequence" (there is no "all" of one)."""
    return ("all " if count > 1 else "") + plural(count, "sequence")


def _interval(low: float, high: float) -> str:
    """A table cell's "[low, high]", or "[–]" where there is no interval (fewer than 2 queries)."""
    return "[–]" if np.isnan(low) or np.isnan(high) else f"[{low:.2f}, {high:.2f}]"


def _report(db: RetrievalDatabase, res: dict[str, DescriptorResult], skipped: list[str], words: int | None,
            n_samples: int, include_own_sequence: bool, trivial: list[str] | None = None,
            query_classes: int | None = None) -> str:
    """retrieval.md: Acc@K [95 % interval] per descriptor, then notes (query_classes: the number of
    classes among the eligible queries; with one, `split_queries` splits query by query)."""
    k_max = max(len(r.accuracy) for r in res.values())
    ks = [k for k in (1, 3, 5, 10) if k <= k_max]
    reranked = any(r.rerank > 0 for r in res.values())
    head = "| descriptor | K (words) | queries | " + " | ".join(f"Acc@{k}" for k in ks) + f" | mean Acc@1–{k_max} |"
    head += f" mean Acc@1–{k_max}, words only |" if reranked else ""
    lines = [head, "|---" * (len(ks) + 4 + reranked) + "|"]
    for n, r in res.items():
        cells = [f"{r.accuracy[k - 1]:.3f} {_interval(r.low[k - 1], r.high[k - 1])}" for k in ks]
        mlo, mhi = bootstrap_interval(r.per_query.mean(axis=1, keepdims=True))
        cells.append(f"{r.per_query.mean():.3f} {_interval(mlo[0], mhi[0])}")
        if reranked:
            wlo, whi = bootstrap_interval(r.per_query_words.mean(axis=1, keepdims=True))
            cells.append(f"{r.per_query_words.mean():.3f} {_interval(wlo[0], whi[0])}")
        lines.append(f"| {n} | {r.words} | {len(r.queries)} | " + " | ".join(cells) + " |")
    n_cls = len(set(db.classes))
    # each descriptor's vocabulary sample (`sample_descriptors`): its own valid descriptors may be fewer
    sampled = {n: min(n_samples, sum(int(f.valid.sum()) for f in db.features[n])) for n in res}
    if len(set(sampled.values())) == 1:
        vocab = plural(next(iter(sampled.values())), "sampled descriptor")
    else:
        vocab = ", ".join(f"{plural(v, 'sampled descriptor') if i == 0 else v} ({n})"
                          for i, (n, v) in enumerate(sampled.items()))
    notes = [f"{plural(len(db.frames), 'frame')} of {plural(len(set(db.sequences)), 'sequence')}, "
             f"{plural(n_cls, 'class', 'classes')}; database: "
             + ("every frame but the query" if include_own_sequence else "the frames of the other sequences")
             + "; [95 % bootstrap interval over queries; – with a single query]",
             f"vocabulary from {vocab}; word weighting "
             f"{next(iter(res.values())).weighting} ({WEIGHTINGS[next(iter(res.values())).weighting]} distance)"]
    if reranked:
        top = next(r.rerank for r in res.values())
        notes.append(f"each query's best {plural(top, 'frame')} by the words reordered by verified matches (mutual nearest "
                     f"neighbours, ratio test {RERANK_RATIO}, confirmed by their neighbours' local affine map); "
                     "K chosen on the words' order")
    if words is None:
        for n, r in res.items():
            scores = ", ".join(f"{k}: {v:.3f}" for k, v in r.validation.items())
            held_out = len(db.is_query.nonzero()[0]) - len(skipped) - len(r.queries)
            notes.append(f"{n}: K = {r.words} chosen by validation (mean Acc@1–{k_max} on "
                         f"{plural(held_out, 'held-out query', 'held-out queries')}: {scores}); "
                         f"Acc@K on the other {len(r.queries)}")
        if query_classes == 1:  # `split_queries` had no classes to split by
            notes.append("WARNING: every query is of one class, so the queries were split one by one and K was "
                         "chosen on queries of the test queries' own object (an optimistic Acc@K); pass --words, or "
                         "add a second object with two sequences")
    else:
        notes.append(f"K = {words} given")
    if trivial:
        n_queries = int(db.is_query.sum()) - len(skipped)
        notes.append(f"WARNING: {len(trivial)} of {plural(n_queries, 'query', 'queries')} can return only frames of "
                     "their own class (no other class left in their database), so their Acc@K is 1 whatever the "
                     "descriptor; add sequences of other objects (distractors): " + ", ".join(trivial))
    if skipped:
        notes.append(f"skipped {plural(len(skipped), 'query', 'queries')} whose class has no other "
                     f"sequence: " + ", ".join(skipped))
    detectors = getattr(db, "detectors", {})
    if detectors:
        notes.append("keypoints (inside the object mask) from: " + ", ".join(f"{d}: {det}" for d, det in detectors.items()))
    sources = set(db.mask_sources.values())
    if len(sources) == 1:  # one line, not one entry per sequence
        notes.append(f"object masks: {sources.pop()}, for {_all_sequences(len(db.mask_sources))}")
    else:
        notes.append("object masks: " + ", ".join(f"{s}: {src}" for s, src in db.mask_sources.items()))
    profiles = set(getattr(db, "depth_profiles", {}).values())
    if len(profiles) == 1:
        notes.append(f"depth profile: {profiles.pop()}, for {_all_sequences(len(db.depth_profiles))}")
    elif profiles:
        notes.append("depth profiles: " + ", ".join(f"{s}: {p}" for s, p in db.depth_profiles.items()))
    if db.skipped:
        notes.append(f"SKIPPED frames: {', '.join(db.skipped)}")
    return "\n".join(lines) + "\n\n" + "\n".join(f"- {x}" for x in notes) + "\n"
