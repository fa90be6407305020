"""Word weightings x vocabulary sizes for `geofeat retrieval`, on described frames cached once.

For each descriptor and vocabulary seed, the vocabulary of every K in --words is built once
(`vocabulary` on the same 10,000 sampled descriptors as `evaluate_descriptor`), every frame's word
counts are computed once, and every weighting of `WEIGHTINGS` is scored: mean Acc@1-10 on the
validation and on the test half of the queries (`split_queries(..., seed=0)`, as the command). Then
per weighting and candidate list, K is chosen on the validation half only, and both halves' scores
of that K are printed (the test score is never used to choose anything).

    # describe once (minutes), then every run reads the cache (seconds to minutes)
    python benchmarks/retrieval_weightings.py out/retrieval_set --classes out/retrieval_set/classes.csv \\
        --descriptors geopatch,sift --cache /tmp/retrieval_db.pkl --out /tmp/weightings.json
"""

from __future__ import annotations

import argparse
import json
import pickle
from pathlib import Path

import numpy as np

from geofeat.apps.retrieval import (
    N_VOCABULARY_SAMPLES, WEIGHTINGS, WORD_CANDIDATES, RetrievalDatabase, describe_datasets, eligible_queries,
    per_query_accuracy, read_classes, sample_descriptors, sample_distances, search, split_queries, vocabulary,
    weight_histograms, word_counts,
)


def load_or_describe(datasets: list[str], classes: str | None, descriptors: tuple[str, ...], cache: Path | None
                     ) -> RetrievalDatabase:
    """The described database: read from `cache` if it exists (and holds `descriptors`), else
    described (`describe_datasets`, SIFT keypoints) and written there."""
    if cache is not None and cache.is_file():
        with open(cache, "rb") as fh:
            db = pickle.load(fh)
        missing = [d for d in descriptors if d not in db.features]
        if missing:
            raise SystemExit(f"--cache {cache}: no {', '.join(missing)} in it (it has {', '.join(db.features)})")
        return db
    db = describe_datasets(datasets, descriptors, classes=read_classes(classes) if classes else None)
    if cache is not None:
        with open(cache, "wb") as fh:
            pickle.dump(db, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return db


def score(db: RetrievalDatabase, name: str, words: list[int], seed: int, n_samples: int) -> list[dict]:
    """One row per (K, weighting): mean Acc@1-10 on the validation and the test half."""
    queries, exclude, _ = eligible_queries(db)
    val, test = split_queries(len(queries), 0, groups=np.asarray(db.classes)[queries])
    features = db.features[name]
    sample = sample_descriptors(features, n_samples, seed)
    D = sample_distances(sample)
    rows = []
    for k in (k for k in words if k < len(sample)):
        vocab = vocabulary(sample, k, seed=seed, distances=D)
        counts = np.stack([word_counts(f, vocab) for f in features])  # (N, K)
        for weighting, distance in WEIGHTINGS.items():
            vectors = weight_histograms(counts, weighting)
            neighbours, _ = search(vectors[queries], vectors, 10, exclude=exclude, distance=distance)
            acc = per_query_accuracy(neighbours, db.classes, np.asarray(db.classes)[queries])  # (Q, 10)
            rows.append(dict(descriptor=name, seed=seed, words=k, weighting=weighting,
                             validation=float(acc[val].mean()), test=float(acc[test].mean())))
            print(f"{name} seed {seed} K={k:5d} {weighting:11s} validation {rows[-1]['validation']:.3f} "
                  f"test {rows[-1]['test']:.3f}", flush=True)
    return rows


def table(rows: list[dict], candidates: tuple[int, ...]) -> str:
    """Markdown: per weighting and descriptor, K chosen on validation among `candidates` (ties:
    the smaller K), mean over seeds of its validation and test scores, and the weighting's sum of
    validation scores over descriptors."""
    descriptors = list(dict.fromkeys(r["descriptor"] for r in rows))
    seeds = sorted({r["seed"] for r in rows})
    lines = ["| weighting | " + " | ".join(f"{d}: K, validation, test" for d in descriptors) + " | validation sum |",
             "|---" * (len(descriptors) + 2) + "|"]
    for weighting in WEIGHTINGS:
        cells, total = [], 0.0
        for d in descriptors:
            ks, vs, ts = [], [], []
            for s in seeds:
                by_k = {r["words"]: r for r in rows if (r["descriptor"], r["seed"], r["weighting"]) == (d, s, weighting)
                        and r["words"] in candidates}
                if not by_k:
                    continue
                best = max(sorted(by_k), key=lambda k: (by_k[k]["validation"], -k))
                ks.append(best), vs.append(by_k[best]["validation"]), ts.append(by_k[best]["test"])
            cells.append(f"{'/'.join(map(str, ks))}, {np.mean(vs):.3f}, {np.mean(ts):.3f}" if ks else "-")
            total += float(np.mean(vs)) if vs else 0.0
        lines.append(f"| {weighting} | " + " | ".join(cells) + f" | {total:.3f} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("datasets", nargs="+")
    p.add_argument("--classes", default=None)
    p.add_argument("--descriptors", default="geopatch,sift")
    p.add_argument("--words", default=",".join(map(str, WORD_CANDIDATES)))
    p.add_argument("--seeds", default="0", help="vocabulary seeds (sample and FasterPAM), comma-separated")
    p.add_argument("--samples", type=int, default=N_VOCABULARY_SAMPLES)
    p.add_argument("--cache", type=Path, default=None, help="pickle of the described frames (read, or written)")
    p.add_argument("--out", type=Path, default=None, help="JSON of every (descriptor, seed, K, weighting) score")
    args = p.parse_args()
    names = tuple(d for d in args.descriptors.split(",") if d)
    words = sorted(int(k) for k in args.words.split(","))
    db = load_or_describe(args.datasets, args.classes, names, args.cache)
    rows = [r for name in names for s in args.seeds.split(",") for r in score(db, name, words, int(s), args.samples)]
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))
    for top in sorted({k for k in (80, 1280, words[-1]) if k <= words[-1]}):
        print(f"\nK chosen on validation among {', '.join(str(k) for k in words if k <= top)} "
              "(mean over seeds of the chosen K's scores):\n")
        print(table(rows, tuple(k for k in words if k <= top)))


if __name__ == "__main__":
    main()
