"""Re-ranking variants for `geofeat retrieval`, on frames cached by `retrieval_weightings.py --cache`.

For each descriptor: the words' top `--depth` results per query (K words, `tfidf-l1`, vocabulary seed
0, as the command), then re-ranked by five scores of a (query, frame) pair, over the best 10 / 20 /
`--depth` of them: the number of mutual nearest-neighbour matches, with Lowe's ratio test 0.8 or 0.9
or none, each with and without the local affine check (`geofeat.apps.retrieval.verified_matches`
is "ratio 0.9, verified"). Prints mean Acc@1-10 on the validation half, the test half and all
queries (`split_queries(..., 0)`, the command's split).

    python benchmarks/retrieval_rerank.py --cache /tmp/big2.pkl --descriptors geopatch,sift --words 2560
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from common import cached_retrieval, word_shortlist
from tqdm import tqdm

from geofeat.apps.retrieval import match_counts, per_query_accuracy

RATIOS = {"mutual": None, "ratio 0.9": 0.9, "ratio 0.8": 0.8}


def pair_scores(fq, fc) -> dict[str, int]:
    """{score name: count} for one (query, frame) pair."""
    out = {}
    for name, ratio in RATIOS.items():
        out[name], out[name + ", verified"] = match_counts(fq, fc, ratio)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cache", type=Path, required=True, help="pickle of the described frames")
    p.add_argument("--descriptors", default="geopatch,sift")
    p.add_argument("--words", type=int, default=2560)
    p.add_argument("--weighting", default="tfidf-l1")
    p.add_argument("--depth", type=int, default=40, help="results per query scored (default 40)")
    args = p.parse_args()
    db, queries, exclude, val, test, classes = cached_retrieval(args.cache)
    for name in [d for d in args.descriptors.split(",") if d]:
        feats = db.features[name]
        nb = word_shortlist(feats, queries, exclude, args.words, args.depth, args.weighting)
        t0 = time.perf_counter()
        scores = [[pair_scores(feats[q], feats[c]) for c in row]
                  for q, row in tqdm(zip(queries, nb), total=len(queries), desc=f"{name}: pairs", unit="query")]
        print(f"{name}: {nb.size} pairs scored in {time.perf_counter() - t0:.0f} s")
        words = per_query_accuracy(nb[:, :10], db.classes, classes[queries]).mean(axis=1)
        print(f"| {name} | words only | | {words[val].mean():.3f} | {words[test].mean():.3f} | {words.mean():.3f} |")
        for score in scores[0][0]:
            counts = np.array([[s[score] for s in row] for row in scores])
            for top in sorted({10, 20, args.depth}):
                order = np.argsort(-counts[:, :top], axis=1, kind="stable")
                ranked = np.concatenate([np.take_along_axis(nb[:, :top], order, axis=1), nb[:, top:]], axis=1)
                acc = per_query_accuracy(ranked[:, :10], db.classes, classes[queries]).mean(axis=1)
                print(f"| {name} | {score} | {top} | {acc[val].mean():.3f} | {acc[test].mean():.3f} | {acc.mean():.3f} |")


if __name__ == "__main__":
    main()
