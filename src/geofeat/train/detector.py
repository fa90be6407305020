"""Training GeoKey (`geofeat train-detector`) on simulated sequences with exact correspondences.

Training signal (per candidate, from the simulator's dense ground truth): a candidate corner of
frame A is *repeatable* when its surface point is visible in frame B and B's own candidates include
one within `match_px` pixels of where that point lands: a corner found again at the same surface
point, with occlusion, self-occlusion, foreshortening and folds all taken into account by the
simulator (the shipped weights use these labels). With `labels="matchable"` it must also be
*matched*: its GeoPatch descriptor's nearest neighbour among all of B's candidates lies within the
protocol's 3 px of where the point lands (SiLK's idea of scoring a pixel by whether its descriptor
finds its partner, with the descriptor fixed and the correspondences exact). The scorer (linear in
the image cues, optionally plus a small MLP of the depth cues) is fitted with a binary
cross-entropy, which learns in a couple of minutes on a CPU; the scorer and the suppression radius
are then chosen on the validation sequences by GeoPatch's matching score.

Every pair (reference, target) and its reverse contributes, so the scorer sees both directions of
each deformation, scale change and roll.
"""

from __future__ import annotations

import numbers
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from tqdm import tqdm

from ..detectors.cues import CUE_NAMES, IMAGE_CUES
from ..detectors.geokey import GeoKeyModel, candidate_features, candidates, detect_geokey, detection_image
from ..inputs import check_non_negative, check_whole
from ..io import Sequence, read_sequence
from ..outputs import plural
from ..scoring import GT_THRESHOLD_PX, ground_truth_pairs
from .dataset import check_simulated, warn_if_not_held_out

#: A candidate is found again when another view's candidate lies within this many pixels.
MATCH_PX = 1.0
#: Suppression radii tried on the validation data, pixels.
NMS_CHOICES = (2.0, 3.0, 4.0, 5.0)
#: Keypoints per frame at which the validation scores each (scorer, radius): the choice maximises the
#: mean matching score over these counts, so that no radius wins by being good at one count only
#: (at 1024 keypoints radii 2 and 4 tie; at 2048, 2 px packs the keypoints so densely that the
#: descriptor confuses neighbours within the protocol's 3 px).
VALIDATION_COUNTS = (1024, 2048)
#: Logit offsets tried on validation for the half-resolution candidates, after the radius: the
#: training label (found again within 1 px among the other view's candidates) does not say how
#: much less often half-resolution corners end up matched within the protocol's 3 px.
LEVEL_BIASES = (0.0, -0.5, -1.0, -1.5)
#: Score thresholds (logits) tried on validation last: a detector that stops at a score, as SIFT stops
#: at a contrast, returns fewer keypoints on a frame with little good surface (a far or crumpled
#: cloth). -inf keeps the n best whatever their score.
THRESHOLDS = (-np.inf, 0.0, 0.25, 0.5, 0.75, 1.0)
#: A threshold is admissible only when, at every validation count, it leaves at least as many
#: reference keypoints per frame as SIFT (the protocol's detector, which stops at its contrast
#: threshold) and gives at least SIFT + GeoPatch's correct matches per pair; and, at the largest
#: count, at least this many reference keypoints per frame. The matching score rises as keypoints
#: are dropped, so without these the highest threshold would always win.
MIN_KEYPOINTS = 1000
#: The floor that goes with a chosen threshold: the best this fraction of a frame's candidates (after
#: suppression) are kept whatever their score. A design constant, not chosen on validation, which
#: cannot show what it guards against: the threshold is calibrated on renders, and real images score
#: lower overall. On the shipped Kinect frame 881 of 5538 candidates reach a logit of 0.5, against
#: 3220 of 5304 on a `paper` render; its rolled pair then gets 881 / 714 keypoints and 648 correct
#: GeoPatch matches at n = 2048, against SIFT's 1482. With the floor: 1938 / 1890 keypoints and 1425.
#: It costs 0.006 of the mean validation MS (BENCHMARKS.md, "GeoKey v3.3").
KEEP_FRACTION = 0.35


#: The detectors' own warnings about a frame ("geokey: no candidate reaches the score threshold ...", "geokey:
#: only 5 % of this frame's keypoints are stronger corners than its image noise", "sift: no keypoint ..."), left
#: out while validation tries settings (`quiet_detectors`): a frame without keypoints at a threshold on trial
#: says nothing about the data, yet read as a problem with it.
DETECTOR_WARNINGS = r"(geokey|sift): "


@contextmanager
def quiet_detectors() -> Iterator[None]:
    """Within it, the detectors' warnings about a frame (`DETECTOR_WARNINGS`) are not shown; others are."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=DETECTOR_WARNINGS, category=UserWarning)
        yield


#: Training labels: "repeatable" (found again) or "matchable" (found again and matched by GeoPatch).
LABELS = ("repeatable", "matchable")


@dataclass
class FrameCandidates:
    xy: np.ndarray                 # (N, 2) pixels
    features: np.ndarray           # (N, D) float32 cues
    descriptors: np.ndarray | None  # (N, 128) float32 GeoPatch descriptors (NaN rows where invalid)


def _frame_candidates(seq: Sequence, name: str, descriptor=None, denoise: float = 0.0) -> FrameCandidates:
    """The candidates of frame `name` and their cues, found on GeoKey's detection image (`denoise`,
    `detection_image`), and their descriptors on the frame itself."""
    frame = seq.frame(name)
    seen = detection_image(frame, denoise)
    cands = candidates(seen)
    desc = None
    if descriptor is not None and len(cands):
        f = descriptor.compute(frame, cands.xy)
        desc = np.where(f.valid[:, None], f.descriptors, np.nan).astype(np.float32)
    return FrameCandidates(cands.xy, candidate_features(seen, cands), desc)


def _nearest_descriptor(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    """(Na,) index of the L2-nearest row of db for each row of da (-1 where a row is invalid)."""
    ok_a, ok_b = np.isfinite(da).all(axis=1), np.isfinite(db).all(axis=1)
    nn = np.full(len(da), -1, np.int64)
    if ok_a.any() and ok_b.any():
        ib = np.flatnonzero(ok_b)
        sim = da[ok_a] @ db[ib].T  # unit-length descriptors: the largest dot product is the nearest
        nn[ok_a] = ib[np.argmax(sim, axis=1)]
    return nn


def sequence_samples(seq: Sequence, match_px: float = MATCH_PX, labels: str = "repeatable",
                     descriptor=None, max_targets: int | None = None, denoise: float = 0.0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Features (M, D) float32 and labels (M,) float32 in {0, 1} of every candidate of every
    (reference, target) pair of a simulated sequence, in both directions.

    Args:
        labels: "repeatable" or "matchable" (see the module docstring).
        descriptor: the `Descriptor` that decides "matchable" (default: the shipped GeoPatch with the
            sequence's radius and depth profile).
        max_targets: use only the first this many target frames (None: all).
        denoise: GeoKey's `denoise` setting the candidates and cues are found with.
    """
    if not seq.has_ground_truth():
        raise ValueError(f"data: {seq.folder} has no simulator ground truth (geofeat simulate writes it)")
    if labels not in LABELS:
        raise ValueError(f"labels: expected one of {', '.join(LABELS)}, got {labels!r}")
    if labels == "matchable" and descriptor is None:
        from ..depth import PROFILES, sequence_depth_profile
        from ..descriptors import make_descriptor

        profile = sequence_depth_profile(seq)
        descriptor = make_descriptor("geopatch", radius=seq.radius, depth_config=PROFILES[profile])
    if labels == "repeatable":
        descriptor = None
    targets = seq.targets[:max_targets] if max_targets else seq.targets
    frames = {name: _frame_candidates(seq, name, descriptor, denoise) for name in [seq.reference, *targets]}
    xs, ys = [], []
    for target in targets:
        for a, b in ((seq.reference, target), (target, seq.reference)):
            ca, cb = frames[a], frames[b]
            if len(ca.xy) == 0:
                continue
            mapped, visible = seq.correspondences(a, b, ca.xy)
            label = np.zeros(len(ca.xy), np.float32)
            if len(cb.xy) and visible.any():
                dist, _ = cKDTree(cb.xy).query(mapped[visible], k=1)
                found = dist <= match_px
                if descriptor is not None:
                    nn = _nearest_descriptor(ca.descriptors[visible], cb.descriptors)
                    landed = np.linalg.norm(cb.xy[np.maximum(nn, 0)] - mapped[visible], axis=1)
                    found &= (nn >= 0) & (landed < GT_THRESHOLD_PX)
                label[visible] = found.astype(np.float32)
            xs.append(ca.features)
            ys.append(label)
    if not xs:
        return np.zeros((0, len(CUE_NAMES)), np.float32), np.zeros(0, np.float32)
    return np.concatenate(xs), np.concatenate(ys)


def collect(folders: list[Path], labels: str = "repeatable", max_targets: int | None = None,
            progress: bool = True, denoise: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """`sequence_samples` of every simulated sequence under `folders`, concatenated."""
    xs, ys = [], []
    for folder in tqdm(folders, desc="candidates", unit="seq", disable=not progress):
        x, y = sequence_samples(read_sequence(folder), labels=labels, max_targets=max_targets, denoise=denoise)
        xs.append(x)
        ys.append(y)
    return np.concatenate(xs), np.concatenate(ys)


def fit(x: np.ndarray, y: np.ndarray, hidden: tuple[int, ...] | None = (32, 32), steps: int = 3000,
        batch: int = 4096, lr: float = 3e-3, seed: int = 0, device: str | None = None,
        progress: bool = True) -> GeoKeyModel:
    """Fit the scorer (linear in the image cues + an MLP of the depth cues) with a binary
    cross-entropy (torch, CPU or the GPU when present).

    Args:
        x: (M, D) cue features (`CUE_NAMES` order); y: (M,) labels in {0, 1}.
        hidden: widths of the depth-cue MLP's hidden layers; None: no MLP (a linear image score).
        steps, batch, lr: Adam iterations, minibatch size, learning rate.
        seed: the same seed gives the same weights (on the same device).
    """
    import torch

    if len(x) == 0:
        raise ValueError("data: no training candidates (are the sequences empty?)")
    from ..gpu import torch_device

    # `is None`, not falsy: device=0 (torch's cuda:0) trained on the CPU without a word
    device = torch_device(device if device is not None else ("cuda" if torch.cuda.is_available() else "cpu"))
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    mean = x.mean(axis=0).astype(np.float32)
    std = (x.std(axis=0) + 1e-6).astype(np.float32)
    xt = torch.from_numpy((x - mean) / std).to(device)
    yt = torch.from_numpy(y.astype(np.float32)).to(device)
    n_image = len(IMAGE_CUES)
    linear = torch.nn.Linear(n_image, 1, bias=False).to(device)
    widths = (x.shape[1] - n_image, *hidden, 1) if hidden is not None else ()
    layers: list = [torch.nn.Identity()]
    for k in range(len(widths) - 1):
        layers.append(torch.nn.Linear(widths[k], widths[k + 1]))
        if k < len(widths) - 2:
            layers.append(torch.nn.ReLU())
    mlp = torch.nn.Sequential(*layers).to(device)
    opt = torch.optim.Adam([*linear.parameters(), *mlp.parameters()], lr=lr)
    if hidden is None:
        opt = torch.optim.Adam(linear.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    loss_fn = torch.nn.BCEWithLogitsLoss()
    bar = tqdm(range(steps), desc="train-detector", unit="step", disable=not progress)
    for step in bar:
        idx = torch.from_numpy(rng.integers(0, len(x), batch)).to(device)
        xb = xt[idx]
        logit = linear(xb[:, :n_image])[:, 0]
        if hidden is not None:
            logit = logit + mlp(xb[:, n_image:])[:, 0]
        loss = loss_fn(logit, yt[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % 200 == 0:
            bar.set_postfix(loss=f"{loss.item():.4f}")
    linears = [m for m in mlp if isinstance(m, torch.nn.Linear)]
    weights = tuple(m.weight.detach().cpu().numpy().T.copy() for m in linears)
    biases = tuple(m.bias.detach().cpu().numpy().copy() for m in linears)
    return GeoKeyModel(mean, std, linear.weight.detach().cpu().numpy()[0].copy(), weights, biases)


def validation_scores(folders: list[Path], detector, n: int, descriptor: str | None = "geopatch",
                      progress: bool = False) -> dict:
    """The protocol's figures of a detector on simulated sequences (means over sequences of the
    per-sequence means over (reference, target) pairs).

    For each pair: the detector's n keypoints in both frames, reference keypoints off the visible
    surface dropped, target keypoints whose surface point is not visible in the reference dropped;
    ground-truth pairs < 3 px (the protocol's rule). repeatability = ground-truth pairs /
    min(n_ref, n_tgt) (the MS of a perfect descriptor); with `descriptor` (a `make_descriptor` name,
    described with each sequence's radius and depth profile), also its MS, MMA and hits.

    Args:
        detector: callable (frame, n) -> Keypoints.
        descriptor: None for repeatability only (fast).

    Returns:
        {"repeatability", "ms", "mma", "hits" (per pair), "pairs" (ground-truth pairs per pair),
        "n_ref" (reference keypoints kept)}.
    """
    from ..depth import PROFILES, sequence_depth_profile
    from ..descriptors import make_descriptor
    from ..matching import match
    from ..scoring import score_detect

    keys = ("repeatability", "ms", "mma", "hits", "pairs", "n_ref")
    per_seq = []
    for folder in tqdm(folders, desc="validation", unit="seq", disable=not progress):
        seq = read_sequence(folder)
        ref_frame = seq.frame(seq.reference)
        describe = None
        if descriptor:
            profile = sequence_depth_profile(seq, None, ref_frame)
            describe = make_descriptor(descriptor, radius=seq.radius, depth_config=PROFILES[profile]).compute
        ref = detector(ref_frame, n).xy
        ref = ref[seq.correspondences(seq.reference, seq.reference, ref)[1]]
        f_ref = describe(ref_frame, ref) if describe is not None and len(ref) else None
        rows = []
        for target in seq.targets:
            frame = seq.frame(target)
            tgt = detector(frame, n).xy
            mapped, visible = seq.correspondences(target, seq.reference, tgt)
            tgt, mapped = tgt[visible], mapped[visible]
            pairs = ground_truth_pairs(ref, mapped)
            denom = min(len(ref), len(tgt))
            row = [len(pairs) / denom if denom else 0.0, np.nan, np.nan, np.nan, len(pairs), len(ref)]
            if f_ref is not None and len(tgt):
                s = score_detect(match(f_ref, describe(frame, tgt)).matches0, pairs, len(ref), len(tgt))
                row[1:4] = [s.ms, s.mma, s.hits]
            elif describe is not None:  # no keypoint on one side: the pair scores 0, as in the bench (not NaN)
                row[1:4] = [0.0, 0.0, 0]
            rows.append(row)
        per_seq.append(np.mean(rows, axis=0))
    means = np.mean(per_seq, axis=0)
    return {k: float(v) for k, v in zip(keys, means)}


def repeatability(folders: list[Path], detector, n: int, progress: bool = False) -> dict:
    """`validation_scores` without a descriptor: repeatability, ground-truth pairs, n_ref."""
    return validation_scores(folders, detector, n, descriptor=None, progress=progress)


def choose_model(models: dict[str, GeoKeyModel], folders: list[Path], counts: tuple[int, ...] = VALIDATION_COUNTS,
                 radii: tuple[float, ...] = NMS_CHOICES, level_biases: tuple[float, ...] = LEVEL_BIASES,
                 thresholds: tuple[float, ...] = THRESHOLDS, keep_fraction: float = KEEP_FRACTION,
                 progress: bool = True) -> tuple[GeoKeyModel, dict, tuple]:
    """The scorer, suppression radius, level-1 bias and score threshold with the best validation
    matching score of the shipped GeoPatch, averaged over the keypoint counts `counts` (denser
    keypoints are more repeatable but harder to tell apart).

    Three stages: every (scorer, radius) with no threshold; then, for the best of those, each logit
    offset of `level_biases` on the half-resolution candidates (`with_level_bias`); then, for the
    best so far, each score threshold of `thresholds` that is admissible against SIFT on the same
    sequences (`admissible_threshold`; SIFT's own figures are in the results as ("SIFT (reference)",
    0.0)). The admissible entry with the best mean MS is kept. When it has a threshold, the model
    also keeps the best `keep_fraction` of each frame's candidates whatever their score
    (`GeoKeyModel.min_fraction`; see `KEEP_FRACTION`).

    The detectors' warnings about single frames are left out while the settings are tried
    (`quiet_detectors`); `frames_without_keypoints` reports, once, those that the chosen model leaves empty.

    Returns the chosen model (its `nms_radius`, bias, `threshold` and `min_fraction` set), {(label,
    radius): {count: validation_scores}}, label = the scorer's name, plus ", level 1 <bias>" for the
    second stage and ", threshold <t>" for the third, and the chosen (label, radius).
    """
    counts = check_counts(counts)
    radii = check_radii(radii)
    results: dict = {}
    candidates_by_key: dict = {}
    models = {name: replace(m, threshold=-np.inf, min_fraction=0.0) for name, m in models.items()}  # no rule yet

    def score(label: str, model: GeoKeyModel, radius: float) -> None:
        per_count = {}
        for n in counts:
            with quiet_detectors():  # frames without keypoints at a setting on trial: `frames_without_keypoints`
                per_count[int(n)] = validation_scores(
                    folders, lambda f, k, m=model, r=radius: detect_geokey(f, k, m, nms_radius=r), int(n))
            if progress:
                r = per_count[int(n)]
                tqdm.write(f"validation {label}, NMS {radius:g} px, {n} keypoints: MS {r['ms']:.3f}, "
                           f"MMA {r['mma']:.3f}, repeatability {r['repeatability']:.3f}")
        results[(label, radius)] = per_count
        candidates_by_key[(label, radius)] = model

    for name, model in models.items():
        for radius in radii:
            score(name, model, radius)
    name, radius = max(results, key=lambda key: mean_ms(results[key]))
    for bias in level_biases:
        if bias != 0.0:
            score(f"{name}, level 1 {bias:+g}", with_level_bias(models[name], bias), radius)
    label, radius = max(results, key=lambda key: mean_ms(results[key]))
    best = replace(candidates_by_key[(label, radius)], nms_radius=radius)
    chosen = (label, radius)
    finite = [t for t in thresholds if np.isfinite(t)]
    if finite:
        from ..keypoints import detect_sift

        with quiet_detectors():
            sift = {int(n): validation_scores(folders, detect_sift, int(n)) for n in counts}
        results[SIFT_KEY] = sift
        admissible = [chosen]
        for t in finite:
            key = (f"{label}, threshold {t:g}", radius)
            score(key[0], replace(best, threshold=float(t)), radius)
            if admissible_threshold(results[key], sift):
                admissible.append(key)
        chosen = max(admissible, key=lambda key: mean_ms(results[key]))
        if chosen != admissible[0]:
            best = replace(candidates_by_key[chosen], min_fraction=keep_fraction)
    return best, results, chosen


def frames_without_keypoints(folders: list[Path], detector) -> tuple[list[str], int]:
    """The frames of the sequences `folders` (reference and targets, as `validation_scores` reads them)
    on which `detector` (callable (frame, n) -> Keypoints; n = 0: all) finds no keypoint, as
    "sequence/frame" names, and the number of frames; the detectors' warnings are left out (this list
    reports them once, `train_detector`)."""
    empty, total = [], 0
    with quiet_detectors():
        for folder in folders:
            seq = read_sequence(folder)
            for name in (seq.reference, *seq.targets):
                total += 1
                if len(detector(seq.frame(name), 0)) == 0:
                    empty.append(f"{Path(folder).name}/{name}")
    return empty, total


def check_radii(radii) -> tuple[float, ...]:
    """Suppression radii to try, pixels, as a tuple: one or more finite numbers >= 0; ValueError
    naming `radii` otherwise (none to try failed as "max() arg is an empty sequence" after training)."""
    if isinstance(radii, numbers.Real):
        radii = (radii,)
    if isinstance(radii, (str, bytes)) or not len(radii):
        raise ValueError(f"radii: expected one or more suppression radii in pixels, got {radii!r}")
    return tuple(check_non_negative(r, "radii") for r in radii)


def check_counts(counts: int | tuple[int, ...]) -> tuple[int, ...]:
    """Validation keypoint counts as a tuple: one or more positive whole numbers."""
    if isinstance(counts, (numbers.Integral, str)):  # one count (numpy's too); a string is not a sequence of them
        counts = (counts,)
    if not counts:
        raise ValueError(f"keypoints: expected positive counts, got {counts}")
    return tuple(check_whole(n, "keypoints", 1) for n in counts)


#: The key of SIFT's own validation figures in `choose_model`'s results.
SIFT_KEY = ("SIFT (reference)", 0.0)


def admissible_threshold(per_count: dict, sift: dict, min_keypoints: int = MIN_KEYPOINTS) -> bool:
    """True when a thresholded detector's validation figures (`{count: validation_scores}`) keep, at
    every count, at least SIFT's reference keypoints per frame and SIFT + GeoPatch's correct matches
    per pair (`sift`, same form), and at least `min_keypoints` reference keypoints at the largest count."""
    largest = max(per_count)
    return (all(per_count[n]["n_ref"] >= sift[n]["n_ref"] and per_count[n]["hits"] >= sift[n]["hits"]
                for n in per_count)
            and per_count[largest]["n_ref"] >= min(min_keypoints, largest))


def with_level_bias(model: GeoKeyModel, bias: float) -> GeoKeyModel:
    """`model` with `bias` added to the logit of every half-resolution (level 1) candidate,
    relative to the full-resolution ones (a change of the linear weight of the standardised
    "level" cue)."""
    k = CUE_NAMES.index("level")
    linear = model.linear.copy()
    linear[k] += np.float32(bias) * model.std[k]
    return replace(model, linear=linear)


def mean_ms(per_count: dict) -> float:
    """Mean validation matching score over the keypoint counts of one (scorer, radius) entry."""
    return float(np.mean([r["ms"] for r in per_count.values()]))


def train_detector(data, val, out: str | Path, n: int | tuple[int, ...] = VALIDATION_COUNTS, hidden: tuple[int, ...] = (32, 32),
                   steps: int = 3000, seed: int = 0, labels: str = "repeatable",
                   radii: tuple[float, ...] = NMS_CHOICES, progress: bool = True,
                   overwrite: bool = False, names: tuple[str, str] = ("data", "val"), denoise: float = 0.0,
                   ) -> tuple[GeoKeyModel, dict, tuple]:
    """Collect candidates from `data`, fit two scorers (image cues only, and image + depth cues),
    choose the scorer, the suppression radius, the level-1 bias and the score threshold on `val` by
    GeoPatch's matching score (mean over the keypoint counts `n`; `choose_model`), and write the
    weights to `out` (written whole or not at all; an existing file only with `overwrite`). The
    options are checked before any work; errors and warnings name `data` and `val` by `names` (the
    command line passes its flags). Returns the model, the validation figures per (scorer, radius)
    and count, and the chosen (scorer, radius) key. `denoise`: GeoKey's edge-preserving filter
    (`GeoKeyModel.denoise`), applied to the training candidates and written with the weights. The
    validation frames on which the chosen model finds no keypoint are warned of once (the detectors'
    own warnings are left out while validation tries settings)."""
    from ..outputs import check_out_file

    out = check_out_file(out, overwrite)
    n = check_counts(n)
    check_whole(steps, "steps", 1)  # Adam steps
    check_whole(seed, "seed", 0)  # numpy's "expected non-negative integer", after the candidates were collected
    denoise = check_non_negative(denoise, "denoise")
    if labels not in LABELS:
        raise ValueError(f"labels: expected one of {', '.join(LABELS)}, got {labels!r}")
    radii = check_radii(radii)
    if hidden is not None and (isinstance(hidden, (str, bytes)) or not hidden
                               or any(isinstance(h, bool) or not isinstance(h, numbers.Integral) or h < 1
                                      for h in hidden)):  # 2.5 failed in torch after the candidates were collected
        raise ValueError(f"hidden: expected positive whole layer widths, got {hidden!r}")
    data_name, val_name = names
    train_folders = check_simulated(data, data_name)  # ground truth in every one, before training
    val_folders = check_simulated(val, val_name)
    if not train_folders:
        raise ValueError(f"{data_name}: no sequences under {data}")
    if not val_folders:
        raise ValueError(f"{val_name}: no sequences under {val}")
    warn_if_not_held_out(train_folders, val_folders, val_name, data_name)
    x, y = collect(train_folders, labels, progress=progress, denoise=denoise)
    check_labels(y, labels, data_name)
    if progress:
        tqdm.write(f"train-detector: {plural(len(x), 'candidate')} from {plural(len(train_folders), 'sequence')}, "
                   f"{y.mean():.3f} positive ({labels})")
    models = {"image cues": fit(x, y, hidden=None, steps=steps, seed=seed, progress=progress),
              "image + depth cues": fit(x, y, hidden=hidden, steps=steps, seed=seed, progress=progress)}
    models = {name: replace(m, denoise=denoise) for name, m in models.items()}
    model, results, chosen = choose_model(models, val_folders, n, radii, progress=progress)
    empty, total = frames_without_keypoints(val_folders, lambda frame, k: detect_geokey(frame, k, model))
    if empty:  # said once here, not by a warning per frame and setting tried
        warnings.warn(f"{val_name}: {len(empty)} of the {plural(total, 'validation frame')} "
                      f"{'has' if len(empty) == 1 else 'have'} no GeoKey keypoint at the chosen setting ({chosen[0]}, "
                      f"NMS {chosen[1]:g} px): {', '.join(empty[:5])}{', ...' if len(empty) > 5 else ''}; "
                      "frames without texture or depth?", UserWarning, stacklevel=2)
    if not any(mean_ms(per_count) > 0 for key, per_count in results.items() if key != SIFT_KEY):
        # every entry tied at 0, and `max` kept the first: the weights were written as if validation had chosen them
        warnings.warn(f"{val_name}: no scorer and radius got a correct GeoPatch match on any validation pair (MS 0 "
                      f"throughout), so the choice ({chosen[0]}, NMS {chosen[1]:g} px) is arbitrary, not chosen by "
                      f"validation; larger or more textured {val_name} sequences give pairs", UserWarning, stacklevel=2)
    model.save(out)  # whole or not at all
    return model, results, chosen


def check_labels(y: np.ndarray, labels: str, data_name: str = "data") -> None:
    """ValueError naming `data_name` when the (M,) training labels `y` cannot train a scorer: no
    candidate at all, or candidates all of one label (none found again, or every one), from which
    the cross-entropy learns no ranking (it was fitted anyway, and the weights written as if trained)."""
    if not len(y):
        raise ValueError(f"{data_name}: no candidate corners in these sequences (frames without texture?); "
                         "larger or more textured sequences give some")
    positives = int(np.count_nonzero(y))
    if positives in (0, len(y)):
        which = "none" if positives == 0 else "every one"
        raise ValueError(f"{data_name}: {which} of the {plural(len(y), 'candidate')} is {labels} in another frame of "
                         f"its sequence, so the scorer has nothing to tell apart; simulate sequences whose frames show "
                         "more of one cloth (larger images, fewer --steps-per-frame)")
