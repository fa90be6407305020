"""Shared helpers of the benchmark scripts."""

from __future__ import annotations

import os
import time


def busy_cpu_seconds(stat_path: str = "/proc/stat") -> float | None:
    """CPU seconds that all processes on this machine have spent busy since boot (Linux's /proc/stat:
    user, nice, system, irq, softirq and steal time of all cores), or None where it cannot be read.
    Its change over a timed block, less this process's CPU time, is what other processes (and the
    hypervisor, as steal) took from the cores meanwhile (`others_cores`)."""
    try:
        with open(stat_path) as fh:
            fields = fh.readline().split()
    except OSError:
        return None
    if not fields or fields[0] != "cpu":
        return None
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(v) for v in fields[1:9])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def others_cores(busy_before: float | None, busy_after: float | None, own_cpu_s: float, wall_s: float) -> float:
    """Cores' worth of CPU that other processes used during a block of `wall_s` seconds in which this
    process used `own_cpu_s` CPU seconds (NaN when /proc/stat could not be read). /proc/stat counts in
    clock ticks (10 ms), so a block should last a few hundred milliseconds for this to mean much."""
    if busy_before is None or busy_after is None or wall_s <= 0:
        return float("nan")
    return max(0.0, (busy_after - busy_before) - own_cpu_s) / wall_s


def wall_times(fn, repeat: int = 5, warm: int = 0) -> list[float]:
    """Wall times of `repeat` calls of fn() after `warm` untimed calls, seconds."""
    for _ in range(warm):
        fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return times


def best_of(fn, repeat: int = 5) -> float:
    """Best wall time of `repeat` calls of fn(), seconds."""
    return min(wall_times(fn, repeat))


def roll_pair_scores(f0, f1, A, describe, detector: str, n: int, tolerance_px: float = 3.0) -> list[float]:
    """One frame against its roll (`geofeat.frame.roll_camera`: f1 and the (2, 3) affine map A of
    f0's pixels onto f1's): keypoints from `detector` (n per frame), descriptors from `describe`
    (frame, keypoints) -> Features, nearest-neighbour matches. Returns [MS, correct matches (within
    `tolerance_px` of the truth), keypoints in f0, keypoints in f1]; the MS divides the correct
    matches by min(keypoints of f0 that land inside f1, keypoints of f1)."""
    import numpy as np

    import geofeat
    from geofeat.matching import match

    k0, k1 = geofeat.detect(f0, n, detector=detector), geofeat.detect(f1, n, detector=detector)
    truth = k0.xy @ A[:, :2].T + A[:, 2]
    H, W = f1.shape
    inside = (truth[:, 0] >= 0) & (truth[:, 0] < W) & (truth[:, 1] >= 0) & (truth[:, 1] < H)
    m = match(describe(f0, k0), describe(f1, k1)).matches0
    ok = (m >= 0) & inside
    correct = np.zeros(len(k0), bool)
    correct[ok] = np.linalg.norm(k1.xy[m[ok]] - truth[ok], axis=1) < tolerance_px
    return [correct.sum() / min(inside.sum(), len(k1)), correct.sum(), len(k0), len(k1)]


def cached_retrieval(cache):
    """The described frames cached by `retrieval_weightings.py --cache` (a pickled
    `RetrievalDatabase`) and its eligible queries: (db, queries (Q,), exclude (Q, N), validation and
    test halves of range(Q) (`split_queries(Q, 0)`, the command's split), classes (N,))."""
    import pickle

    import numpy as np

    from geofeat.apps.retrieval import eligible_queries, split_queries

    with open(cache, "rb") as fh:
        db = pickle.load(fh)
    queries, exclude, _ = eligible_queries(db)
    val, test = split_queries(len(queries), 0, groups=np.asarray(db.classes)[queries])
    return db, queries, exclude, val, test, np.asarray(db.classes)


def word_shortlist(features, queries, exclude, words: int, depth: int, weighting: str = "tfidf-l1"):
    """(Q, depth) database indices of each query's best results by the words, as `geofeat retrieval`
    ranks them: K = `words` medoids of the sampled descriptors (seed 0), `weighting`."""
    import numpy as np

    from geofeat.apps.retrieval import (N_VOCABULARY_SAMPLES, WEIGHTINGS, sample_descriptors, sample_distances,
                                        search, vocabulary, weight_histograms, word_counts)

    sample = sample_descriptors(features, N_VOCABULARY_SAMPLES, 0)
    vocab = vocabulary(sample, words, seed=0, distances=sample_distances(sample))
    vectors = weight_histograms(np.stack([word_counts(f, vocab) for f in features]), weighting)
    return search(vectors[queries], vectors, depth, exclude=exclude, distance=WEIGHTINGS[weighting])[0]


def paired_halves(a, b, val, test) -> dict:
    """Paired difference a - b of two descriptors' per-query figures (Q,) (e.g. mean Acc@1-10), over
    all queries with its 95 % bootstrap interval over queries, and over the validation and test halves
    (index arrays); plus the validation sum a + b by which a rule shared by both is chosen.
    Returns {diff, low, high, val, test, val_sum}."""
    import numpy as np

    from geofeat.apps.retrieval import bootstrap_interval

    a, b = np.asarray(a, float), np.asarray(b, float)
    d = a - b
    low, high = bootstrap_interval(d[:, None])
    return dict(diff=d.mean(), low=low[0], high=high[0], val=d[val].mean(), test=d[test].mean(),
                val_sum=a[val].mean() + b[val].mean())


def simulated_as(folder, keys: tuple[str, ...] = ("scenario",)) -> str | None:
    """The simulator's settings `keys` of a sequence folder (its groundtruth.json), joined by ", "
    ("?" for a key it lacks); None for a folder the simulator did not write."""
    from pathlib import Path

    from geofeat.groundtruth.simulator import GT_JSON, read_metadata

    if not (Path(folder) / GT_JSON).is_file():
        return None
    meta = read_metadata(folder)
    return ", ".join(str(meta.get(key, "?")) for key in keys)


def paired_by_sequence(keys, a, b, n: int = 2000, level: float = 0.95, seed: int = 0) -> dict:
    """Paired difference b - a of a per-pair figure (e.g. the MS of two runs of `geofeat bench`),
    by the bench's averaging rule: the mean over sequences of the per-sequence mean (so a
    sequence with more scored pairs weighs no more), with a percentile bootstrap interval that
    resamples sequences, the independent unit (the pairs of one sequence share its reference
    keypoints and scene, so resampling pairs gives too narrow an interval).

    keys: one tuple per pair whose first item is the sequence name; a, b: the two runs' figures in
    that order. Returns {a, b, diff, low, high, sequences, pairs}: low and high NaN with fewer than
    two sequences (`geofeat.apps.retrieval.bootstrap_interval`)."""
    import numpy as np

    from geofeat.apps.retrieval import bootstrap_interval

    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    seqs = [k[0] for k in keys]
    names = list(dict.fromkeys(seqs))
    if len(seqs) != len(a) or len(a) != len(b):
        raise ValueError(f"keys, a, b: expected one of each per pair, got {len(seqs)}, {len(a)}, {len(b)}")
    per_seq = np.array([[a[[s == name for s in seqs]].mean(), b[[s == name for s in seqs]].mean()] for name in names])
    d = (per_seq[:, 1] - per_seq[:, 0])[:, None]
    low, high = bootstrap_interval(d, n, level, seed)
    return dict(a=float(per_seq[:, 0].mean()), b=float(per_seq[:, 1].mean()), diff=float(d.mean()),
                low=float(low[0]), high=float(high[0]), sequences=len(names), pairs=len(a))
