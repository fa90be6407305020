"""Independent cross-checks of the evaluation figures: plain-loop re-implementations, written from
the definitions (`geofeat.scoring`'s docstring, shared/reference/matching_score_protocol.md,
`geofeat.bench.report`'s docstrings), compared with the project's vectorised code."""

import csv
import math

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from geofeat.bench.report import detail_table, read_results, summary
from geofeat.bench.runner import COLUMNS
from geofeat.scoring import ground_truth_pairs, score_detect


def _plain_ground_truth_pairs(ref, tgt, threshold=3.0):
    """Protocol step 4 as a loop: each target keypoint in order, its nearest reference keypoint is its
    partner when strictly closer than 3 px, unless an earlier target keypoint claimed it. None when a
    target keypoint is equidistant from two nearest reference keypoints (the protocol leaves that open)."""
    claimed, pairs = set(), []
    for t, (x, y) in enumerate(tgt):
        if not (math.isfinite(x) and math.isfinite(y)) or not ref:
            continue
        d = [math.hypot(x - rx, y - ry) for rx, ry in ref]
        best = min(d)
        nearest = [r for r, v in enumerate(d) if v == best]
        if len(nearest) > 1:
            return None
        if best < threshold and nearest[0] not in claimed:
            claimed.add(nearest[0])
            pairs.append((nearest[0], t))
    return pairs


# whole pixels give distances of exactly 3 px ((0, 0) to (3, 0)); some targets have no ground truth (NaN)
_coord = st.one_of(st.integers(0, 9).map(float), st.floats(0, 9).map(lambda v: round(v, 2)))
_ref = st.lists(st.tuples(_coord, _coord), max_size=12, unique=True)
_tgt = st.lists(st.one_of(st.tuples(_coord, _coord), st.just((math.nan, math.nan))), max_size=14)


@settings(max_examples=400, deadline=None, suppress_health_check=list(HealthCheck))
@given(_ref, _tgt, st.data())
def test_pairs_hits_ms_and_mma_equal_a_plain_loop(ref, tgt, data):
    expected = _plain_ground_truth_pairs(ref, tgt)
    assume(expected is not None)
    ref_xy, tgt_xy = np.array(ref, float).reshape(-1, 2), np.array(tgt, float).reshape(-1, 2)
    pairs = ground_truth_pairs(ref_xy, tgt_xy)
    assert [tuple(p) for p in pairs.tolist()] == expected

    # any nearest-neighbour result of the reference keypoints (-1: none)
    n_ref, n_tgt = len(ref), len(tgt)
    matches0 = np.array(data.draw(st.lists(st.integers(-1, n_tgt - 1), min_size=n_ref, max_size=n_ref)), np.int64)
    s = score_detect(matches0, pairs, n_ref, n_tgt)
    hits = sum(1 for r, t in expected if matches0[r] == t)
    assert s.hits == hits and s.n_gt == len(expected)
    assert s.ms == (hits / min(n_ref, n_tgt) if min(n_ref, n_tgt) else 0.0)  # keypoint counts, not pairs
    assert s.mma == (hits / len(expected) if expected else 0.0)


def test_bench_tables_are_means_over_sequences_of_means_over_pairs(tmp_path):
    """summary and details.md, read back from a results.csv, against the mean over sequences of the
    per-sequence means, computed by hand; sequences with very different pair counts, so that a mean over
    all pairs (or over the wrong rows) would differ."""
    rng = np.random.default_rng(7)
    rows = []
    for seq, n_pairs in (("a-deform", 1), ("b-rotate", 6), ("c-scale", 2)):
        for descriptor in ("geopatch", "sift"):
            for k in range(n_pairs if descriptor == "geopatch" or seq != "c-scale" else 1):
                n_ref, n_tgt, n_gt = (int(v) for v in rng.integers(100, 2048, 3))
                hits = int(rng.integers(0, n_gt))
                rows.append(dict(sequence=seq, reference="ref", target=f"t{k}", descriptor=descriptor, detector="sift",
                                 protocol="detect", keypoint_set="protocol", depth_profile="kinect",
                                 ms=hits / min(n_ref, n_tgt), mma=hits / n_gt, repeatability=n_gt / min(n_ref, n_tgt),
                                 hits=hits, n_gt=n_gt, n_ref=n_ref, n_tgt=n_tgt, seconds_extract=0.0,
                                 seconds_match=0.0, angle_deg=math.nan, scale=math.nan))
    path = tmp_path / "results.csv"
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    read = read_results(path)

    def by_hand(descriptor, key, sequence=None):
        seqs = {}
        for r in rows:
            if r["descriptor"] == descriptor and sequence in (None, r["sequence"]):
                seqs.setdefault(r["sequence"], []).append(r[key])
        return sum(sum(v) / len(v) for v in seqs.values()) / len(seqs)

    s = summary(read)
    for descriptor in ("geopatch", "sift"):
        assert math.isclose(s[descriptor]["ms"], by_hand(descriptor, "ms"), rel_tol=1e-12)
        assert math.isclose(s[descriptor]["mma"], by_hand(descriptor, "mma"), rel_tol=1e-12)
    table = detail_table(read).splitlines()[2:]
    assert len(table) == 2 * 4  # three sequences and **all** per descriptor
    for line in table:
        cells = [c.strip() for c in line.strip("|").split("|")]
        descriptor, sequence = cells[0], None if cells[2] == "**all**" else cells[2]
        expected = [f"{by_hand(descriptor, k, sequence):.3f}" for k in ("ms", "mma", "repeatability")]
        expected += [f"{by_hand(descriptor, k, sequence):.0f}" for k in ("n_ref", "n_tgt", "hits")]
        assert cells[3:] == expected, line
