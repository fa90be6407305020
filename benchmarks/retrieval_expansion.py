"""Re-ranking deeper, and query expansion after verification, on a cached retrieval set (issue 23).

`geofeat retrieval` reorders each query's best `RERANK` (80) results by the words by their verified
matches (`apps.retrieval.match_counts`). Two ways to reach relevant frames that the words rank lower:

- `deepD`: reorder the words' best D results instead of 80 (D / 80 times the matching);
- `aqeMcC`: average query expansion (Chum et al., ICCV 2007) after the verification: the query's
  word vector plus those of its best M re-ranked results with at least C verified matches,
  L1-normalised, searches again; the union of both result lists is verified and sorted by verified
  matches.

Frames come from the pickles that `retrieval_weightings.py --cache` writes (one per descriptor set, as
`retrieval_halves.py` reads them); K is fixed (`--words`, `tfidf-l1`, vocabulary seed 0, as the command
chooses on these sets). Verified-match counts are kept in `--counts` (a pickle, read and extended), so
that variants share the matching. Prints mean Acc@1-10 over all eligible queries per descriptor and
variant, and the paired difference of the first descriptor minus the second, over all queries and
over the validation and test halves of `split_queries` (by object).

    python benchmarks/retrieval_expansion.py --cache GEOKEY.pkl --cache SIFT.pkl --counts C.pkl \\
        --descriptors geopatch@geokey,sift --variants base,deep160,aqe3c20
"""

from __future__ import annotations

import argparse
import pickle
import time
from pathlib import Path

import numpy as np

from common import paired_halves
from geofeat.apps.retrieval import (
    RERANK, eligible_queries, match_counts, per_query_accuracy, sample_descriptors,
    sample_distances, search, split_queries, tie_keys, vocabulary, weight_histograms, word_counts,
)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cache", action="append", required=True, type=Path, help="pickle(s) of described frames")
    p.add_argument("--descriptors", default="geopatch@geokey,sift", help="two names in the caches")
    p.add_argument("--words", type=int, default=2560)
    p.add_argument("--counts", required=True, type=Path, help="pickle of verified-match counts (read and extended)")
    p.add_argument("--variants", default="base,deep160,aqe3c20")
    args = p.parse_args()
    names = args.descriptors.split(",")
    variants = args.variants.split(",")
    depth = max([RERANK] + [int(v[4:]) for v in variants if v.startswith("deep")])
    dbs = []
    for path in args.cache:
        with open(path, "rb") as fh:
            dbs.append(pickle.load(fh))
    cache = pickle.loads(args.counts.read_bytes()) if args.counts.exists() else {}
    t0 = time.perf_counter()
    per_query = {}
    for name in names:
        db = next(d for d in dbs if name in d.features)
        feats = db.features[name]

        def verified(q: int, j: int) -> int:
            key = (name, int(q), int(j))
            if key not in cache:
                cache[key] = match_counts(feats[q], feats[j])[1]
            return cache[key]

        queries, exclude, _ = eligible_queries(db)
        canonical = sorted(range(len(feats)), key=lambda i: db.sequences[i])  # as `evaluate_descriptor`
        sample = sample_descriptors([feats[i] for i in canonical], 10_000, 0)
        vocab = vocabulary(sample, args.words, seed=0, distances=sample_distances(sample))
        vectors = weight_histograms(np.stack([word_counts(f, vocab) for f in feats]), "tfidf-l1")
        ties = tie_keys(db.sequences, db.frames)
        words, _ = search(vectors[queries], vectors, depth, exclude=exclude, distance="l1", order=ties)
        cls = np.asarray(db.classes)
        for variant in variants:
            top10 = np.zeros((len(queries), 10), np.int64)
            matched = 0
            for row, q in enumerate(queries):
                top = int(variant[4:]) if variant.startswith("deep") else RERANK
                pool = words[row, :top]
                if variant.startswith("aqe"):
                    m, c_min = (int(x) for x in variant[3:].split("c"))
                    counts = np.array([verified(q, j) for j in pool])
                    order = np.argsort(-counts, kind="stable")
                    best = pool[order[:m]][counts[order[:m]] >= c_min]
                    if len(best):
                        v = vectors[q] + vectors[best].sum(axis=0)
                        again, _ = search((v / np.abs(v).sum())[None], vectors, RERANK, exclude=exclude[row:row + 1],
                                          distance="l1", order=ties)
                        pool = np.array(list(dict.fromkeys(list(again[0]) + list(pool))))
                counts = np.array([verified(q, j) for j in pool])
                matched += len(pool)
                top10[row] = pool[np.argsort(-counts, kind="stable")][:10]
            acc = per_query_accuracy(top10, db.classes, cls[queries]).mean(axis=1)
            per_query[(name, variant)] = acc
            print(f"{name} {variant}: mean Acc@1-10 {acc.mean():.3f}, frames verified per query "
                  f"{matched / len(queries):.0f} ({time.perf_counter() - t0:.0f} s)", flush=True)
            args.counts.write_bytes(pickle.dumps(cache))
    val, test = split_queries(len(queries), 0, groups=cls[queries])
    for variant in variants:
        a, b = per_query[(names[0], variant)], per_query[(names[1], variant)]
        p = paired_halves(a, b, val, test)
        print(f"{variant}: {names[0]} {a.mean():.3f}, {names[1]} {b.mean():.3f}; difference, all "
              f"{p['diff']:+.3f} [{p['low']:+.2f}, {p['high']:+.2f}], validation half {p['val']:+.3f}, test half "
              f"{p['test']:+.3f}; validation sum of both {p['val_sum']:.3f}")


if __name__ == "__main__":
    main()
