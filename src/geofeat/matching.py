"""Nearest-neighbour descriptor matching: L2, Hamming, and min-over-rotations Hamming (GeoBit).

Metrics (chosen from the descriptor type when ``metric=None``):

- ``"l2"``: float descriptors (N, D); Euclidean distance via a matrix product (numpy, float64 for
  float64 input, float32 otherwise) of the descriptors less their mean (so that a large common part
  does not cancel their differences away), computed in blocks of queries; one numba pass per block finds
  the best and second-best target of each query and the best query of each target, comparing squared
  distances (square roots, in float64, of the two best only).
- ``"hamming"``: uint8 descriptors (N, B) of B bytes = 8 B bits; distance in bits.
- ``"hamming-rot"``: uint8 descriptors (N, R, B), R rotated copies of each descriptor (GeoBit:
  R = 16, B = 64). d(i, j) = min over k of Hamming(query i rotation 0, target j rotation k).
  Note that this distance is not symmetric.

The Hamming kernels are numba functions, parallel over queries: descriptors are viewed as uint64
words (bytes padded with zeros to a multiple of 8), XORed, and bit-counted with a branch-free
SWAR routine, which LLVM turns into the hardware popcount / vectorised nibble-lookup. Descriptors of
up to 512 bits (GeoBit, ORB, BRIEF) use a kernel unrolled over 8 words with the query in registers;
longer ones a generic kernel with targets laid out (N1, words, R), vectorised over rotations.
With 2-16 rotations of up to 512 bits (GeoBit), `_hamming_search` picks one of two exact pruned
searches (`_choose_method`): "two-stage" (a 256-bit lower bound of every pair, then exact distances
only for the pairs that the bound cannot rule out; for descriptors of real images; the mutual check
then asks each query's nearest target whether the query is its nearest, from the same bounds) or
"blocked" (one pass with per-block bounds; for data whose bounds rule out little, such as random
bits).

Rules: keypoints with ``valid == False`` on either side never match; among equal distances the
lowest target index wins; ``matches0 == -1`` means no match and its distance is inf.
"""

from __future__ import annotations

import numbers
import warnings

import numba
import numpy as np
from numba import njit, prange

from .features import Features, Matches
from .inputs import check_bool

__all__ = ["match", "distance_matrix", "METRICS"]

METRICS = ("l2", "hamming", "hamming-rot")

_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)
_S1 = np.uint64(1)
_S2 = np.uint64(2)
_S4 = np.uint64(4)
_S56 = np.uint64(56)
_BIG = np.uint64(1 << 62)
_BYTES1 = np.uint64(0x0101010101010101)
_H80 = np.uint64(0x8080808080808080)
#: Rotations per vector in the min-over-rotations kernel (GeoBit has 16).
_LANES = 16


@njit(inline="always", cache=True)
def _popcount64(x):
    """Number of set bits of a uint64 (SWAR bit count)."""
    x = x - ((x >> _S1) & _M1)
    x = (x & _M2) + ((x >> _S2) & _M2)
    x = (x + (x >> _S4)) & _M4
    return (x * _H01) >> _S56


@njit(cache=True, inline="always")
def _min_over_rotations8(q0, q1, q2, q3, q4, q5, q6, q7, t, j):
    """min over k of the Hamming distance between a 512-bit query (8 uint64 words, in registers)
    and rotation k of target j of t (N1, R, 8)."""
    m = _BIG
    for k in range(t.shape[1]):
        dk = (
            _popcount64(q0 ^ t[j, k, 0])
            + _popcount64(q1 ^ t[j, k, 1])
            + _popcount64(q2 ^ t[j, k, 2])
            + _popcount64(q3 ^ t[j, k, 3])
            + _popcount64(q4 ^ t[j, k, 4])
            + _popcount64(q5 ^ t[j, k, 5])
            + _popcount64(q6 ^ t[j, k, 6])
            + _popcount64(q7 ^ t[j, k, 7])
        )
        m = min(m, dk)
    return m


@njit(parallel=True, cache=True)
def _hamming_nn(q, t, valid0, valid1, n_chunks, want_cols, best_d, best_j, second_d, col_d, col_i):
    """Nearest neighbours under min-over-rotations Hamming distance.

    q: (N0, W) uint64 query words (rotation 0). t: (N1, W, R) uint64 target words, rotations last.
    valid0 (N0,), valid1 (N1,) bool. Outputs: best_d, second_d (N0,) uint64 (second = best distance
    over the other targets), best_j (N0,) int64 (-1 if none); with want_cols, col_d / col_i
    (n_chunks, N1) hold the per-chunk best query of every target (for the mutual check).
    """
    n0, W = q.shape
    n1 = t.shape[0]
    R = t.shape[2]
    for c in prange(n_chunks):
        i_start = (c * n0) // n_chunks
        i_stop = ((c + 1) * n0) // n_chunks
        d = np.empty(R, np.uint64)
        for i in range(i_start, i_stop):
            best = _BIG
            second = _BIG
            bj = -1
            if valid0[i]:
                for j in range(n1):
                    if not valid1[j]:
                        continue
                    for k in range(R):
                        d[k] = 0
                    for w in range(W):
                        qw = q[i, w]
                        for k in range(R):
                            d[k] += _popcount64(qw ^ t[j, w, k])
                    m = d[0]
                    for k in range(1, R):
                        if d[k] < m:
                            m = d[k]
                    if m < best:
                        second = best
                        best = m
                        bj = j
                    elif m < second:
                        second = m
                    if want_cols and m < col_d[c, j]:
                        col_d[c, j] = m
                        col_i[c, j] = i
            best_d[i] = best
            second_d[i] = second
            best_j[i] = bj


@njit(parallel=True, cache=True)
def _hamming_nn8(q, t, valid0, valid1, n_chunks, want_cols, best_d, best_j, second_d, col_d, col_i):
    """`_hamming_nn` for descriptors of exactly 8 words (512 bits; shorter ones are zero padded):
    the query words live in registers and each (target, rotation) distance is one unrolled sum.
    q: (N0, 8) uint64; t: (N1, R, 8) uint64 (rotations first). Other arguments as `_hamming_nn`."""
    n0 = q.shape[0]
    n1 = t.shape[0]
    for c in prange(n_chunks):
        i_start = (c * n0) // n_chunks
        i_stop = ((c + 1) * n0) // n_chunks
        for i in range(i_start, i_stop):
            best = _BIG
            second = _BIG
            bj = -1
            if valid0[i]:
                q0, q1, q2, q3 = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
                q4, q5, q6, q7 = q[i, 4], q[i, 5], q[i, 6], q[i, 7]
                for j in range(n1):
                    if not valid1[j]:
                        continue
                    m = _min_over_rotations8(q0, q1, q2, q3, q4, q5, q6, q7, t, j)
                    if m < best:
                        second = best
                        best = m
                        bj = j
                    elif m < second:
                        second = m
                    if want_cols and m < col_d[c, j]:
                        col_d[c, j] = m
                        col_i[c, j] = i
            best_d[i] = best
            second_d[i] = second
            best_j[i] = bj


@njit(inline="always", cache=True)
def _pc4(q0, q1, q2, q3, t, j, w, k):
    """Bits set in (q0, .., q3) XOR words w, .., w + 3 of target j at rotation k; t is (N1, 8, R)."""
    return (_popcount64(q0 ^ t[j, w, k]) + _popcount64(q1 ^ t[j, w + 1, k])
            + _popcount64(q2 ^ t[j, w + 2, k]) + _popcount64(q3 ^ t[j, w + 3, k]))


@njit(inline="always", cache=True)
def _futile(lb, j, best, second, bj, need_second, want_cols, col):
    """True when a pair (query, target j) whose distance is at least `lb` cannot change any output:
    not the query's nearest neighbour under the order (distance, target index), not below its second
    best distance (when `need_second`), and not below `col`, the target's best distance so far
    (when `want_cols`; queries arrive in ascending order, so a tie never wins there)."""
    bound = second if need_second else best
    if lb < bound or (lb == bound and lb == best and j < bj):
        return False
    return (not want_cols) or lb >= col


@njit(parallel=True, cache=True)
def _rot_nn8(q, t, valid0, valid1, n_chunks, block, need_second, want_cols, best_d, best_j, second_d,
             col_d, col_i):
    """Nearest neighbours under min-over-rotations Hamming distance of 512-bit descriptors (8 words,
    shorter ones zero padded), exact, with pruning.

    q: (N0, 8) uint64 query words (rotation 0), kept in registers; t: (N1, 8, R) uint64 target
    words, rotations last, so that the distances of a pair to its R rotations are one vector of
    popcounts per word (AVX-512 VPOPCNTQ where the CPU has it). Queries are split into `n_chunks`
    contiguous chunks (one thread each); a chunk walks the targets in blocks of `block`, which stay
    in cache while every query of the chunk visits them.

    Pruning: distances over the first words only grow with more words, so they bound the exact
    distance from below. For every query and block: (1) the 4-word bounds (256 bits) of the whole
    block; (2) the exact distance to the target with the smallest bound first (usually the true
    match: a tight bound early); (3) the other targets in order, each dropped when its bound shows
    that it cannot change any output (`_futile`), the others completed from their stored 4-word
    distances per rotation; on GeoBit descriptors of the Kinect frame over
    95 % of the pairs end there, at half the work. The query's nearest
    neighbour is kept under the order (distance, target index), so the visiting order does not
    matter and every output is identical to brute force, ties included (lowest index wins on both
    sides).

    Outputs as `_hamming_nn`; second_d is exact only with need_second.
    """
    n0 = q.shape[0]
    n1, _, R = t.shape
    for c in prange(n_chunks):
        i_start = (c * n0) // n_chunks
        i_stop = ((c + 1) * n0) // n_chunks
        lb = np.empty(block, np.uint64)
        part = np.empty((block, R), np.uint64)  # per-rotation 4-word distances of the block
        for i in range(i_start, i_stop):
            best_d[i] = _BIG
            second_d[i] = _BIG
            best_j[i] = -1
        for j_start in range(0, n1, block):
            j_stop = min(n1, j_start + block)
            for i in range(i_start, i_stop):
                if not valid0[i]:
                    continue
                q0, q1, q2, q3 = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
                q4, q5, q6, q7 = q[i, 4], q[i, 5], q[i, 6], q[i, 7]
                best = best_d[i]
                second = second_d[i]
                bj = best_j[i]
                # (1) 4-word lower bounds of the block and the target with the smallest one
                seed = -1
                low = _BIG
                for j in range(j_start, j_stop):
                    m = _BIG
                    for k in range(R):  # over rotations: one vector per word
                        p = _pc4(q0, q1, q2, q3, t, j, 0, k)
                        part[j - j_start, k] = p
                        m = min(m, p)
                    lb[j - j_start] = m
                    if valid1[j] and m < low:
                        low = m
                        seed = j
                # (2) the seed, then (3) the others in order
                for step in range(-1, j_stop - j_start):
                    if step < 0:
                        j = seed
                        if j < 0:
                            continue
                    else:
                        j = j_start + step
                        if j == seed or not valid1[j]:
                            continue
                    col = col_d[c, j] if want_cols else _BIG
                    if _futile(lb[j - j_start], j, best, second, bj, need_second, want_cols, col):
                        continue
                    m = _BIG
                    for k in range(R):
                        m = min(m, part[j - j_start, k] + _pc4(q4, q5, q6, q7, t, j, 4, k))
                    if m < best or (m == best and j < bj):
                        second = best
                        best = m
                        bj = j
                    elif m < second:
                        second = m
                    if want_cols and m < col:
                        col_d[c, j] = m
                        col_i[c, j] = i
                best_d[i] = best
                second_d[i] = second
                best_j[i] = bj


@njit(inline="always", cache=True)
def _rot_exact8(q0, q1, q2, q3, q4, q5, q6, q7, t, j):
    """min over rotations k of the 512-bit Hamming distance between the query words (registers)
    and target j of t (N1, 8, R) uint64, rotations last (one vector of popcounts per word)."""
    m = _BIG
    for k in range(t.shape[2]):
        m = min(m, _pc4(q0, q1, q2, q3, t, j, 0, k) + _pc4(q4, q5, q6, q7, t, j, 4, k))
    return m


@njit(parallel=True, cache=True)
def _rot_bounds8(q, t, valid0, valid1, n_chunks, block, lb, seeds):
    """Stage 1 of the two-stage search: a lower bound of every (query, target) distance.

    q: (N0, 8) uint64 query words (rotation 0); t: (N1, W, R) uint64 target words (W >= 4),
    rotations last. lb: (N0, N1) uint8 output, min over rotations of the Hamming distance of the
    first 4 words (256 bits), clipped to 127 (still a lower bound of the full min-over-rotations
    distance, since every further word only adds bits); rows of invalid queries are left unset.
    seeds: (N0, 2) int64 output, the valid targets with the smallest and second smallest bound
    (lowest index among ties; -1 when there are fewer valid targets). Queries in `n_chunks` chunks
    (one thread each); targets in blocks of `block` that stay in cache while the chunk visits them.
    """
    n0 = q.shape[0]
    n1, _, R = t.shape
    for c in prange(n_chunks):
        i_start = (c * n0) // n_chunks
        i_stop = ((c + 1) * n0) // n_chunks
        lows = np.full((i_stop - i_start, 2), _BIG, np.uint64)
        for i in range(i_start, i_stop):
            seeds[i, 0] = -1
            seeds[i, 1] = -1
        for j_start in range(0, n1, block):
            j_stop = min(n1, j_start + block)
            for i in range(i_start, i_stop):
                if not valid0[i]:
                    continue
                q0, q1, q2, q3 = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
                low0 = lows[i - i_start, 0]
                low1 = lows[i - i_start, 1]
                s0 = seeds[i, 0]
                s1 = seeds[i, 1]
                for j in range(j_start, j_stop):
                    m = _BIG
                    for k in range(R):  # over rotations: one vector per word
                        m = min(m, _pc4(q0, q1, q2, q3, t, j, 0, k))
                    lb[i, j] = np.uint8(min(m, np.uint64(127)))
                    if m < low1 and valid1[j]:
                        if m < low0:
                            low1, s1 = low0, s0
                            low0, s0 = m, j
                        else:
                            low1, s1 = m, j
                lows[i - i_start, 0] = low0
                lows[i - i_start, 1] = low1
                seeds[i, 0] = s0
                seeds[i, 1] = s1


@njit(inline="always", cache=True)
def _byte_fill(v):
    """uint64 with every byte equal to v (0 <= v <= 127)."""
    return np.uint64(v) * _BYTES1


@njit(inline="always", cache=True)
def _flags_at_most(word, threshold):
    """Nonzero when some byte of `word` is at most `threshold` (bytes and threshold <= 127, so one
    subtraction tests all eight: no borrow crosses a byte)."""
    return ((_byte_fill(threshold) | _H80) - word) & _H80


@njit(inline="always", cache=True)
def _rot_exact_row(q, i, t, j):
    """`_rot_exact8` of query row i of q (N0, 8) and target j."""
    return _rot_exact8(q[i, 0], q[i, 1], q[i, 2], q[i, 3], q[i, 4], q[i, 5], q[i, 6], q[i, 7], t, j)


@njit(inline="always", cache=True)
def _consider(m, j, best, second, bj):
    """A query's (best, second, best index) updated with the exact distance m of its pair with
    target j, under the brute-force order (distance, index)."""
    if m < best or (m == best and j < bj):
        second = best
        best = m
        bj = j
    elif m < second:
        second = m
    return best, second, bj


@njit(parallel=True, cache=True)
def _rot_finish8(q, t, valid0, valid1, lb, seeds, n_chunks, best_d, best_j, second_d, n_exact):
    """Stage 2 of the two-stage search: exact distances only where the bound of `_rot_bounds8`
    leaves a pair able to change a query's output.

    Per query (chunks of consecutive queries, one thread each): the exact distances to its two
    seeds first (tight running bounds at once), then every other valid target j whose bound
    lb[i, j] is at most the running best. Skipped pairs have
    d >= lb > every bound that matters, so they can neither win nor tie; evaluated pairs update the
    outputs under the brute-force rules (`_consider`), so the visiting order changes no output.

    The bounds are scanned 8 at a time: lb's rows are read as uint64 words, and one subtraction
    per word flags every byte at or below its threshold (bytes and thresholds <= 127, so no borrow
    crosses a byte); a word without a flag skips 8 targets at once. Flagged bytes are checked
    again against the running best (which only falls) before an exact distance.

    q (N0, 8), t (N1, 8, R) uint64, valid0, valid1 as `_rot_bounds8`; lb (N0, N1p) uint8 (N1p a
    multiple of 8; bounds clipped to 127, padding ignored) and seeds (N0, 2) its outputs.
    Outputs best_d, best_j as `_hamming_nn`; second_d is not exact (the ratio test is
    `_verify_ratio`'s). n_exact (n_chunks,) int64: exact distances computed per chunk.
    """
    n0 = q.shape[0]
    n1 = t.shape[0]
    n1p = lb.shape[1]
    words = lb.view(np.uint64)  # (N0, N1p / 8)
    for c in prange(n_chunks):
        count = 0
        for i in range((c * n0) // n_chunks, ((c + 1) * n0) // n_chunks):
            best = _BIG
            second = _BIG
            bj = -1
            if valid0[i]:
                q0, q1, q2, q3 = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
                q4, q5, q6, q7 = q[i, 4], q[i, 5], q[i, 6], q[i, 7]
                s0 = seeds[i, 0]
                s1 = seeds[i, 1]
                for j in (s0, s1):  # valid targets (or -1)
                    if j >= 0:
                        m = _rot_exact8(q0, q1, q2, q3, q4, q5, q6, q7, t, j)
                        count += 1
                        best, second, bj = _consider(m, j, best, second, bj)
                for w in range(n1p // 8):
                    if _flags_at_most(words[i, w], min(best, np.uint64(127))) == 0:
                        continue
                    for j in range(8 * w, min(8 * w + 8, n1)):
                        if j == s0 or j == s1 or not valid1[j] or np.uint64(lb[i, j]) > best:
                            continue
                        m = _rot_exact8(q0, q1, q2, q3, q4, q5, q6, q7, t, j)
                        count += 1
                        best, second, bj = _consider(m, j, best, second, bj)
            best_d[i] = best
            second_d[i] = second
            best_j[i] = bj
        n_exact[c] = count


@njit(parallel=True, cache=True)
def _transpose_bounds(lb, n0, n1, out):
    """out[j, i] = lb[i, j] for i < n0, j < n1, in 64 x 64 tiles. lb (N0, N1p), out (N1, N0p) uint8."""
    tile = 64
    for bj in prange((n1 + tile - 1) // tile):
        j_stop = min(n1, (bj + 1) * tile)
        for i_start in range(0, n0, tile):
            i_stop = min(n0, i_start + tile)
            for j in range(bj * tile, j_stop):
                for i in range(i_start, i_stop):
                    out[j, i] = lb[i, j]


@njit(parallel=True, cache=True)
def _verify_mutual(q, t, valid0, lbt, best_d, best_j, owner):
    """owner[i] = True when query i is its nearest target's nearest query: no other valid query i'
    has a smaller exact distance to j = best_j[i], or the same distance and a lower index (the
    brute-force column rule). Only the queries whose bound lbt[j, i'] (the transposed bounds of
    `_rot_bounds8`) is at most best_d[i] can break it, so only they get an exact distance (the
    column's bytes scanned 8 at a time, `_flags_at_most`); the scan stops at the first that does.
    q (N0, 8), t (N1, 8, R) uint64; lbt (N1, N0p) uint8, N0p a multiple of 8."""
    n0 = q.shape[0]
    n0p = lbt.shape[1]
    words = lbt.view(np.uint64)  # (N1, N0p / 8)
    for i in prange(n0):
        j = best_j[i]
        ok = j >= 0
        if ok:
            d = best_d[i]
            for w in range(n0p // 8):
                if _flags_at_most(words[j, w], min(d, np.uint64(127))) == 0:
                    continue
                for k in range(8 * w, min(8 * w + 8, n0)):
                    if k == i or not valid0[k] or np.uint64(lbt[j, k]) > d:
                        continue
                    m = _rot_exact_row(q, k, t, j)
                    if m < d or (m == d and k < i):
                        ok = False
                        break
                if not ok:
                    break
        owner[i] = ok


@njit(parallel=True, cache=True)
def _verify_ratio(q, t, valid1, lb, seeds, best_d, best_j, ratio, second_d):
    """The ratio test after the rows are done: second_d[i] = the exact distance of some other valid
    target j that fails query i's test (best_d[i] >= ratio * d(i, j)), else _BIG (the test passes,
    as with the true second best). Only targets whose bound lb[i, j] is at most best / ratio (+ one
    bit) can fail it, so only they get an exact distance: first the row's seeds (its two smallest
    bounds, the likeliest to fail it), then the row's other flagged bytes (`_flags_at_most`); the
    search stops at the first failure. ratio in (0, 1]."""
    n0 = q.shape[0]
    n1 = t.shape[0]
    n1p = lb.shape[1]
    words = lb.view(np.uint64)
    for i in prange(n0):
        second = _BIG
        bj = best_j[i]
        if bj >= 0:
            best = best_d[i]
            # capped in float64 before the conversion: best / ratio overflows uint64 for a tiny ratio
            thr = np.uint64(min(np.float64(best) / ratio + 1.0, 127.0))
            s0, s1 = seeds[i, 0], seeds[i, 1]
            for j in (s0, s1):  # valid targets (or -1)
                if j >= 0 and j != bj and second == _BIG:
                    m = _rot_exact_row(q, i, t, j)
                    if np.float64(best) >= ratio * np.float64(m):
                        second = m
            for w in range(n1p // 8):
                if second != _BIG:
                    break
                if _flags_at_most(words[i, w], thr) == 0:
                    continue
                for j in range(8 * w, min(8 * w + 8, n1)):
                    if j == bj or j == s0 or j == s1 or not valid1[j] or np.uint64(lb[i, j]) > thr:
                        continue
                    m = _rot_exact_row(q, i, t, j)
                    if np.float64(best) >= ratio * np.float64(m):
                        second = m
                        break
        second_d[i] = second


def _as_words(desc: np.ndarray) -> np.ndarray:
    """(N, ..., B) uint8 -> (N, ..., ceil(B / 8)) uint64 (zero padded; bit counts are unchanged)."""
    B = desc.shape[-1]
    pad = (-B) % 8
    if pad:
        desc = np.concatenate([desc, np.zeros(desc.shape[:-1] + (pad,), np.uint8)], axis=-1)
    return np.ascontiguousarray(desc).view(np.uint64)


def _two_stage(q, t, valid0, valid1, n_chunks, ratio, want_cols, best_d, best_j, second_d, col_d, col_i):
    """The two-stage exact search (`_rot_bounds8` then `_rot_finish8`) on padded words
    q (N0, 8), t (N1, 8, R) uint64; ratio: Lowe's ratio or None. Fills the outputs like `_rot_nn8`
    (second_d as `_rot_finish8` says), except the columns: with want_cols, a target j that is the
    nearest neighbour of a query i which is also j's nearest query gets col_d[0, j] = 0 and
    col_i[0, j] = i, and every other column stays empty (all the mutual check needs;
    `_verify_mutual`). Returns the number of exact distances computed in stage 2 (the pairs that the
    bounds could not rule out)."""
    n0, n1 = len(q), len(t)
    t4 = np.ascontiguousarray(t[:, :4])  # (N1, 4, R): the words of the bound, compact in cache
    block = max(16, (64 * 1024) // t4[0].nbytes)
    n1p = -(-n1 // 8) * 8  # rows padded to whole uint64 words; invalid rows stay 127
    lb = np.full((n0, n1p), 127, np.uint8)
    seeds = np.empty((n0, 2), np.int64)
    _rot_bounds8(q, t4, valid0, valid1, n_chunks, block, lb, seeds)
    n_exact = np.zeros(n_chunks, np.int64)
    _rot_finish8(q, t, valid0, valid1, lb, seeds, n_chunks, best_d, best_j, second_d, n_exact)
    if ratio is not None:
        # the ratio test asks one question per query once its best is known: does another target
        # come within best / ratio? Answered from the row's bounds (`_verify_ratio`)
        _verify_ratio(q, t, valid1, lb, seeds, best_d, best_j, float(ratio), second_d)
    if want_cols:
        # the mutual check asks one question per query: is it its nearest target's nearest query?
        # Answered from the column's bounds, after the rows are done (`_verify_mutual`)
        lbt = np.full((n1, -(-n0 // 8) * 8), 127, np.uint8)
        _transpose_bounds(lb, n0, n1, lbt)
        owner = np.zeros(n0, np.bool_)
        _verify_mutual(q, t, valid0, lbt, best_d, best_j, owner)
        mine = np.flatnonzero(owner)
        col_d[0, best_j[mine]] = 0
        col_i[0, best_j[mine]] = mine
    return int(n_exact.sum())


#: Largest bound matrix (bytes) of the two-stage search; larger problems use the blocked search.
_TWO_STAGE_MAX_BYTES = 256 * 2**20
#: The two-stage search is chosen when at most this fraction of sampled pairs needs an exact distance.
_TWO_STAGE_MAX_EXACT = 0.3
#: Queries sampled by `_choose_method`.
_SAMPLE_QUERIES = 16


def _choose_method(q, t, valid0, valid1, ratio) -> str:
    """"two-stage" or "blocked" for padded words q (N0, 8), t (N1, 8, R) uint64: the two-stage
    search computes bounds for every pair (about half the work of brute force) and then exact
    distances for the pairs they do not rule out, so it wins when those are few (descriptors of
    real images: about 4 % of the pairs; uniformly random bits: all of them). Runs it on
    `_SAMPLE_QUERIES` evenly spaced valid queries and compares the fraction of exact distances with
    `_TWO_STAGE_MAX_EXACT`. Speed only: both methods give the same matches."""
    n0, n1 = len(q), len(t)
    n_valid1 = int(np.count_nonzero(valid1))
    if n0 * (n1 + 8) > _TWO_STAGE_MAX_BYTES or n_valid1 == 0:
        return "blocked"
    rows = np.flatnonzero(valid0)
    if len(rows) == 0:
        return "blocked"
    rows = rows[np.linspace(0, len(rows) - 1, min(_SAMPLE_QUERIES, len(rows))).astype(np.int64)]
    rows = np.unique(rows)
    k = len(rows)
    out_d, out_s = np.empty(k, np.uint64), np.empty(k, np.uint64)
    out_j = np.empty(k, np.int64)
    dummy_d, dummy_i = np.full((1, 1), _BIG, np.uint64), np.full((1, 1), -1, np.int64)
    n_chunks = max(1, min(numba.get_num_threads(), k))
    n_exact = _two_stage(np.ascontiguousarray(q[rows]), t, np.ones(k, bool), valid1, n_chunks, ratio, False,
                         out_d, out_j, out_s, dummy_d, dummy_i)
    return "two-stage" if n_exact <= _TWO_STAGE_MAX_EXACT * k * n_valid1 else "blocked"


def _hamming_search(d0, d1, valid0, valid1, want_cols, ratio=None, method="auto"):
    """d0, d1: (N, R, B) uint8. Returns best_d, best_j, second_d (N0,), col_j (N1,) or None.
    second_d is exact for one rotation, and otherwise only as far as the ratio test needs it: with
    R > 1 the searches prune against the best distance (no ratio) or the second best ("blocked"),
    or, for "two-stage", second_d is a distance of another target that fails the test, or _BIG
    when none does (`_verify_ratio`), so the ratio test `best < ratio * second` decides as with
    the exact value.
    method, for R in 2..16 rotations of at most 512 bits: "two-stage" (`_two_stage`), "blocked"
    (`_rot_nn8`) or "auto" (`_choose_method`); every method gives the same matches."""
    need_second = ratio is not None
    words = _as_words(d1)  # (N1, R, W)
    n0, n1, R, W = d0.shape[0], d1.shape[0], words.shape[1], words.shape[2]
    q = np.ascontiguousarray(_as_words(d0[:, 0, :]))  # (N0, W)
    rotations = 1 < R <= _LANES and W <= 8
    if W <= 8:  # pad to 8 words for the unrolled kernels (zero words add nothing)
        q = np.concatenate([q, np.zeros((n0, 8 - W), np.uint64)], axis=1)
        words = np.concatenate([words, np.zeros((n1, R, 8 - W), np.uint64)], axis=2)
    if rotations:
        pad = (-R) % _LANES  # repeat the last rotation: the minimum over rotations is unchanged
        t = np.concatenate([words, np.repeat(words[:, -1:], pad, axis=1)], axis=1) if pad else words
        t = np.ascontiguousarray(t.transpose(0, 2, 1))  # (N1, 8, 16)
    elif W <= 8:
        t = words  # (N1, 1, 8)
        kernel = _hamming_nn8
    else:
        t = np.ascontiguousarray(words.transpose(0, 2, 1))  # (N1, W, R)
        kernel = _hamming_nn
    n_chunks = max(1, min(numba.get_num_threads() * 4, n0))
    best_d = np.empty(n0, np.uint64)
    second_d = np.empty(n0, np.uint64)
    best_j = np.empty(n0, np.int64)
    shape = (n_chunks, n1) if want_cols else (1, 1)
    col_d = np.full(shape, _BIG, np.uint64)
    col_i = np.full(shape, -1, np.int64)
    if rotations:
        # a block of targets stays in the L2 cache: about 128 KiB of words
        block = max(16, (128 * 1024) // t[0].nbytes)
        if method == "auto":
            method = _choose_method(q, t, valid0, valid1, ratio)
        if method == "two-stage":
            _two_stage(q, t, valid0, valid1, n_chunks, ratio, want_cols, best_d, best_j, second_d,
                       col_d, col_i)
        elif method != "blocked":
            raise ValueError(f"method: expected 'auto', 'two-stage' or 'blocked', got {method!r}")
        else:
            _rot_nn8(q, t, valid0, valid1, n_chunks, block, bool(need_second), bool(want_cols), best_d,
                     best_j, second_d, col_d, col_i)
    else:
        kernel(q, t, valid0, valid1, n_chunks, bool(want_cols), best_d, best_j, second_d, col_d, col_i)
    bd = best_d.astype(np.float64)
    sd = second_d.astype(np.float64)
    bd[best_d == _BIG] = np.inf
    sd[second_d == _BIG] = np.inf
    col_j = None
    if want_cols:
        # chunks cover ascending query ranges: the first chunk holding the minimum has the lowest i
        c = np.argmin(col_d, axis=0)
        col_j = col_i[c, np.arange(n1)]
    return bd, best_j, sd, col_j


#: The most bits whose dot products float16 holds exactly (every integer up to 2**11): the products
#: of {0, 1} numbers are exact, and so is every partial sum of at most this many of them.
FP16_EXACT_BITS = 2048


def _hamming_dot_dtype(device_type: str, n_bits: int):
    """The torch dtype in which `_hamming_search_torch` multiplies {0, 1} bit matrices of `n_bits`
    columns, exactly: float16 on CUDA up to `FP16_EXACT_BITS` bits (the fast one there), else
    float32 (every integer up to 2**24; TF32 or bfloat16 inputs hold 0 and 1 exactly and accumulate
    in float32), and float64 beyond. A float16 product of more bits rounds the dot product (2049 ones
    gave 2048) and so the distance, silently: descriptors of more than 256 bytes (GeoBit with
    n_bits > 2048) matched on a GPU differed from the CPU's."""
    import torch

    if device_type == "cuda" and n_bits <= FP16_EXACT_BITS:
        return torch.float16
    return torch.float32 if n_bits <= 1 << 24 else torch.float64


def _hamming_search_torch(d0, d1, valid0, valid1, want_cols, device, block: int | None = None, dtype=None):
    """`_hamming_search` as matrix products on a torch device (meant for CUDA; exact).

    Bits become {0, 1} numbers (`_hamming_dot_dtype`: float16 on CUDA for at most 2048 bits, where
    every dot product is an integer held exactly, float32 otherwise) and, per query block,
    Hamming(a, b) = |a| + |b| - 2 a.b for every target rotation at once. Then the minimum over
    rotations, the nearest and second nearest targets (first index among ties, as `torch.argmin`)
    and, with want_cols, the nearest query of every target. d0, d1: (N, R, B) uint8. `dtype`: the
    product's dtype instead of `_hamming_dot_dtype`'s (the tests run CUDA's float16 on the CPU).
    """
    import torch

    dev = torch.device(device)
    if dtype is None:
        dtype = _hamming_dot_dtype(dev.type, 8 * int(d1.shape[-1]))
    shifts = torch.arange(7, -1, -1, device=dev, dtype=torch.uint8)

    def on_device(x):  # numpy arrays are uploaded, tensors (e.g. GPU-path descriptors) used in place
        return x.to(dev) if isinstance(x, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(x)).to(dev)

    def bits(d):  # (..., B) uint8 -> (..., 8 B) {0, 1}, unpacked on the device
        t = on_device(d)
        return ((t.unsqueeze(-1) >> shifts) & 1).flatten(-2)

    n0, n1, R = d0.shape[0], d1.shape[0], d1.shape[1]
    b0 = bits(d0[:, 0])  # (N0, L)
    b1 = bits(d1).reshape(n1 * R, -1)  # (N1 R, L)
    c0 = b0.sum(1, dtype=torch.int32)
    c1 = b1.sum(1, dtype=torch.int32)
    f1 = b1.to(dtype)
    big = int(_BIG)
    v0 = on_device(valid0).bool()
    v1 = on_device(valid1).bool()
    block = block or (1024 if dev.type == "cuda" else 128)
    best_d = torch.empty(n0, dtype=torch.int64, device=dev)
    best_j = torch.empty(n0, dtype=torch.int64, device=dev)
    second_d = torch.empty(n0, dtype=torch.int64, device=dev)
    col_d = torch.full((n1,), big, dtype=torch.int64, device=dev)
    col_i = torch.full((n1,), -1, dtype=torch.int64, device=dev)
    for s in range(0, n0, block):
        dot = (b0[s:s + block].to(dtype) @ f1.T).round().to(torch.int32)  # (n, N1 R)
        dist = (c0[s:s + block, None] + c1[None, :] - 2 * dot).reshape(-1, n1, R).amin(2).to(torch.int64)
        dist.masked_fill_(~v1[None, :], big)
        dist.masked_fill_(~v0[s:s + block, None], big)
        j = dist.argmin(1)
        rows = torch.arange(len(j), device=dev)
        bd = dist[rows, j]
        best_d[s:s + block] = bd
        best_j[s:s + block] = torch.where(bd < big, j, -1)
        if want_cols:  # strict: an earlier block keeps ties (lowest query index)
            i = dist.argmin(0)
            cd = dist[i, torch.arange(n1, device=dev)]
            better = cd < col_d
            col_d = torch.where(better, cd, col_d)
            col_i = torch.where(better, i + s, col_i)
        dist[rows, j] = big
        second_d[s:s + block] = dist.amin(1) if n1 > 1 else big
    bd = best_d.cpu().numpy().astype(np.float64)
    sd = second_d.cpu().numpy().astype(np.float64)
    bd[bd >= big] = np.inf
    sd[sd >= big] = np.inf
    col_j = col_i.cpu().numpy() if want_cols else None
    return bd, best_j.cpu().numpy(), sd, col_j


def _l2_search_torch(d0, d1, valid0, valid1, want_cols):
    """`_l2_search` on torch tensors of one device (the GPU path): the same float32 (float64 for
    float64 input) squared distances |a|^2 + |b|^2 - 2 a.b of the descriptors less their valid rows'
    mean, as one matrix product (TF32 off), the same tie rules (first index, as torch.argmin) on the
    squared distances (`_l2_search_device`), and the square roots of the best two in float64 on the
    host. Returns numpy arrays like `_l2_search`."""
    bd, best_j, second, col_j = _l2_search_device(d0, d1, valid0, valid1, want_cols)

    def root(x):  # numpy's float64 square root (correctly rounded), as `_l2_search`
        return np.sqrt(x.cpu().numpy().astype(np.float64))

    return (root(bd), best_j.cpu().numpy(), root(second), None if col_j is None else col_j.cpu().numpy())


def _l2_search_device(d0, d1, valid0, valid1, want_cols):
    """The device part of `_l2_search_torch`, with no read back to the host (a CUDA graph can hold
    it): tensors (best squared distance (N0,), best index (N0,) int64 (-1: none), second squared
    distance (N0,), best row per column (N1,) or None)."""
    import torch

    dtype = torch.float64 if torch.float64 in (d0.dtype, d1.dtype) else torch.float32
    valid0, valid1 = valid0.bool(), valid1.bool()
    # `_valid_mean` as masked sums: boolean indexing would wait for the GPU twice to learn the row counts
    total = torch.where(valid0[:, None], d0.double(), 0.0).sum(0) + torch.where(valid1[:, None], d1.double(), 0.0).sum(0)
    count = (valid0.sum() + valid1.sum()).clamp_min(1).double()
    centre = torch.round(total / count).to(dtype)  # zeros when none is valid, as `_valid_mean`
    a, b = d0.to(dtype) - centre, d1.to(dtype) - centre
    n1 = b.shape[0]
    from .process_settings import no_tf32

    with no_tf32(cudnn=False):
        ab = a @ b.T
    # squared distances: the order and the ties of the exact ones for whole-number descriptors (a
    # float32 square root merges neighbours at distances above 2048, and torch's float64 one on the
    # CPU gave sqrt(32) one unit in the last place low, which flipped the ratio test at 0.8 sqrt(50))
    dist = ((a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * ab).clamp_min(0.0)
    inf = torch.full((), float("inf"), dtype=dist.dtype, device=dist.device)  # a fill, not a host copy
    dist = torch.where(valid1[None, :] & valid0[:, None], dist, inf)
    j = dist.argmin(1)
    rows = torch.arange(len(j), device=dist.device)
    bd = dist[rows, j]
    best_j = torch.where(torch.isfinite(bd), j, -1)
    col_j = dist.argmin(0) if want_cols else None
    if n1 > 1:
        dist[rows, j] = inf
        second = dist.amin(1)
    else:
        second = torch.full_like(bd, float("inf"))
    return bd, best_j, second, col_j


@njit(parallel=True, cache=True)
def _l2_block_rows(ab, aa, bb, two, zero, valid0, valid1, keep, dist, best_d, best_j, second_d):
    """One block of queries: the squared distances max(aa[i] + bb[j] - two * ab[i, j], 0) in the
    descriptors' float type (inf where either side is invalid), stored in dist when `keep` (for the
    columns' pass), and per row the first minimum (best_d, best_j; -1 where none is finite) and the
    minimum of the other entries (second_d), all squared. The square root is the caller's, in float64:
    a float32 one maps neighbouring squared distances (exact for whole-number descriptors) of
    distances above 2048 to one value, a tie that the exact distances do not have.
    `two` and `zero` are 2 and 0 of that type (numba would promote a float32 times a Python
    number to float64)."""
    n, n1 = ab.shape
    inf = np.inf
    for i in prange(n):
        b1 = inf
        b2 = inf
        j1 = -1
        if valid0[i]:
            for j in range(n1):
                if valid1[j]:
                    d = max((aa[i] + bb[j]) - two * ab[i, j], zero)
                else:
                    d = inf
                if keep:
                    dist[i, j] = d
                if d < b1:
                    b2 = b1
                    b1 = d
                    j1 = j
                elif d < b2:
                    b2 = d
        elif keep:
            for j in range(n1):
                dist[i, j] = inf
        best_d[i] = b1
        best_j[i] = j1
        second_d[i] = b2


@njit(parallel=True, cache=True)
def _l2_block_cols(dist, offset, col_best, col_j):
    """Fold one block's distances into the per-column minimum: the first row of the block with the
    column's smallest distance replaces the running one only when strictly smaller."""
    n, n1 = dist.shape
    chunk = 64
    for c in prange((n1 + chunk - 1) // chunk):
        lo = c * chunk
        hi = min(lo + chunk, n1)
        for i in range(n):
            for j in range(lo, hi):
                if dist[i, j] < col_best[j]:
                    col_best[j] = dist[i, j]
                    col_j[j] = i + offset


def _valid_mean(d0, d1, valid0, valid1) -> np.ndarray:
    """(D,) float64 mean of the valid rows of d0 (N0, D) and d1 (N1, D), rounded to whole numbers
    (zeros when none is valid). The L2 searches subtract it from both sides: the distances do not
    change, but |a|^2 + |b|^2 - 2 a.b no longer cancels away the differences of descriptors that share
    a large common part (float32 descriptors of mean 100 that differ by 0.01 found 0.5 % of their
    nearest neighbours without it). Whole numbers keep whole-valued descriptors exact, so that equal
    distances stay equal (ties go to the lowest index); unit-length ones (GeoPatch) are left as they are."""
    total = np.zeros(d0.shape[1], np.float64)
    for d, valid in ((d0, valid0), (d1, valid1)):
        total += np.asarray(d)[np.asarray(valid, dtype=bool)].sum(axis=0, dtype=np.float64)
    count = int(np.count_nonzero(valid0)) + int(np.count_nonzero(valid1))
    return np.rint(total / max(count, 1))


def _l2_search(d0, d1, valid0, valid1, want_cols, block: int = 1024):
    """d0 (N0, D), d1 (N1, D) float. Returns best_d, best_j, second_d (N0,), col_j (N1,) or None.

    Squared distances are max(|a|^2 + |b|^2 - 2 a.b, 0) in float32 (float64 for float64 input) of
    the descriptors less their mean (`_valid_mean`), the matrix product in blocks of `block` queries;
    one numba pass per block finds each row's best and second squared distance, another the columns'
    best (first row among equals). Only the returned best and second distances get a square root, in
    float64: whole-number descriptors then give the exact distances, ties and ratio test of brute
    force (a float32 square root merged squared distances such as 4204753 and 4204754)."""
    dtype = np.float64 if (d0.dtype == np.float64 or d1.dtype == np.float64) else np.float32
    centre = _valid_mean(d0, d1, valid0, valid1).astype(dtype)
    if centre.any():
        a = np.ascontiguousarray(np.asarray(d0, dtype=dtype) - centre)
        b = np.ascontiguousarray(np.asarray(d1, dtype=dtype) - centre)
    else:  # unit-length descriptors (GeoPatch): a mean that rounds to 0, no copies
        a = np.ascontiguousarray(d0, dtype=dtype)
        b = np.ascontiguousarray(d1, dtype=dtype)
    n0, n1 = len(a), len(b)
    bb = np.einsum("ij,ij->i", b, b)
    two = dtype(2.0)
    v0 = np.ascontiguousarray(valid0, dtype=np.bool_)
    v1 = np.ascontiguousarray(valid1, dtype=np.bool_)
    best_d = np.empty(n0, dtype)
    second_d = np.empty(n0, dtype)
    best_j = np.empty(n0, np.int64)
    col_best = np.full(n1, np.inf, dtype)
    col_j = np.full(n1, -1, np.int64)
    dist = np.empty((min(block, n0), n1) if want_cols else (1, 1), dtype)  # kept for the columns only
    for s in range(0, n0, block):
        ab = a[s : s + block]
        aa = np.einsum("ij,ij->i", ab, ab)
        rows = dist[: len(ab)]
        _l2_block_rows(ab @ b.T, aa, bb, two, dtype(0.0), v0[s : s + block], v1, bool(want_cols), rows,
                       best_d[s : s + block], best_j[s : s + block], second_d[s : s + block])
        if want_cols:
            _l2_block_cols(rows, s, col_best, col_j)
    # square roots in float64 of the squared distances: exact ties stay ties, and no others appear
    return (np.sqrt(best_d.astype(np.float64)), best_j, np.sqrt(second_d.astype(np.float64)),
            (col_j if want_cols else None))


#: uint8 (N, B) descriptors are taken for a quantised histogram (SIFT stored as uint8, as COLMAP
#: does), not packed bits, when more than this share of their bytes is 0 and over half of them are
#: below `SMALL_BYTE`. Measured on the demo frame: ORB (OpenCV's and geofeat's), GeoBit (any one
#: rotation) and random bytes have 0.3-0.7 % zero bytes and a median byte of 127-145; SIFT stored as
#: uint8 (OpenCV's values cast, COLMAP's L2 or L1-root x 512) 25 % zero bytes and a median of 5-23.
ZERO_BYTES_NOT_BITS = 0.1
SMALL_BYTE = 64


def quantised_zero_share(descriptors: np.ndarray) -> float | None:
    """The share of zero bytes of uint8 `descriptors` that look like a quantised histogram rather than
    packed bits (`ZERO_BYTES_NOT_BITS`, `SMALL_BYTE`); None when they look like bits, are not uint8,
    are empty, or hold only 0 and 1 (unpacked bits, for which Hamming over bytes is exact)."""
    d = np.asarray(descriptors)
    if d.dtype != np.uint8 or not d.size or d.max() <= 1:
        return None
    zeros = np.count_nonzero(d == 0) / d.size
    small = np.count_nonzero(d < SMALL_BYTE) / d.size
    return float(zeros) if zeros > ZERO_BYTES_NOT_BITS and small > 0.5 else None


def metric_of_pair(d0: np.ndarray, d1: np.ndarray, names: tuple[str, str] = ("features0", "features1"),
                   valid: tuple[np.ndarray, np.ndarray] | None = None) -> str:
    """The metric `match` chooses for two descriptor arrays (from the dtype and rank), which must be of
    one kind: float against uint8 bits has no common distance. ValueError naming both otherwise.
    A UserWarning when uint8 (N, B) descriptors, matched by Hamming, look like a quantised histogram
    (`quantised_zero_share`, over the rows `valid` (N0,), (N1,) bool; None: all) rather than packed
    bits: SIFT stored as uint8 wants metric "l2"."""
    metric = _default_metric(d0)
    if _default_metric(d1) != metric:  # e.g. float GeoPatch against uint8 ORB
        raise ValueError(f"descriptors: {names[0]} ({d0.dtype}) and {names[1]} ({d1.dtype}) are of different kinds; "
                         "use descriptors of one type, or pass metric=")
    if metric == "hamming":
        rows = (d0, d1) if valid is None else (d0[np.asarray(valid[0], bool)], d1[np.asarray(valid[1], bool)])
        zeros = quantised_zero_share(np.concatenate(rows))
        if zeros is not None:
            warnings.warn(f"descriptors: uint8 {names[0]} and {names[1]} have {zeros:.0%} zero bytes and mostly "
                          f"small values, as a quantised histogram (SIFT stored as uint8) has, not packed bits "
                          f"(about 0.4 % zero bytes), and are matched by Hamming distance; pass metric=\"l2\" to "
                          f"match them as vectors (or metric=\"hamming\", if they are bits, to silence this)",
                          UserWarning, stacklevel=3)
    return metric


def check_finite_descriptors(descriptors: np.ndarray, valid: np.ndarray | None = None, name: str = "descriptors") -> None:
    """Float (N, ...) descriptors must be finite at every valid keypoint (`valid` (N,) bool; None: all):
    a NaN distance matches nothing or anything, without a word. ValueError naming the rows otherwise."""
    d = np.asarray(descriptors)
    if d.dtype.kind != "f" or d.size == 0:
        return
    finite = np.isfinite(d.reshape(len(d), -1)).all(axis=1)
    bad = np.flatnonzero(~finite if valid is None else (valid & ~finite))
    if len(bad):
        raise ValueError(f"descriptors: {name} has NaN or infinite values at valid keypoints "
                         f"{bad[:5].tolist()}{' ...' if len(bad) > 5 else ''}; mark them invalid or drop them")


def check_l2_range(pairs, largest: float, what: str, hint: str = "") -> None:
    """ValueError unless the squared L2 distances of float (N, D) descriptors stay below `largest`.
    `pairs`: (descriptors, valid (N,) bool or None for all rows, name) for each side; `what` names
    what overflows and `hint` ends the message. |a - b|^2 and the terms |a|^2 + |b|^2 - 2 a.b it is
    computed from, of the descriptors less their mean, stay below 16 times the largest squared norm
    of a valid row; past the float type's range they were inf and NaN, with only numpy's
    RuntimeWarning, and no keypoint was matched (or any was)."""
    norms = []
    for d, valid, name in pairs:
        d = np.asarray(d)
        if d.size and d.ndim == 2:  # quick bound first (no copy): D x the largest square bounds every row's norm
            with np.errstate(over="ignore"):
                peak = float(np.abs(d).max())
            if 16.0 * d.shape[1] * peak * peak < largest:
                continue
        rows = d[slice(None) if valid is None else np.asarray(valid, bool)].astype(np.float64)
        if rows.size:
            with np.errstate(over="ignore"):  # a square past float64's range is inf: refused below
                norms.append((float(np.einsum("ij,ij->i", rows, rows).max()), name))
    norm, name = max(norms, key=lambda pair: pair[0], default=(0.0, ""))
    if not 16.0 * norm < largest:
        raise ValueError(f"descriptors: {name} has a row of squared norm {norm:.3g}: its squared L2 distances (up to "
                         f"16 times that) overflow {what}; scale the descriptors down (divide them by their largest "
                         f"norm){hint}")


#: `warn_if_scales_differ` warns when the median norms of two float descriptor sets differ by more than this factor.
MAX_NORM_RATIO = 10.0


#: Rows per side whose norms `warn_if_scales_differ` takes the median of (evenly spaced valid rows): every
#: row's took about 4 ms per side pair for 2048 x 128 descriptors, as long as the L2 match itself.
NORM_CHECK_ROWS = 256


def check_same_method(features0, features1, names: tuple[str, str] = ("features0", "features1")) -> None:
    """ValueError when two feature sets record different descriptors (`Features.method`): ORB's and
    BRAND's descriptors are both (N, 32) uint8, GeoPatch's and SIFT's (N, 128) float32, and were matched
    without a word. Sets that record none (bare arrays, features from other tools) are not checked."""
    methods = [getattr(f, "method", None) for f in (features0, features1)]
    if None not in methods and methods[0] != methods[1]:
        raise ValueError(f"{names[0]}, {names[1]}: descriptors of two methods ({methods[0]} and {methods[1]}); their "
                         "distances mean nothing: match features of one descriptor")


def warn_if_scales_differ(d0: np.ndarray, d1: np.ndarray, valid0: np.ndarray | None = None,
                          valid1: np.ndarray | None = None, names: tuple[str, str] = ("features0", "features1")) -> None:
    """Warn when the median L2 norms of the valid rows (`NORM_CHECK_ROWS` of them, evenly spaced) of float (N0, D) `d0` and (N1, D) `d1` (`valid0`,
    `valid1` (N,) bool; None: all) differ by more than `MAX_NORM_RATIO`: descriptors of two methods of one
    width (SIFT's norm is about 512, GeoPatch's and the image-patch nets' 1), or one set normalised and
    the other not. Their L2 distances then mostly measure the norms: each target's nearest query is
    the query of smallest norm, and the mutual matches are few and wrong, without a word."""
    medians = []
    for d, valid in ((d0, valid0), (d1, valid1)):
        d = np.asarray(d)
        index = np.arange(len(d)) if valid is None else np.flatnonzero(np.asarray(valid, bool))
        if not index.size or not d[:1].size:
            return
        rows = d[index[::max(1, len(index) // NORM_CHECK_ROWS)]]  # evenly spaced: a median, not every norm (hot path)
        medians.append(float(np.median(np.sqrt(np.einsum("ij,ij->i", rows, rows, dtype=np.float64)))))
    small, large = sorted(medians)
    if large > MAX_NORM_RATIO * small:
        warnings.warn(f"descriptors: the median norms of {names[0]} ({medians[0]:.3g}) and {names[1]} "
                      f"({medians[1]:.3g}) differ {large / small if small else np.inf:.3g} times: descriptors of two "
                      "methods (SIFT's norm is about 512, GeoPatch's 1), or one set normalised and the other not? "
                      "Their L2 distances mostly measure the norms; match descriptors of one method, normalised "
                      "alike", UserWarning, stacklevel=3)


def check_descriptor_length(shape: tuple[int, ...]) -> None:
    """ValueError unless descriptors of shape (N, ...) hold at least one value per keypoint: with none
    (an (N, 0) array, a slice past the end) every distance was 0, so each keypoint matched the first
    one of the other image, without a word."""
    if int(np.prod(shape[1:])) == 0:
        raise ValueError(f"descriptors: shape {tuple(shape)} holds no values per keypoint; expected descriptors "
                         "such as (N, 128) float or (N, 32) uint8")


def _unpack(x, which: str) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(x, Features):
        desc, valid = np.asarray(x.descriptors), np.asarray(x.valid, dtype=bool)
        if len({np.shape(x.keypoints)[:1], desc.shape[:1], valid.shape}) > 1:  # fields replaced after construction
            raise ValueError(f"{which}: keypoints, descriptors and valid must have one entry per keypoint, got "
                             f"shapes {np.shape(x.keypoints)}, {desc.shape} and {valid.shape}")
        return desc, valid
    if isinstance(x, np.ndarray):
        return x, np.ones(x.shape[0] if x.ndim else 0, bool)
    raise TypeError(f"{which}: expected a Features record or a descriptor array, got {type(x).__name__}")


def _default_metric(desc: np.ndarray) -> str:
    if desc.dtype.kind == "f":
        return "l2"
    if desc.dtype == np.uint8 and desc.ndim == 2:
        return "hamming"
    if desc.dtype == np.uint8 and desc.ndim == 3:
        return "hamming-rot"
    raise ValueError(
        f"descriptors: cannot choose a metric for dtype {desc.dtype} and shape {desc.shape}; expected "
        "float (N, D) for 'l2', uint8 (N, B) for 'hamming' or uint8 (N, R, B) for 'hamming-rot'"
    )


def check_match_options(ratio, mutual) -> None:
    """ValueError unless `ratio` is None or a number in (0, 1] and `mutual` a bool (`match` and
    `geofeat.gpu.match_cuda`): ratio=True would run as 1.0, and a truthy mutual="no" as mutual."""
    if ratio is not None and (isinstance(ratio, bool) or not isinstance(ratio, numbers.Real) or not 0 < ratio <= 1):
        raise ValueError(f"ratio: expected a number in (0, 1] or None, got {ratio!r}")
    check_bool(mutual, "mutual")


def match(
    features0: Features | np.ndarray,
    features1: Features | np.ndarray,
    metric: str | None = None,
    mutual: bool = False,
    ratio: float | None = None,
    device: str | None = None,
) -> Matches:
    """Match every keypoint of image 0 to its nearest neighbour in image 1.

    Args:
        features0, features1: `Features` records (or bare descriptor arrays, all valid) with
            descriptors of the same trailing shape: float (N, D), uint8 (N, B) or uint8 (N, R, B).
        metric: "l2", "hamming" or "hamming-rot"; None chooses from the descriptor dtype and rank.
        mutual: keep i -> j only if i is also the nearest neighbour of j among image 0's keypoints
            (under the same distance d(i, j)).
        ratio: Lowe's ratio test: keep i -> j only if d(i, j) < ratio * d(i, second nearest).
            A match with no second candidate passes. The second nearest is the best of the other
            valid targets, so a tie for the nearest (duplicate targets) fails the test at any ratio.
        device: None: the numba kernels (Hamming) and numpy (L2) on the CPU. A torch device
            ("cuda", "cuda:1", "cpu"): every metric as matrix products there (`_hamming_search_torch`,
            `_l2_search_torch`; the same matches). For descriptors already on the GPU see
            `geofeat.gpu.match_cuda`.

    Ties: the result is brute force's, on every path (numba, numpy, torch; any thread count, chunking
    or pruning): the nearest target is the lowest index among the valid targets at the smallest
    distance (``np.argmin`` of the row), and under ``mutual`` the nearest query of target j is the
    lowest index among the valid queries at its smallest distance (``np.argmin`` of the column).
    Hamming distances are exact integers; L2 ones are compared squared, which is exact for
    whole-number descriptors whose squared norms after the centring stay below 2**22 in float32
    (2**51 in float64), and otherwise rounded as the float32 (float64) matrix product rounds them:
    two identical non-whole-number descriptors in different blocks of 1024 queries can then differ
    in the last bit, so under ``mutual`` the later copy may win a column (computing each distinct
    descriptor once fixed that, and made L2 matching 2.5 times slower: not done).

    Float descriptors whose valid rows' median norms differ more than `MAX_NORM_RATIO` (10) times
    warn (`warn_if_scales_differ`): descriptors of two methods, or one set normalised and the other not.

    Two `Features` of different descriptors (`Features.method`, e.g. ORB's and BRAND's, both (N, 32)
    uint8) are a ValueError: their distances mean nothing.

    Returns:
        `Matches` with matches0 (N0,) int64 (-1 = no match) and distances0 (N0,) float64 (bits for
        Hamming metrics, Euclidean units for L2; inf where no match).
    """
    check_same_method(features0, features1)
    d0, valid0 = _unpack(features0, "features0")
    d1, valid1 = _unpack(features1, "features1")
    if d0.ndim < 2 or d1.ndim < 2:
        raise ValueError(
            f"descriptors: expected at least 2 dimensions (N, ...), got shapes {d0.shape} and {d1.shape}"
        )
    if d0.shape[1:] != d1.shape[1:]:
        raise ValueError(
            f"descriptors: trailing shapes differ: features0 {d0.shape} vs features1 {d1.shape}"
        )
    if len(d0) or len(d1):  # two empty sets match nothing, whatever their width
        check_descriptor_length(d0.shape)
    if metric is None:
        metric = metric_of_pair(d0, d1, valid=(valid0, valid1))
    if metric not in METRICS:
        raise ValueError(f"metric: expected one of {METRICS} or None, got {metric!r}")
    check_match_options(ratio, mutual)
    n0, n1 = d0.shape[0], d1.shape[0]
    if metric == "l2":
        if d0.ndim != 2:
            raise ValueError(f"descriptors: metric 'l2' expects (N, D) arrays, got shape {d0.shape}")
        if d0.dtype.kind not in "fiu" or d1.dtype.kind not in "fiu":
            raise TypeError(f"descriptors: metric 'l2' expects numeric arrays, got {d0.dtype} and {d1.dtype}")
        check_finite_descriptors(d0, valid0, "features0")
        check_finite_descriptors(d1, valid1, "features1")
    else:
        if d0.dtype != np.uint8 or d1.dtype != np.uint8:
            raise TypeError(
                f"descriptors: metric {metric!r} expects uint8 arrays of packed bits, got {d0.dtype} and {d1.dtype}"
            )
        want = 2 if metric == "hamming" else 3
        if d0.ndim != want:
            raise ValueError(
                f"descriptors: metric {metric!r} expects shape "
                f"{'(N, B)' if want == 2 else '(N, R, B)'}, got {d0.shape}"
            )
    if device is not None:
        from .gpu import torch_device

        dev = torch_device(device)
    if n0 == 0 or n1 == 0:
        return Matches(np.full(n0, -1, np.int64), np.full(n0, np.inf))
    if metric == "l2":  # in the dtype of the squared distances (`_l2_search`, `_l2_search_torch`)
        dtype = np.float64 if np.float64 in (d0.dtype, d1.dtype) else np.float32
        largest = float(np.finfo(dtype).max)
        check_l2_range(((d0, valid0, "features0"), (d1, valid1, "features1")), largest,
                       f"{np.dtype(dtype).name} (largest {largest:.3g})",
                       ", or pass them as float64" if dtype == np.float32 else "")
        warn_if_scales_differ(d0, d1, valid0, valid1)  # their norms are known to fit float64 now

    if metric == "l2" and device is not None:
        import torch

        best_d, best_j, second_d, col_j = _l2_search_torch(
            *(torch.from_numpy(np.ascontiguousarray(x)).to(dev) for x in (d0, d1, valid0, valid1)), mutual)
    elif metric == "l2":
        best_d, best_j, second_d, col_j = _l2_search(d0, d1, valid0, valid1, mutual)
    else:
        if metric == "hamming":
            d0, d1 = d0[:, None, :], d1[:, None, :]
        if device is not None:
            best_d, best_j, second_d, col_j = _hamming_search_torch(d0, d1, valid0, valid1, mutual, device)
        else:
            best_d, best_j, second_d, col_j = _hamming_search(d0, d1, valid0, valid1, mutual, ratio)

    return _finish_matches(best_d, best_j, second_d, col_j, ratio=ratio, mutual=mutual)


def _finish_matches(best_d, best_j, second_d, col_j, ratio: float | None, mutual: bool) -> Matches:
    """`Matches` from the nearest-neighbour search: ratio test and mutual check applied."""
    keep = best_j >= 0
    if ratio is not None:
        keep &= ~(best_d >= ratio * second_d)  # second = inf (single candidate) passes
    if mutual:
        ok = np.zeros(len(best_j), bool)
        idx = np.flatnonzero(keep)
        ok[idx] = col_j[best_j[idx]] == idx
        keep &= ok
    matches0 = np.where(keep, best_j, -1).astype(np.int64)
    distances0 = np.where(keep, best_d, np.inf)
    return Matches(matches0, distances0)


@njit(parallel=True, cache=True)
def _hamming_matrix8(q, t, out):
    """All (query, target) min-over-rotations Hamming distances for 512-bit descriptors.
    q: (N0, 8) uint64 (rotation 0); t: (N1, R, 8) uint64; out: (N0, N1) float32."""
    n0 = q.shape[0]
    n1 = t.shape[0]
    for i in prange(n0):
        q0, q1, q2, q3 = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        q4, q5, q6, q7 = q[i, 4], q[i, 5], q[i, 6], q[i, 7]
        for j in range(n1):
            m = _min_over_rotations8(q0, q1, q2, q3, q4, q5, q6, q7, t, j)
            out[i, j] = np.float32(m)


@njit(parallel=True, cache=True)
def _hamming_matrix(q, t, out):
    """`_hamming_matrix8` for any number of words. q: (N0, W); t: (N1, R, W) uint64."""
    n0, W = q.shape
    n1, R, _ = t.shape
    for i in prange(n0):
        for j in range(n1):
            m = _BIG
            for k in range(R):
                dk = np.uint64(0)
                for w in range(W):
                    dk += _popcount64(q[i, w] ^ t[j, k, w])
                m = min(m, dk)
            out[i, j] = np.float32(m)


def distance_matrix(descriptors0: np.ndarray, descriptors1: np.ndarray, metric: str | None = None,
                    valid0: np.ndarray | None = None, valid1: np.ndarray | None = None) -> np.ndarray:
    """All pairwise descriptor distances, with the same metrics as `match`.

    Args:
        descriptors0: (N0, D) float, (N0, B) uint8 or (N0, R, B) uint8 descriptors.
        descriptors1: (N1, ...) descriptors of the same trailing shape.
        metric: "l2", "hamming" or "hamming-rot" (GeoBit: d(i, j) = min over rotations k of
            Hamming(descriptors0[i, 0], descriptors1[j, k])); None chooses from dtype and rank.
        valid0, valid1: (N0,), (N1,) bool, the keypoints whose descriptors are used (None: all); the
            distances of the others are returned as computed (NaN for a NaN descriptor), for the
            caller to mask.

    Returns:
        (N0, N1) float32 distances (bits for the Hamming metrics, Euclidean units for L2).

    Float descriptors must be (N, D) and finite at the valid keypoints, as for `match` (ValueError
    otherwise).
    """
    d0, d1 = np.asarray(descriptors0), np.asarray(descriptors1)
    if d0.ndim < 2 or d1.ndim < 2 or d0.shape[1:] != d1.shape[1:]:
        raise ValueError(f"descriptors: expected (N, ...) arrays of the same trailing shape, got {d0.shape} and {d1.shape}")
    if len(d0) or len(d1):
        check_descriptor_length(d0.shape)
    if metric is None:
        metric = metric_of_pair(d0, d1, ("descriptors0", "descriptors1"))
    if metric not in METRICS:
        raise ValueError(f"metric: expected one of {METRICS} or None, got {metric!r}")
    if metric == "l2":
        if d0.ndim != 2:  # as `match`; einsum failed with "operand has more dimensions than subscripts"
            raise ValueError(f"descriptors: metric 'l2' expects (N, D) arrays, got shape {d0.shape}")
        # as `match`: a NaN row gave NaN distances, which np.argmin reads as the smallest (every query's nearest)
        for d, valid, name in ((d0, valid0, "descriptors0"), (d1, valid1, "descriptors1")):
            if valid is not None and np.shape(valid) != d.shape[:1]:
                raise ValueError(f"valid{name[-1]}: expected one flag per row of {name} ({len(d)},), got shape "
                                 f"{np.shape(valid)}")
            check_finite_descriptors(d, None if valid is None else np.asarray(valid, bool), name)
        # squared in float64, returned in float32: the distances must fit float32
        largest = float(np.finfo(np.float32).max)
        check_l2_range(((d0, valid0, "descriptors0"), (d1, valid1, "descriptors1")), largest ** 2,
                       f"the float32 distance matrix (distances up to {largest:.3g})")
        warn_if_scales_differ(d0, d1, valid0, valid1, ("descriptors0", "descriptors1"))
        a, b = d0.astype(np.float64), d1.astype(np.float64)
        dist2 = np.einsum("ij,ij->i", a, a)[:, None] + np.einsum("ij,ij->i", b, b)[None, :] - 2.0 * (a @ b.T)
        return np.sqrt(np.maximum(dist2, 0.0)).astype(np.float32)
    if d0.dtype != np.uint8 or d1.dtype != np.uint8 or d0.ndim != (2 if metric == "hamming" else 3):
        raise ValueError(f"descriptors: metric {metric!r} expects uint8 {'(N, B)' if metric == 'hamming' else '(N, R, B)'}"
                         f" arrays, got {d0.dtype} {d0.shape}")
    if metric == "hamming":
        d0, d1 = d0[:, None, :], d1[:, None, :]
    q = np.ascontiguousarray(_as_words(d0[:, 0, :]))  # (N0, W)
    t = np.ascontiguousarray(_as_words(d1))  # (N1, R, W)
    out = np.empty((len(q), len(t)), np.float32)
    if len(q) and len(t):
        W = q.shape[1]
        if W <= 8:
            q = np.concatenate([q, np.zeros((len(q), 8 - W), np.uint64)], axis=1)
            t = np.concatenate([t, np.zeros(t.shape[:2] + (8 - W,), np.uint64)], axis=2)
            _hamming_matrix8(q, t, out)
        else:
            _hamming_matrix(q, t, out)
    return out
