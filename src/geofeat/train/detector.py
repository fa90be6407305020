"""Training GeoKey (`geofeat train-detector`) on simulated sequences with exact correspondences.

Training signal (per candidate, from the simulator's dense ground truth): a candidate corner of
frame A is positive when its surface point is visible in frame B and B's own candidates include one
within `match_px` pixels of where that point lands. That is repeatability measured where it counts
(a corner found again at the same surface point), with occlusion, self-occlusion, foreshortening and
folds all taken into account by the simulator. The scorer (a small MLP on `cues`) is fitted with a
binary cross-entropy, which learns in a couple of minutes on a CPU; the suppression radius is then
chosen on the validation sequences by the protocol's repeatability.

Every pair (reference, target) and its reverse contributes, so the scorer sees both directions of
each deformation, scale change and roll.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from tqdm import tqdm

from ..detectors.cues import CUE_NAMES, cue_features, cue_maps
from ..detectors.geokey import GeoKeyModel, candidates, detect_geokey
from ..io import Sequence, find_sequences, read_sequence
from ..scoring import ground_truth_pairs

#: A candidate is found again when another view's candidate lies within this many pixels.
MATCH_PX = 1.0
#: Suppression radii tried on the validation data, pixels.
NMS_CHOICES = (2.0, 3.0, 4.0, 5.0)


@dataclass
class FrameCandidates:
    xy: np.ndarray        # (N, 2) pixels
    features: np.ndarray  # (N, D) float32


def _frame_candidates(seq: Sequence, name: str) -> FrameCandidates:
    frame = seq.frame(name)
    xy, level = candidates(frame)
    return FrameCandidates(xy, cue_features(cue_maps(frame), xy, level))


def sequence_samples(seq: Sequence, match_px: float = MATCH_PX) -> tuple[np.ndarray, np.ndarray]:
    """Features (M, D) float32 and labels (M,) float32 in {0, 1} of every candidate of every
    (reference, target) pair of a simulated sequence, in both directions."""
    if not seq.has_ground_truth():
        raise ValueError(f"data: {seq.folder} has no simulator ground truth (geofeat simulate writes it)")
    frames = {name: _frame_candidates(seq, name) for name in seq.names}
    xs, ys = [], []
    for target in seq.targets:
        for a, b in ((seq.reference, target), (target, seq.reference)):
            ca, cb = frames[a], frames[b]
            if len(ca.xy) == 0:
                continue
            mapped, visible = seq.correspondences(a, b, ca.xy)
            label = np.zeros(len(ca.xy), np.float32)
            if len(cb.xy) and visible.any():
                dist, _ = cKDTree(cb.xy).query(mapped[visible], k=1)
                label[visible] = (dist <= match_px).astype(np.float32)
            xs.append(ca.features)
            ys.append(label)
    if not xs:
        return np.zeros((0, len(CUE_NAMES)), np.float32), np.zeros(0, np.float32)
    return np.concatenate(xs), np.concatenate(ys)


def collect(folders: list[Path], progress: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """`sequence_samples` of every simulated sequence under `folders`, concatenated."""
    xs, ys = [], []
    for folder in tqdm(folders, desc="candidates", unit="seq", disable=not progress):
        x, y = sequence_samples(read_sequence(folder))
        xs.append(x)
        ys.append(y)
    return np.concatenate(xs), np.concatenate(ys)


def fit(x: np.ndarray, y: np.ndarray, hidden: tuple[int, ...] = (32, 32), steps: int = 3000,
        batch: int = 4096, lr: float = 3e-3, seed: int = 0, device: str | None = None,
        progress: bool = True) -> GeoKeyModel:
    """Fit the MLP scorer with a binary cross-entropy (torch, CPU or the GPU when present).

    Args:
        x: (M, D) cue features; y: (M,) labels in {0, 1}.
        hidden: widths of the hidden layers.
        steps, batch, lr: Adam iterations, minibatch size, learning rate.
        seed: the same seed gives the same weights (on the same device).
    """
    import torch

    if len(x) == 0:
        raise ValueError("data: no training candidates (are the sequences empty?)")
    device = device or ("cuda" if torch.cuda.is_available() else "cpu")
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    mean = x.mean(axis=0).astype(np.float32)
    std = (x.std(axis=0) + 1e-6).astype(np.float32)
    xt = torch.from_numpy((x - mean) / std).to(device)
    yt = torch.from_numpy(y.astype(np.float32)).to(device)
    widths = (x.shape[1], *hidden, 1)
    layers: list = []
    for k in range(len(widths) - 1):
        layers.append(torch.nn.Linear(widths[k], widths[k + 1]))
        if k < len(widths) - 2:
            layers.append(torch.nn.ReLU())
    net = torch.nn.Sequential(*layers).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    loss_fn = torch.nn.BCEWithLogitsLoss()
    bar = tqdm(range(steps), desc="train-detector", unit="step", disable=not progress)
    for step in bar:
        idx = torch.from_numpy(rng.integers(0, len(x), batch)).to(device)
        loss = loss_fn(net(xt[idx])[:, 0], yt[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % 200 == 0:
            bar.set_postfix(loss=f"{loss.item():.4f}")
    linears = [m for m in net if isinstance(m, torch.nn.Linear)]
    weights = tuple(m.weight.detach().cpu().numpy().T.copy() for m in linears)
    biases = tuple(m.bias.detach().cpu().numpy().copy() for m in linears)
    return GeoKeyModel(mean, std, weights, biases)


def repeatability(folders: list[Path], detector, n: int, progress: bool = False) -> dict:
    """The protocol's best matching score of a detector on simulated sequences.

    For each (reference, target) pair: the detector's n keypoints in both frames, reference
    keypoints off the visible surface dropped, target keypoints whose surface point is not visible
    in the reference dropped; ground-truth pairs < 3 px (the protocol's rule) / min(n_ref, n_tgt).

    Args:
        detector: callable (frame, n) -> Keypoints.

    Returns:
        {"repeatability": mean over sequences of the mean over pairs, "n_ref": mean reference
        keypoints kept, "pairs": ground-truth pairs per pair (mean)}.
    """
    per_seq, n_refs, n_pairs = [], [], []
    for folder in tqdm(folders, desc="repeatability", unit="seq", disable=not progress):
        seq = read_sequence(folder)
        ref = detector(seq.frame(seq.reference), n).xy
        ref = ref[seq.correspondences(seq.reference, seq.reference, ref)[1]]
        scores = []
        for target in seq.targets:
            tgt = detector(seq.frame(target), n).xy
            mapped, visible = seq.correspondences(target, seq.reference, tgt)
            mapped = mapped[visible]
            pairs = ground_truth_pairs(ref, mapped)
            denom = min(len(ref), len(mapped))
            scores.append(len(pairs) / denom if denom else 0.0)
            n_pairs.append(len(pairs))
        per_seq.append(float(np.mean(scores)))
        n_refs.append(len(ref))
    return {"repeatability": float(np.mean(per_seq)), "n_ref": float(np.mean(n_refs)),
            "pairs": float(np.mean(n_pairs))}


def choose_nms_radius(model: GeoKeyModel, folders: list[Path], n: int) -> tuple[float, dict]:
    """The suppression radius of NMS_CHOICES with the best validation repeatability at n keypoints."""
    results = {}
    for radius in NMS_CHOICES:
        results[radius] = repeatability(folders, lambda f, k: detect_geokey(f, k, model, nms_radius=radius), n)
    best = max(results, key=lambda r: results[r]["repeatability"])
    return best, results


def train_detector(data, val, out: str | Path, n: int = 1024, hidden: tuple[int, ...] = (32, 32),
                   steps: int = 3000, seed: int = 0, progress: bool = True) -> tuple[GeoKeyModel, dict]:
    """Collect candidates from `data`, fit the scorer, choose the suppression radius on `val`, and
    write the weights to `out`. Returns the model and the validation figures per radius."""
    train_folders = find_sequences(data)
    val_folders = find_sequences(val)
    if not train_folders:
        raise ValueError(f"data: no sequences under {data}")
    if not val_folders:
        raise ValueError(f"val: no sequences under {val}")
    x, y = collect(train_folders, progress)
    if progress:
        tqdm.write(f"train-detector: {len(x)} candidates from {len(train_folders)} sequences, "
                   f"{y.mean():.3f} positive")
    model = fit(x, y, hidden=hidden, steps=steps, seed=seed, progress=progress)
    radius, results = choose_nms_radius(model, val_folders, n)
    model = GeoKeyModel(model.mean, model.std, model.weights, model.biases, radius)
    model.save(out)
    return model, results
