"""`geofeat retrieval`: object retrieval with a bag of visual words (Acc@K)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..apps.retrieval import DEFAULT_WEIGHTING, RERANK, WEIGHTINGS, WORD_CANDIDATES
from ..outputs import plural
from .common import check_devices
from .options import app_options, device_option, names, whole_number


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `retrieval` to an argparse subparsers object; returns its parser."""
    p = subparsers.add_parser("retrieval", help="object retrieval with a bag of visual words (Acc@K)")
    p.add_argument("datasets", nargs="+", help="sequence folders, or folders of sequences")
    app_options(p)
    p.add_argument("--words", type=whole_number(2), default=None,
                   help="visual words K (default: chosen per descriptor among "
                        f"{','.join(map(str, WORD_CANDIDATES))} (those below --samples) by validation on the queries "
                        "of a random half of the classes; Acc@K is then reported on the other half's queries, so that "
                        "no test query's object informs K; queries of a single class are split one by one, and "
                        "retrieval.md warns)")
    p.add_argument("--weighting", choices=tuple(WEIGHTINGS), default=DEFAULT_WEIGHTING,
                   help="word weighting and distance: none (L1-normalised histograms, L2: the paper's), hellinger "
                        "(square roots, L2), tfidf (tf-idf, cosine), tfidf-sqrt (square-root tf times idf, cosine), "
                        "tfidf-l1 (tf-idf, L1-normalised, L1 distance); idf from the database frames "
                        f"(default {DEFAULT_WEIGHTING})")
    p.add_argument("--rerank", type=whole_number(0), default=RERANK, metavar="N",
                   help="reorder each query's best N results by the words by verified matches (mutual nearest "
                        "neighbours passing the ratio test that their neighbours' local affine map confirms); 0 keeps "
                        f"the words' order, the paper's setting (default {RERANK})")
    p.add_argument("--include-own-sequence", action="store_true",
                   help="the database also holds the query's own sequence (default: only the other sequences, "
                        "the paper's setting)")
    p.add_argument("--samples", type=whole_number(1), default=10000, help="descriptors sampled for the vocabulary (default 10000)")
    p.add_argument("--classes", default=None, help="CSV 'sequence,class' (default: class = sequence folder name)")
    p.add_argument("--seed", type=whole_number(0, 2**32 - 1), default=0, help="random seed (default 0)")
    device_option(p, ", and its matching for --rerank,", "; the other descriptors, the vocabulary and the words on "
                  "the CPU")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Object retrieval on the datasets; writes retrieval.csv/md, acc_at_k.png, top6.png."""
    from ..apps.retrieval import RESULT_FILES, check_samples, run_retrieval
    from ..io import find_sequences
    from ..outputs import check_out_dir

    # before any work, after the refusal of a non-empty --out (which `run_retrieval` repeats): a
    # sample no larger than K, in the words of the flags
    check_out_dir(args.out, args.overwrite, files=RESULT_FILES,
                  inputs=[*args.datasets, *find_sequences(args.datasets, unique_names=True), args.tps_dir])
    check_samples(args.samples, args.words, "--samples", "--words")
    device = check_devices(args.device, names(args.descriptors))
    acc, db = run_retrieval(args.datasets, args.out, names(args.descriptors),
                            words=args.words, n_samples=args.samples, seed=args.seed, classes_file=args.classes,
                            n_keypoints=args.keypoints, tps_dir=args.tps_dir, radius=args.radius,
                            depth_scale=args.depth_scale, include_own_sequence=args.include_own_sequence,
                            overwrite=args.overwrite, detector=args.detector,
                            weighting=args.weighting, rerank_top=args.rerank, device=device)
    out = Path(args.out)
    print((out / "retrieval.md").read_text(encoding="utf-8"))
    print(f"wrote {', '.join(str(out / name) for name in RESULT_FILES)}")
    if db.skipped:
        print(f"{plural(len(db.skipped), 'frame')} SKIPPED: {', '.join(db.skipped)}", file=sys.stderr)
    return 1 if db.skipped else 0
