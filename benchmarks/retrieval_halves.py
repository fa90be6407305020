"""Two checks of a `geofeat retrieval` result on `make_retrieval_set.py`'s set, on frames cached by
`retrieval_weightings.py --cache`:

1. per-query mean Acc@1-10 of each descriptor with a fixed K and weighting, on the test half, the
   validation half and all queries (`split_queries(..., 0)`, as the command), and the paired
   difference of the first descriptor minus each other one with a 95 % bootstrap interval;
2. of the wrong results in each query's top 10, the share from an object whose texture is of the
   query's procedural fabric family (`geofeat.sim.fabric_texture`'s `kind`, redrawn from the set's
   texture seeds), against the share of such frames among those the query may return;
3. with `--by-scenario SET_DIR`, the paired difference over all queries grouped by the simulator's scenario
   and preset of the query's sequence (its groundtruth.json).

    python benchmarks/retrieval_halves.py --cache /tmp/db_gp_sift.pkl --descriptors geopatch,sift --words 2560
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import numpy as np

from common import simulated_as
from geofeat.apps.retrieval import (
    DEFAULT_WEIGHTING, N_VOCABULARY_SAMPLES, bootstrap_interval, eligible_queries, evaluate_descriptor, split_queries,
)
from geofeat.sim.textures import FABRIC_KINDS



def fabric_families(classes: list[str], objects: int, seed: int) -> dict[str, str]:
    """{class: fabric family} of `make_retrieval_set.py`'s classes (object-II, distractor-JJ): texture
    i (objects first, then distractors) is `fabric_texture(default_rng(seed + 7919 (i + 1)))`, whose
    first draw picks the family."""
    out = {}
    for c in sorted(set(classes)):
        kind, num = c.rsplit("-", 1)
        i = int(num) + (objects if kind == "distractor" else 0)
        rng = np.random.default_rng(seed + 7919 * (i + 1))
        out[c] = FABRIC_KINDS[int(rng.integers(len(FABRIC_KINDS)))]
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cache", type=Path, required=True, action="append", help="pickle(s) of described frames")
    p.add_argument("--descriptors", default="geopatch,sift")
    p.add_argument("--words", type=int, default=2560)
    p.add_argument("--weighting", default=DEFAULT_WEIGHTING)
    p.add_argument("--samples", type=int, default=N_VOCABULARY_SAMPLES,
                   help=f"descriptors sampled for the vocabulary (default {N_VOCABULARY_SAMPLES}; more than --words)")
    p.add_argument("--rerank", type=int, default=0,
                   help="results re-ranked by verified matches (default 0: the words' order, as the figures in "
                        "BENCHMARKS.md that this script made before `geofeat retrieval` re-ranked)")
    p.add_argument("--objects", type=int, default=20, help="make_retrieval_set.py --objects")
    p.add_argument("--set-seed", type=int, default=5000, help="make_retrieval_set.py --seed")
    p.add_argument("--by-scenario", type=Path, metavar="SET_DIR",
                   help="also the paired difference by the query sequence's scenario and preset, read from "
                        "SET_DIR/<sequence>/groundtruth.json (the set the cache was described from)")
    args = p.parse_args()
    names = [d for d in args.descriptors.split(",") if d]
    dbs = []
    for path in args.cache:
        with open(path, "rb") as fh:
            dbs.append(pickle.load(fh))
    per_query, first, query_index = {}, None, None
    for name in names:
        db = next((d for d in dbs if name in d.features), None)
        if db is None:
            raise SystemExit(f"--descriptors: {name} is in no --cache")
        first = first or db
        if db.sequences != first.sequences or db.frames != first.frames:
            raise SystemExit("--cache: the pickles hold different frames")
        queries, exclude, _ = eligible_queries(db)
        query_index = queries
        r = evaluate_descriptor(db.features[name], db, queries, exclude, words=args.words, weighting=args.weighting,
                                rerank_top=args.rerank, n_samples=args.samples)
        per_query[name] = r.per_query.mean(axis=1)  # (Q,) all queries: K is given
        cls = np.asarray(db.classes)
        family = fabric_families(db.classes, args.objects, args.set_seed)
        fam = np.array([family[c] for c in cls])  # (N,)
        if name == names[0]:
            mates = [any(family[c] == family[cls[q]] for c in family if c != cls[q]) for q in queries]
            print(f"{len(set(family.values()))} fabric families among {len(family)} classes; {sum(mates)} of "
                  f"{len(queries)} queries have another class of their family")
        wrong = cls[r.neighbours] != cls[r.queries][:, None]  # (Q, 10)
        same = fam[r.neighbours] == fam[r.queries][:, None]
        other = ~exclude & (cls[None, :] != cls[queries][:, None])  # (Q, N) frames of other classes it may return
        chance = ((fam[None, :] == fam[queries][:, None]) & other).sum(1) / other.sum(1)
        print(f"{name}: wrong results in the top 10: {wrong.sum()} ({wrong.mean():.1%}); of them of the query's "
              f"fabric family {(wrong & same).sum() / max(wrong.sum(), 1):.2f} (chance {chance.mean():.3f})")
    val, test = split_queries(len(per_query[names[0]]), 0, groups=cls[queries])
    for label, idx in (("test half", test), ("validation half", val), ("all", np.arange(len(per_query[names[0]])))):
        cells = ", ".join(f"{n} {per_query[n][idx].mean():.3f}" for n in names)
        diffs = []
        for other_name in names[1:]:
            d = per_query[names[0]][idx] - per_query[other_name][idx]
            lo, hi = bootstrap_interval(d[:, None])
            diffs.append(f"{names[0]} - {other_name} {d.mean():+.3f} [{lo[0]:+.2f}, {hi[0]:+.2f}]")
        print(f"{label} ({len(idx)} queries): {cells}; " + "; ".join(diffs))
    if args.by_scenario:
        print_by_scenario(first, query_index, per_query, names, args.by_scenario)


def print_by_scenario(db, queries: np.ndarray, per_query: dict, names: list[str], set_dir: Path) -> None:
    """The paired difference of the first descriptor minus each other one, per (scenario, preset) of
    the query's sequence, over all queries (95 % bootstrap intervals)."""
    groups = np.array([simulated_as(set_dir / db.sequences[q], ("scenario", "preset")) or "?" for q in queries])
    print("| query's scenario, preset | queries | " + " | ".join(names) + " | "
          + " | ".join(f"{names[0]} - {o}" for o in names[1:]) + " |")
    print("|---|---|" + "---|" * (2 * len(names) - 1))
    for g in sorted(set(groups)):
        idx = np.flatnonzero(groups == g)
        cells = [f"{per_query[n][idx].mean():.3f}" for n in names]
        for other in names[1:]:
            d = per_query[names[0]][idx] - per_query[other][idx]
            lo, hi = bootstrap_interval(d[:, None])
            cells.append(f"{d.mean():+.3f} [{lo[0]:+.2f}, {hi[0]:+.2f}]")
        print(f"| {g} | {len(idx)} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
