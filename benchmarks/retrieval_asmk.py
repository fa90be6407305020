"""ASMK and ASMK* instead of the bag of words in `geofeat retrieval` (issue 23's retrieval target):
tried, not adopted (BENCHMARKS.md, "ASMK instead of the bag of words").

The aggregated selective match kernel (Tolias, Avrithis & Jégou, "To aggregate or not to aggregate:
selective match kernels for image search", ICCV 2013), written here from the paper's definitions. A
frame X is a set of descriptors x, each assigned its nearest visual word c (the command's K-medoids
`vocabulary` of 10,000 sampled descriptors, seed 0). Per word the residuals are summed and
L2-normalised, V(X_c) = sum (x - c) / ||sum (x - c)|| (`aggregate_residuals`); ASMK* keeps only their
signs, b = sign(V) / sqrt(D), whose dot product is 1 - 2 h / D for the Hamming distance h of the two
D-bit codes. Two frames score

    K(X, Y) = gamma(X) gamma(Y) sum over the words c of both of w_c sigma(<V(X_c), V(Y_c)>),
    sigma(u) = sign(u) |u|^alpha for u > tau, else 0,   gamma(X) = (sum over X's words of w_c)^(-1/2),

with w_c = 1 or the word's idf over the database frames, so that a frame's similarity to itself is 1
and no pair scores more (`asmk_similarities`). Tried: K = 256, 1024, 2560; (alpha, tau) in `KERNELS`.

Why K-medoids and not k-means: the residual x - c needs c in descriptor space, which a medoid is (one
of the sampled descriptors); k-means would give other words than the command's, and then a gain could
not be told from the change of words. The same vocabulary serves the bag of words and ASMK here.

Then, as the command does, each query's best `RERANK` (80) frames are reordered by their verified
matches V (`match_counts`, cached in --counts; new pairs are matched and added). Printed per variant:
mean Acc@1-10 of both descriptors over all queries (words alone, and re-ranked), the paired difference
GeoPatch - SIFT with its 95 % bootstrap interval, both descriptors on the validation half
(`split_queries` by object) and their sum (the rule that chooses a variant: better retrieval for both,
not a wider lead), and how many of a query's 12 relevant frames (the other sequences of its object)
the 80-frame shortlist holds. Re-ranked (`--rerank auto`): the bag of words at the largest K, and of
ASMK and of ASMK* the variant with the best validation sum of the words alone.

    python benchmarks/retrieval_asmk.py --cache DB.pkl --counts COUNTS.pkl [--words 256,1024,2560]

DB.pkl: a pickled `RetrievalDatabase` of a `make_retrieval_set.py` folder (GeoPatch on GeoKey's
keypoints as "geopatch", SIFT as "sift"; `retrieval_scores.py --cache` writes one); COUNTS.pkl: the
(M, V) of each (descriptor, query, frame) pair (`retrieval_scores.py --counts`), read and extended.
"""

from __future__ import annotations

import argparse
import pickle
import time
import zlib
from pathlib import Path

import numpy as np

from common import paired_halves
from geofeat.apps.retrieval import (
    RERANK, eligible_queries, inverse_document_frequency, match_counts, nearest_words, per_query_accuracy,
    rank_distances, sample_descriptors, sample_distances, search, split_queries, tie_keys, vocabulary,
    weight_histograms,
)

NAMES = ("geopatch", "sift")
#: (alpha, tau) of the selective function sigma tried (the paper's: alpha = 3, tau = 0).
KERNELS = ((1.0, 0.0), (3.0, 0.0), (5.0, 0.0), (7.0, 0.0), (3.0, 0.25))


#: A frame's aggregated residuals: the words it holds (m,) int64, ascending, and their (m, D) float32 unit vectors.
Aggregated = tuple[np.ndarray, np.ndarray]


def aggregate_residuals(descriptors: np.ndarray, words: np.ndarray, centres: np.ndarray, binary: bool = False
                        ) -> Aggregated:
    """One frame's aggregated residuals, per visual word it holds.

    Args:
        descriptors: (n, D) float descriptors of the frame.
        words: (n,) int, each descriptor's nearest word (an index into `centres`; -1: left out, e.g. an
            invalid descriptor, as `nearest_words` gives it).
        centres: (K, D) float, the visual words (the command's K-medoids).
        binary: ASMK*'s code, sign(V) / sqrt(D) (+1 for a zero component), instead of V.
    Returns:
        (words (m,) int64 ascending, vectors (m, D) float32 of unit L2 norm): per word held, the
        normalised sum of x - c over the frame's descriptors of that word. A word whose residuals sum
        to exactly zero (one descriptor that is the word itself) has no direction and is left out.
    """
    descriptors, words, centres = np.asarray(descriptors), np.asarray(words), np.asarray(centres)
    if descriptors.ndim != 2 or not np.issubdtype(descriptors.dtype, np.floating):
        raise ValueError(f"descriptors: expected (n, D) float descriptors (a residual x - c needs a vector space; "
                         f"binary descriptors have none), got {descriptors.dtype} of shape {descriptors.shape}")
    if centres.ndim != 2 or centres.shape[1] != descriptors.shape[1]:
        raise ValueError(f"centres: expected (K, {descriptors.shape[1]}) words, got shape {centres.shape}")
    if words.shape != (len(descriptors),) or (words.size and (words.min() < -1 or words.max() >= len(centres))):
        raise ValueError(f"words: expected {len(descriptors)} word indices in [-1, {len(centres)}), one per "
                         f"descriptor, got shape {words.shape}")
    keep = words >= 0
    w, x = words[keep].astype(np.int64), descriptors[keep].astype(np.float32)
    if len(w) == 0:
        return np.zeros(0, np.int64), np.zeros((0, descriptors.shape[1]), np.float32)
    order = np.argsort(w, kind="stable")
    w, x = w[order], x[order]
    held, start = np.unique(w, return_index=True)
    sums = np.add.reduceat(x - centres.astype(np.float32)[w], start, axis=0)  # (m, D)
    norm = np.linalg.norm(sums, axis=1)
    held, sums, norm = held[norm > 0], sums[norm > 0], norm[norm > 0]
    if binary:
        vectors = np.where(sums >= 0, 1.0, -1.0).astype(np.float32) / np.float32(np.sqrt(sums.shape[1]))
    else:
        vectors = (sums / norm[:, None]).astype(np.float32)
    return held, vectors


def _by_word(frames: list[Aggregated], n_words: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The entries of `aggregate_residuals` frames sorted by word: (n_words + 1,) start of each word's
    entries, (E,) the frame of each entry, (E, D) its vector."""
    words = np.concatenate([np.asarray(w, np.int64) for w, _ in frames])
    if words.size and (words.min() < 0 or words.max() >= n_words):
        raise ValueError(f"frames: word indices from {words.min()} to {words.max()}, expected [0, {n_words}) "
                         "(one weight per word)")
    owner = np.repeat(np.arange(len(frames)), [len(w) for w, _ in frames])
    vectors = np.concatenate([np.asarray(v, np.float32) for _, v in frames])
    order = np.argsort(words, kind="stable")
    return np.searchsorted(words[order], np.arange(n_words + 1)), owner[order], vectors[order]


def asmk_similarities(queries: list[Aggregated], database: list[Aggregated], weights: np.ndarray,
                      kernels: tuple[tuple[float, float], ...] = ((3.0, 0.0),)) -> np.ndarray:
    """ASMK similarities K(X, Y) (the module's docstring) of Q query frames to N database frames.

    Args:
        queries, database: `aggregate_residuals` of each frame (ASMK's vectors or ASMK*'s codes).
        weights: (n_words,) w_c >= 0 of each word (e.g. `inverse_document_frequency`).
        kernels: (alpha, tau) of each sigma, all computed in one pass over the words.
    Returns:
        (len(kernels), Q, N) float64: 1 for a frame against itself and at most 1 (up to float32
        rounding of the vectors); 0 for frames that share no word of weight > 0.
    """
    weights = np.asarray(weights, np.float64)
    if weights.ndim != 1 or not (np.isfinite(weights) & (weights >= 0)).all():
        raise ValueError(f"weights: expected (n_words,) finite weights >= 0, got shape {weights.shape}")
    if not kernels or any(a <= 0 for a, _ in kernels):
        raise ValueError(f"kernels: expected (alpha, tau) pairs with alpha > 0, got {kernels!r}")
    n_words = len(weights)
    qs, qf, qv = _by_word(queries, n_words)
    ds, df, dv = _by_word(database, n_words)
    if qv.shape[1:] != dv.shape[1:]:
        raise ValueError(f"queries, database: vectors of different lengths {qv.shape[1:]} and {dv.shape[1:]}")
    out = np.zeros((len(kernels), len(queries), len(database)))
    for c in np.flatnonzero((weights > 0) & (np.diff(qs) > 0) & (np.diff(ds) > 0)):
        u = (qv[qs[c]:qs[c + 1]] @ dv[ds[c]:ds[c + 1]].T).astype(np.float64)  # (queries with c, frames with c)
        cells = np.ix_(qf[qs[c]:qs[c + 1]], df[ds[c]:ds[c + 1]])  # one entry per frame and word: no repeats
        for i, (alpha, tau) in enumerate(kernels):
            out[i][cells] += weights[c] * np.where(u > tau, np.sign(u) * np.abs(u) ** alpha, 0.0)
    gamma_q = np.array([weights[np.asarray(w, np.int64)].sum() for w, _ in queries])
    gamma_d = np.array([weights[np.asarray(w, np.int64)].sum() for w, _ in database])
    norm = np.sqrt(gamma_q[:, None] * gamma_d[None, :])
    return np.divide(out, norm, out=np.zeros_like(out), where=norm > 0)


def _vocabulary(sample: np.ndarray, D: np.ndarray, words: int, path: Path):
    """The command's K-medoids vocabulary (seed 0), read from or written to `path` (FasterPAM takes minutes)."""
    from geofeat.apps.retrieval import Vocabulary

    if path.is_file():
        return Vocabulary(np.load(path), "l2")
    vocab = vocabulary(sample, words, seed=0, distances=D)
    np.save(path, vocab.medoids)
    return vocab


def shortlists(db, name: str, queries: np.ndarray, exclude: np.ndarray, word_sizes: list[int], work: Path,
               depth: int = RERANK) -> dict[str, np.ndarray]:
    """{variant: (Q, depth) database indices} of descriptor `name`: the bag of words (tfidf-l1, L1,
    the command's) and every ASMK / ASMK* kernel and weighting, for each vocabulary size."""
    feats = db.features[name]
    ties = tie_keys(db.sequences, db.frames)
    canonical = sorted(range(len(feats)), key=lambda i: db.sequences[i])  # as `evaluate_descriptor`
    sample = sample_descriptors([feats[i] for i in canonical], 10_000, 0)
    D = None
    out, t0 = {}, time.perf_counter()
    for k in word_sizes:
        path = work / f"vocab_{name}_{k}_{zlib.crc32(sample.tobytes()):08x}.npy"  # this sample's words
        if not path.is_file() and D is None:
            D = sample_distances(sample)
        vocab = _vocabulary(sample, D, k, path)
        words = [nearest_words(f, vocab) for f in feats]
        counts = np.stack([np.bincount(w[w >= 0], minlength=k) for w in words])
        vectors = weight_histograms(counts, "tfidf-l1")
        out[f"bow K={k}"] = search(vectors[queries], vectors, depth, exclude=exclude, distance="l1", order=ties)[0]
        for binary in (False, True):
            frames = [aggregate_residuals(np.asarray(f.descriptors), w, vocab.medoids, binary)
                      for f, w in zip(feats, words)]
            present = np.zeros((len(frames), k))
            for i, (w, _) in enumerate(frames):
                present[i, w] = 1
            for weighting, weights in (("", np.ones(k)), (" idf", inverse_document_frequency(present))):
                sims = asmk_similarities([frames[q] for q in queries], frames, weights, KERNELS)
                for (alpha, tau), s in zip(KERNELS, sims):
                    label = f"{'asmk*' if binary else 'asmk'} K={k} a={alpha:g} t={tau:g}{weighting}"
                    out[label] = rank_distances(-s, depth, exclude, ties)[0]
        print(f"{name}: K = {k} done ({time.perf_counter() - t0:.0f} s)", flush=True)
    return out


def verified(db, name: str, queries: np.ndarray, top: np.ndarray, cache: dict, counts_path: Path) -> np.ndarray:
    """(Q, depth) verified matches V of each (query, shortlisted frame), from `cache` or matched (and added)."""
    feats = db.features[name]
    V, new = np.zeros(top.shape), 0
    for row, q in enumerate(queries):
        for col, j in enumerate(top[row]):
            key = (name, int(q), int(j))
            if key not in cache:
                cache[key] = match_counts(feats[q], feats[j])
                new += 1
            V[row, col] = cache[key][1]
        if new >= 500:
            counts_path.write_bytes(pickle.dumps(cache))
            new = 0
    counts_path.write_bytes(pickle.dumps(cache))
    return V


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", type=Path, required=True, help="pickled RetrievalDatabase")
    ap.add_argument("--counts", type=Path, required=True, help="pickle of each pair's (M, V) (read and extended)")
    ap.add_argument("--words", default="256,1024,2560", help="vocabulary sizes, comma-separated")
    ap.add_argument("--work", type=Path, default=Path("/tmp"), help="folder for the cached vocabularies")
    ap.add_argument("--rerank", default="auto",
                    help="variants to re-rank, ';'-separated, or 'auto': the bag of words at the largest K and, of "
                         "ASMK and of ASMK*, the variant with the best validation sum of the words alone")
    ap.add_argument("--save", type=Path, help="pickle of every shortlist and re-ranked list (written at the end)")
    ap.add_argument("--lists", type=Path, help="the shortlists of an earlier run's --save, instead of computing them")
    args = ap.parse_args()
    db = pickle.loads(args.cache.read_bytes())
    classes = np.asarray(db.classes)
    queries, exclude, _ = eligible_queries(db)
    val, test = split_queries(len(queries), 0, groups=classes[queries])
    relevant = (classes[queries][:, None] == classes[None, :]) & ~exclude  # (Q, N)
    sizes = [int(k) for k in args.words.split(",")]
    if args.lists:
        lists = pickle.loads(args.lists.read_bytes())["lists"]
    else:
        lists = {name: shortlists(db, name, queries, exclude, sizes, args.work) for name in NAMES}

    def scores(top: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Per descriptor: (Q,) mean Acc@1-10 of its (Q, >= 10) results."""
        return {n: per_query_accuracy(t[:, :10], db.classes, classes[queries]).mean(axis=1) for n, t in top.items()}

    def row(label: str, acc: dict[str, np.ndarray], extra: str = "") -> str:
        a, b = acc[NAMES[0]], acc[NAMES[1]]
        p = paired_halves(a, b, val, test)
        return (f"| {label} | {a.mean():.3f} / {b.mean():.3f} | {p['diff']:+.3f} [{p['low']:+.2f}, {p['high']:+.2f}] | "
                f"{a[val].mean():.3f} / {b[val].mean():.3f} | {p['val_sum']:.3f} |{extra}")

    print(f"\n{len(queries)} queries ({len(val)} validation, {len(test)} test); mean Acc@1-10 over all queries, "
          f"GeoPatch / SIFT; relevant frames per query {relevant.sum(1).mean():.1f}")
    print("\nwords alone:\n| variant | GeoPatch / SIFT | difference [95 %] | validation half | validation sum | "
          "relevant in the best 80, GeoPatch / SIFT |\n|---|---|---|---|---|---|")
    words_alone = {}
    for variant in lists[NAMES[0]]:
        acc = scores({n: lists[n][variant] for n in NAMES})
        words_alone[variant] = paired_halves(acc[NAMES[0]], acc[NAMES[1]], val, test)["val_sum"]
        held = [np.take_along_axis(relevant, lists[n][variant], axis=1).sum(1).mean() for n in NAMES]
        print(row(variant, acc, f" {held[0]:.2f} / {held[1]:.2f} |"), flush=True)
    if args.rerank == "auto":
        chosen = [f"bow K={max(sizes)}"]
        for kind in ("asmk ", "asmk* "):
            chosen.append(max((v for v in words_alone if v.startswith(kind)), key=words_alone.get))
    else:
        chosen = args.rerank.split(";")
    cache = pickle.loads(args.counts.read_bytes()) if args.counts.exists() else {}
    print("\nthe best 80 re-ranked by verified matches:\n| variant | GeoPatch / SIFT | difference [95 %] | "
          "validation half, GeoPatch / SIFT | validation sum |\n|---|---|---|---|---|", flush=True)
    reranked = {}
    for variant in chosen:
        top = {}
        for n in NAMES:
            t = lists[n][variant]
            V = verified(db, n, queries, t, cache, args.counts)
            top[n] = np.take_along_axis(t, np.argsort(-V, axis=1, kind="stable"), axis=1)
        reranked[variant] = top
        print(row(variant, scores(top)), flush=True)
    if args.save:
        args.save.write_bytes(pickle.dumps(dict(queries=queries, val=val, test=test, lists=lists, reranked=reranked)))


if __name__ == "__main__":
    main()
