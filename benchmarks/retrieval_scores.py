"""How `geofeat retrieval` orders the re-ranked results: other scores than the verified-match count (issue 23).

`geofeat retrieval` reorders each query's best `RERANK` (80) frames by the words by their verified
matches (`apps.retrieval.match_counts`: mutual nearest neighbours passing the ratio test, confirmed by
their neighbours' local affine map). This script keeps, for each (query, frame) of those 80, the
matches M, the verified matches V and the words' L1 distance d (tfidf-l1 vectors, in [0, 2]), and
orders the 80 by other scores: V over M (verified share), V plus a share of the words' similarity
1 - d / 2, V above a floor and then the words' order. One rule for both descriptors, judged on the
validation half's sum (`split_queries`, by object); the difference GeoPatch - SIFT over all queries
with its 95 % bootstrap interval.

    python benchmarks/retrieval_scores.py out/retrieval_set --cache DB.pkl --counts COUNTS.pkl

SET is a `make_retrieval_set.py` folder (its classes.csv is read); `--cache` holds the described frames
(written on the first run: GeoPatch on GeoKey's keypoints, SIFT on SIFT's, 2048 each, as the command
does; about 25 minutes for 1200 frames on 2 cores); `--counts` the (M, V) of each pair (written as it
goes: about 17 minutes for 180 queries x 80 frames x 2 descriptors).
"""

from __future__ import annotations

import argparse
import pickle
import time
from pathlib import Path

import numpy as np

from common import paired_halves
from geofeat.apps.retrieval import (
    RERANK, describe_datasets, eligible_queries, match_counts, per_query_accuracy, read_classes,
    sample_descriptors, sample_distances, search, split_queries, tie_keys, vocabulary, weight_histograms, word_counts,
)

NAMES = ("geopatch", "sift")


def described(folder: Path, cache: Path):
    """The `RetrievalDatabase` of `folder`, read from `cache` or described and written there."""
    if cache.is_file():
        return pickle.loads(cache.read_bytes())
    db = describe_datasets([folder], NAMES, classes=read_classes(folder / "classes.csv"))
    cache.write_bytes(pickle.dumps(db))
    return db


def pair_counts(db, counts_path: Path, words: int) -> dict[str, dict[str, np.ndarray]]:
    """Per descriptor: the queries, their best `RERANK` frames by the words (Q, 80), the words' L1
    distances, and the matches M and verified matches V of each (query, frame)."""
    cache = pickle.loads(counts_path.read_bytes()) if counts_path.exists() else {}
    out, t0 = {}, time.perf_counter()
    for name in NAMES:
        feats = db.features[name]
        queries, exclude, _ = eligible_queries(db)
        canonical = sorted(range(len(feats)), key=lambda i: db.sequences[i])  # as `evaluate_descriptor`
        sample = sample_descriptors([feats[i] for i in canonical], 10_000, 0)
        vocab = vocabulary(sample, words, seed=0, distances=sample_distances(sample))
        vectors = weight_histograms(np.stack([word_counts(f, vocab) for f in feats]), "tfidf-l1")
        top, dist = search(vectors[queries], vectors, RERANK, exclude=exclude, distance="l1",
                           order=tie_keys(db.sequences, db.frames))
        M, V = np.zeros(top.shape), np.zeros(top.shape)
        for row, q in enumerate(queries):
            for col, j in enumerate(top[row]):
                key = (name, int(q), int(j))
                if key not in cache:
                    cache[key] = match_counts(feats[q], feats[j])
                M[row, col], V[row, col] = cache[key]
            if row % 30 == 29 or row == len(queries) - 1:
                counts_path.write_bytes(pickle.dumps(cache))
                print(f"{name}: {row + 1} of {len(queries)} queries ({time.perf_counter() - t0:.0f} s)", flush=True)
        out[name] = dict(queries=queries, top=top, d=dist, M=M, V=V)
    return out


def rules() -> dict[str, callable]:
    """Score of each of a query's 80 frames (higher first; ties keep the words' order)."""
    rank = lambda p: -np.broadcast_to(np.arange(p["top"].shape[1], dtype=float), p["top"].shape)  # noqa: E731
    out = {"words alone": rank, "V (the command's)": lambda p: p["V"]}
    for c in (2, 10, 20):
        out[f"V / (M + {c})"] = (lambda c: lambda p: p["V"] / (p["M"] + c))(c)
    out["V / sqrt(M + 1)"] = lambda p: p["V"] / np.sqrt(p["M"] + 1)
    for b in (1, 3, 10, 30):
        out[f"V + {b} x (1 - d / 2)"] = (lambda b: lambda p: p["V"] + b * (1 - p["d"] / 2))(b)
    for b in (1, 2):
        out[f"log(1 + V) + {b} x (1 - d / 2)"] = (lambda b: lambda p: np.log1p(p["V"]) + b * (1 - p["d"] / 2))(b)
    for t in (2, 3, 5, 8):
        out[f"V >= {t} first, then the words"] = (lambda t: lambda p: 1000.0 * (p["V"] >= t) + rank(p))(t)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("set", type=Path, help="a make_retrieval_set.py folder")
    ap.add_argument("--cache", type=Path, required=True, help="pickle of the described frames (read, or written)")
    ap.add_argument("--counts", type=Path, required=True, help="pickle of each pair's (M, V) (read and extended)")
    ap.add_argument("--words", type=int, default=2560)
    args = ap.parse_args()
    db = described(args.set, args.cache)
    data = pair_counts(db, args.counts, args.words)
    classes = np.asarray(db.classes)
    queries = data[NAMES[0]]["queries"]
    val, test = split_queries(len(queries), 0, groups=classes[queries])
    print(f"{len(queries)} queries ({len(val)} validation, {len(test)} test); mean Acc@1-10, validation / test / all")
    print("| score | GeoPatch | SIFT | GeoPatch - SIFT, all [95 %] | validation | test | validation sum |")
    print("|---|---|---|---|---|---|---|")
    for rule, score in rules().items():
        acc = {}
        for name in NAMES:
            p = data[name]
            order = np.argsort(-score(p), axis=1, kind="stable")
            top10 = np.take_along_axis(p["top"], order, axis=1)[:, :10]
            acc[name] = per_query_accuracy(top10, db.classes, classes[p["queries"]]).mean(axis=1)
        a, b = acc[NAMES[0]], acc[NAMES[1]]
        p = paired_halves(a, b, val, test)
        print(f"| {rule} | {a[val].mean():.3f} / {a[test].mean():.3f} / {a.mean():.3f} | {b[val].mean():.3f} / "
              f"{b[test].mean():.3f} / {b.mean():.3f} | {p['diff']:+.3f} [{p['low']:+.2f}, {p['high']:+.2f}] | "
              f"{p['val']:+.3f} | {p['test']:+.3f} | {p['val_sum']:.3f} |")


if __name__ == "__main__":
    main()
