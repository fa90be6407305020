"""A learned heatmap detector (R2D2-style repeatability + peakiness), against GeoKey: a trial for issue 20.

GeoKey finds corner candidates with a hand-made rule (Shi-Tomasi, 3 px window) and learns only how to
rank them. A detector whose whole heatmap is learned from the simulator's exact correspondences could
find points that noise and lighting move less. This script trains one on CPU and measures its
repeatability with the protocol of `geofeat.train.detector.repeatability`, beside GeoKey with its
shipped rule and GeoKey returning its n best (no threshold).

The network (about 13 k weights): two 3 x 3 convolutions of 8 channels at full resolution, three of
24 channels at half resolution (one dilated), upsampled and joined with the full-resolution features,
then a 3 x 3 convolution and a sigmoid: a (H, W) heatmap in [0, 1] of the frame standardised to zero
mean and unit variance. Training pairs: every target frame of each training sequence with its
reference. A random 160 x 160 crop of the target with at least 40 % of its pixels visible in the
reference; the reference around the crop's mapped pixels is run through the same network and its
heatmap resampled into the target crop by the exact correspondences. Loss (R2D2's): 1 - the mean
cosine similarity of the two heatmaps over N x N patches (stride N/2, patches at least 75 % visible),
plus the peakiness 1 - mean(max - mean) over (N + 1) x (N + 1) windows of each heatmap. Keypoints: the
heatmap's local maxima within 3 px, on pixels at least 3 px from a depth edge and 4 px from the border
(GeoKey's rules), the n highest, sub-pixel by GeoKey's parabola.

Two losses on peak positions can be added (eighteenth session): `--position W`, the expected distance
between the two heatmaps' softmax positions within every 8 x 8 window (`position_loss`), and
`--peak-score W`, a cross-entropy that teaches the value at each target peak whether the reference
has a peak within 2 px there (`peak_score_loss`). `--whole-frames` trains on whole frames, a batch of
pairs per step, on `--device` (a GPU when one is lent); `--cache` keeps the loaded pairs in an .npz.

    PYTHONPATH=src .venv/bin/python benchmarks/heatmap_detector_trial.py train out/det/train --steps 1500 --keep 500 --out OUT.pt
    PYTHONPATH=src .venv/bin/python benchmarks/heatmap_detector_trial.py evaluate OUT.pt out/det2/val/*hard* [--geokey] [--ms]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from geofeat.detectors import geokey
from geofeat.detectors.cues import depth_edge_distance
from geofeat.io import read_sequence
from geofeat.keypoints import Keypoints
from geofeat.train.detector import validation_scores


class HeatmapNet(nn.Module):
    """(B, 1, H, W) gray image in [0, 1] -> (B, 1, H, W) heatmap in [0, 1]; H, W even."""

    def __init__(self, full: int = 8, half: int = 24):
        super().__init__()
        self.full1, self.full2 = nn.Conv2d(1, full, 3, padding=1), nn.Conv2d(full, full, 3, padding=1)
        self.half1 = nn.Conv2d(full, half, 3, padding=1, stride=2)
        self.half2 = nn.Conv2d(half, half, 3, padding=1)
        self.half3 = nn.Conv2d(half, half, 3, padding=2, dilation=2)
        self.joined = nn.Conv2d(full + half, full, 3, padding=1)
        self.out = nn.Conv2d(full, 1, 1)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.logits(image))

    def logits(self, image: torch.Tensor) -> torch.Tensor:
        """(B, 1, H, W) image -> (B, 1, H, W) logits of the heatmap."""
        x = (image - image.mean(dim=(2, 3), keepdim=True)) / (image.std(dim=(2, 3), keepdim=True) + 1e-3)
        full = F.relu(self.full2(F.relu(self.full1(x))))
        half = F.relu(self.half3(F.relu(self.half2(F.relu(self.half1(full))))))
        half = F.interpolate(half, size=full.shape[-2:], mode="bilinear", align_corners=False)
        return self.out(F.relu(self.joined(torch.cat([full, half], 1))))


def load_pairs(folders: list[Path], jobs: int = 1) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """(reference image (H, W), target image (H, W), target pixel -> reference pixel (H, W, 2), visible
    (H, W) bool) for every target of every sequence; pixels not visible map to -1000. `jobs` processes."""
    if jobs > 1:
        from multiprocessing import Pool

        with Pool(jobs) as pool:
            return [pair for part in pool.map(sequence_pairs, folders) for pair in part]
    return [pair for folder in folders for pair in sequence_pairs(folder)]


def cached_pairs(folders: list[Path], cache: str | None, jobs: int = 1):
    """`load_pairs`, kept in (or read from) the .npz `cache` when one is given (images as 8-bit). The
    cache records the sequence folders it was made from; a cache of other folders is refused."""
    names = np.array(sorted(str(Path(f).resolve()) for f in folders))
    if cache and Path(cache).is_file():
        z = np.load(cache)
        if "folders" not in z.files or not np.array_equal(z["folders"], names):
            raise SystemExit(f"--cache {cache} was made from other sequence folders; remove it or choose another")
        ref, tgt, mapped, vis = z["ref"], z["tgt"], z["mapped"], z["vis"]
        return [(ref[i] / np.float32(255), tgt[i] / np.float32(255), mapped[i], vis[i]) for i in range(len(tgt))]
    pairs = load_pairs(folders, jobs)
    if cache:
        np.savez(cache, folders=names, ref=np.stack([np.round(p[0] * 255).astype(np.uint8) for p in pairs]),
                 tgt=np.stack([np.round(p[1] * 255).astype(np.uint8) for p in pairs]),
                 mapped=np.stack([p[2] for p in pairs]), vis=np.stack([p[3] for p in pairs]))
    return pairs


def sequence_pairs(folder: Path) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """`load_pairs` of one sequence."""
    pairs = []
    seq = read_sequence(folder)
    ref = seq.frame(seq.reference)
    for name in seq.targets:
        frame = seq.frame(name)
        H, W = frame.shape
        v, u = np.mgrid[0:H, 0:W]
        mapped, visible = seq.correspondences(name, seq.reference, np.stack([u.ravel(), v.ravel()], 1).astype(float))
        mapped = np.where(np.isfinite(mapped), mapped, -1000.0).reshape(H, W, 2).astype(np.float32)
        pairs.append((ref.image.astype(np.float32), frame.image.astype(np.float32), mapped,
                      visible.reshape(H, W) & (frame.depth > 0)))
    return pairs


def random_crop(pairs, rng, size: int):
    """A target crop, the reference region its visible pixels map into (12 px margin), the crop's
    mapping into that region (size, size, 2) and its visibility (size, size)."""
    while True:
        ref, tgt, mapped, visible = pairs[rng.integers(len(pairs))]
        H, W = tgt.shape
        y0, x0 = rng.integers(0, H - size), rng.integers(0, W - size)
        vis = visible[y0:y0 + size, x0:x0 + size]
        if vis.mean() < 0.4:
            continue
        m = mapped[y0:y0 + size, x0:x0 + size]
        lo = np.maximum(np.floor(m[vis].min(0)) - 12, 0).astype(int)
        hi = np.minimum(np.ceil(m[vis].max(0)) + 12, [W - 1, H - 1]).astype(int)
        if (hi - lo).min() < 32 or (hi - lo).max() > 3 * size:
            continue
        return (tgt[y0:y0 + size, x0:x0 + size], ref[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1],
                (m - lo).astype(np.float32), vis)


def repeatability_loss(target: torch.Tensor, warped: torch.Tensor, mask: torch.Tensor, N: int) -> torch.Tensor:
    """1 - mean cosine similarity of the two (1, 1, C, C) heatmaps over N x N patches at least 75 % visible."""
    patches = lambda x: F.unfold(x, N, stride=N // 2)  # noqa: E731
    a, b, m = patches(target * mask), patches(warped * mask), patches(mask)
    ok = m.mean(1) > 0.75
    cos = (F.normalize(a, dim=1) * F.normalize(b, dim=1)).sum(1)
    return 1 - cos[ok].mean() if ok.any() else target.sum() * 0


def peakiness_loss(heatmap: torch.Tensor, N: int) -> torch.Tensor:
    return 1 - (F.max_pool2d(heatmap, N + 1, 1, N // 2) - F.avg_pool2d(heatmap, N + 1, 1, N // 2)).mean()


def position_loss(target: torch.Tensor, warped: torch.Tensor, mask: torch.Tensor, N: int,
                  tau: float = 0.1) -> torch.Tensor:
    """Expected distance (pixels) between a pixel drawn from softmax(target / tau) and one drawn from
    softmax(warped / tau), within every N x N window (two grids, offset by N/2) that is wholly visible.

    target, warped: (B, 1, H, W) heatmaps in [0, 1] in the target's pixels (the reference's warped);
    mask (B, 1, H, W) in {0, 1}. The fixed temperature bounds how sharp a window can be (on logits the
    loss drove them to thousands and saturated the sigmoid: a first GPU run).
    It is 0 only when both windows put all their mass on the same pixel, so it rewards a sharp peak
    at the same surface point in both views: what the protocol counts, unlike the patch cosine.
    """
    yy, xx = torch.meshgrid(torch.arange(N, dtype=target.dtype, device=target.device),
                            torch.arange(N, dtype=target.dtype, device=target.device), indexing="ij")
    xy = torch.stack([xx.ravel(), yy.ravel()], 1)
    D = torch.cdist(xy, xy)  # (N*N, N*N)
    terms = []
    for off in (0, N // 2):
        a = F.unfold(target[..., off:, off:], N, stride=N)   # (B, N*N, L)
        b = F.unfold(warped[..., off:, off:], N, stride=N)
        m = F.unfold(mask[..., off:, off:], N, stride=N).amin(1) > 0.5  # (B, L)
        pa, pb = torch.softmax(a / tau, 1), torch.softmax(b / tau, 1)
        expected = torch.einsum("bil,ij,bjl->bl", pa, D, pb)
        terms.append(expected[m])
    d = torch.cat(terms)
    return d.mean() if d.numel() else target.sum() * 0


def peak_score_loss(target: torch.Tensor, warped: torch.Tensor, mask: torch.Tensor, radius: int = 3,
                    near: int = 2) -> torch.Tensor:
    """Binary cross-entropy of the target heatmap's value at each of its local maxima (within
    `radius` px, on visible pixels) against whether the warped reference heatmap has a local maximum
    within `near` px: the value that ranks the peaks learns to predict that a peak is found again.
    target, warped: (B, 1, H, W) heatmaps in [0, 1]; mask (B, 1, H, W) in {0, 1}."""
    k = 2 * radius + 1

    def local_maxima(h: torch.Tensor) -> torch.Tensor:  # plateaus are not peaks
        mean = F.avg_pool2d(h, k, 1, radius, count_include_pad=False)
        return (h >= F.max_pool2d(h, k, 1, radius)) & (h > mean + 1e-3) & (mask > 0.5)

    with torch.no_grad():
        peaks_t, peaks_w = local_maxima(target), local_maxima(warped)
        found = F.max_pool2d(peaks_w.float(), 2 * near + 1, 1, near) > 0
    if not peaks_t.any():
        return target.sum() * 0
    return F.binary_cross_entropy(target[peaks_t].clamp(1e-4, 1 - 1e-4), found[peaks_t].float())


def sampling_grid(mapped: np.ndarray, width: int, height: int) -> np.ndarray:
    """(..., 2) pixel coordinates (x, y) of an image of `width` x `height` -> grid_sample's [-1, 1]
    units (align_corners=True), float32."""
    return np.stack([mapped[..., 0] / (width - 1) * 2 - 1, mapped[..., 1] / (height - 1) * 2 - 1], -1).astype(np.float32)


def stacked_pairs(pairs, device: str):
    """The pairs as tensors on `device`: references, targets (P, 1, H, W), grids (P, H, W, 2) in
    grid_sample's [-1, 1] units (pixels not visible far outside), visibility (P, 1, H, W)."""
    ref = torch.from_numpy(np.stack([p[0] for p in pairs]))[:, None]
    tgt = torch.from_numpy(np.stack([p[1] for p in pairs]))[:, None]
    H, W = pairs[0][1].shape
    grid = sampling_grid(np.stack([p[2] for p in pairs]), W, H)
    vis = torch.from_numpy(np.stack([p[3] for p in pairs]).astype(np.float32))[:, None]
    return ref.to(device), tgt.to(device), torch.from_numpy(grid).to(device), vis.to(device)


def trial_loss(a: argparse.Namespace, target: torch.Tensor, warped: torch.Tensor, reference: torch.Tensor,
               mask: torch.Tensor) -> torch.Tensor:
    """R2D2's cosine and peakiness, plus `--position` x `position_loss` / N and `--peak-score` x
    `peak_score_loss`. target, warped (the reference's, in the target's pixels), mask: (B, 1, h, w);
    reference: the reference's own heatmap (its peakiness)."""
    loss = repeatability_loss(target, warped, mask, a.patch) + 0.5 * (
        peakiness_loss(target, a.patch) + peakiness_loss(reference, a.patch))
    if a.position > 0:
        loss = loss + a.position * position_loss(target, warped, mask, a.patch) / a.patch
    if a.peak_score > 0:
        loss = loss + a.peak_score * peak_score_loss(target, warped, mask)
    return loss


def optimise(a: argparse.Namespace, net: nn.Module, opt: torch.optim.Optimizer, loss: torch.Tensor, step: int,
             history: list[float], start: float) -> bool:
    """One optimiser step on `loss`; print and save every 100 steps and at the last, keep the `--keep`
    steps' weights. True when `--minutes` have passed (the weights saved)."""
    opt.zero_grad()
    loss.backward()
    opt.step()
    history.append(float(loss.detach()))
    if (step + 1) % 100 == 0 or step + 1 == a.steps:
        print(f"step {step + 1}: loss {np.mean(history[-100:]):.4f} ({time.perf_counter() - start:.0f} s)", flush=True)
        torch.save(net.state_dict(), a.out)
    if step + 1 in a.keep:
        torch.save(net.state_dict(), Path(a.out).with_suffix(f".step{step + 1}.pt"))
    if a.minutes and time.perf_counter() - start > 60 * a.minutes:
        torch.save(net.state_dict(), a.out)
        print(f"stopped at step {step + 1} after {a.minutes} min: loss {np.mean(history[-100:]):.4f}", flush=True)
        return True
    return False


def train_full(a: argparse.Namespace) -> None:
    """Whole frames, a batch of pairs per step, on `--device`: R2D2's cosine and peakiness plus
    `--position` x the windowed expected distance (`position_loss`, divided by N) and `--peak-score` x
    the peak-value cross-entropy (`peak_score_loss`)."""
    folders = sorted(p for p in Path(a.data).iterdir() if p.is_dir())
    pairs = cached_pairs(folders, a.cache, a.jobs)
    ref, tgt, grid, vis = stacked_pairs(pairs, a.device)
    del pairs
    print(f"{len(ref)} pairs from {len(folders)} sequences on {a.device}; load average {os.getloadavg()[0]:.2f}",
          flush=True)
    gen = torch.Generator().manual_seed(0)
    torch.manual_seed(0)
    net = HeatmapNet(a.full, a.half).to(a.device)
    opt = torch.optim.Adam(net.parameters(), a.lr)
    start, history = time.perf_counter(), []
    for step in range(a.steps):
        idx = torch.randint(len(ref), (a.batch,), generator=gen).to(a.device)
        gain = torch.empty(a.batch, 1, 1, 1).uniform_(0.6, 1.4, generator=gen).to(a.device)
        t_img = (tgt[idx] * gain).clamp(0, 1)
        t_logit, r_logit = net.logits(t_img), net.logits(ref[idx])
        warped = F.grid_sample(r_logit, grid[idx], align_corners=True, padding_mode="border")
        mask = vis[idx]
        s_t, s_w = torch.sigmoid(t_logit), torch.sigmoid(warped)
        loss = trial_loss(a, s_t, s_w, torch.sigmoid(r_logit), mask)
        if optimise(a, net, opt, loss, step, history, start):
            break


def train(a: argparse.Namespace) -> None:
    folders = sorted(p for p in Path(a.data).iterdir() if p.is_dir())
    pairs = cached_pairs(folders, a.cache, a.jobs)
    print(f"{len(pairs)} pairs from {len(folders)} sequences; load average {os.getloadavg()[0]:.2f}")
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    net = HeatmapNet(a.full, a.half)
    opt = torch.optim.Adam(net.parameters(), a.lr)
    start, history = time.perf_counter(), []
    for step in range(a.steps):
        loss = torch.zeros(())
        for _ in range(a.batch):
            tgt, ref, mapped, vis = random_crop(pairs, rng, a.crop)
            if rng.random() < 0.5:
                tgt = np.clip(tgt * rng.uniform(0.6, 1.4), 0, 1)  # brightness jitter
            s_tgt = net(torch.from_numpy(np.ascontiguousarray(tgt))[None, None])
            s_ref = net(torch.from_numpy(np.ascontiguousarray(ref))[None, None])
            h, w = ref.shape
            grid = torch.from_numpy(sampling_grid(mapped, w, h))
            warped = F.grid_sample(s_ref, grid[None], align_corners=True)
            mask = torch.from_numpy(vis.astype(np.float32))[None, None]
            loss = loss + trial_loss(a, s_tgt, warped, s_ref, mask)
        loss = loss / a.batch
        if optimise(a, net, opt, loss, step, history, start):
            break


def heatmap_detector(net: HeatmapNet, radius: int = 3, threshold: float = 0.0):
    """(frame, n) -> Keypoints: the heatmap's n highest local maxima on the surface, of those whose
    heatmap value reaches `threshold`."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))

    def detect(frame, n):
        with torch.no_grad():
            heat = net(torch.from_numpy(frame.image.astype(np.float32))[None, None])[0, 0].numpy()
        ok = depth_edge_distance(frame.depth, float(frame.K[0, 0]), geokey.DEPTH_EDGE_STEP_FOOTPRINTS,
                                 fy=float(frame.K[1, 1])) >= geokey.DEPTH_EDGE_MARGIN_PX
        b = geokey.BORDER_PX
        ok[:b], ok[-b:], ok[:, :b], ok[:, -b:] = False, False, False, False
        y, x = np.nonzero((heat >= cv2.dilate(heat, kernel)) & ok & (heat >= threshold))
        order = np.argsort(-heat[y, x], kind="stable")[:n]
        xy = geokey.refine_peaks(heat, np.stack([x[order], y[order]], 1).astype(np.float64))
        return Keypoints(xy, np.zeros(len(xy)), np.full(len(xy), 8.0), heat[y[order], x[order]].astype(np.float64))

    return detect


def evaluate(a: argparse.Namespace) -> None:
    state = torch.load(a.weights, map_location="cpu")
    net = HeatmapNet(state["full1.weight"].shape[0], state["half1.weight"].shape[0])
    net.load_state_dict(state)
    net.eval()
    detectors = {f"heatmap network, threshold {t:g}": heatmap_detector(net, threshold=t) for t in a.thresholds}
    if a.geokey:
        detectors["GeoKey, shipped rule"] = lambda f, n: geokey.detect_geokey(f, n)
        detectors["GeoKey, n best"] = lambda f, n: geokey.detect_geokey(f, n, threshold=-np.inf, min_fraction=0)
    print(f"{len(a.sequences)} sequences; load average {os.getloadavg()[0]:.2f}")
    what = "MS / correct matches / repeatability / ground-truth pairs / reference keypoints" if a.ms else \
        "repeatability / ground-truth pairs / reference keypoints"
    print(f"| detector | 1024: {what} | 2048: the same |")
    print("|---|---|---|")
    for name, detect in detectors.items():
        cells = []
        for n in (1024, 2048):
            r = validation_scores(a.sequences, detect, n, descriptor="geopatch" if a.ms else None)
            cell = f"{r['repeatability']:.3f} / {r['pairs']:.0f} / {r['n_ref']:.0f}"
            cells.append(f"{r['ms']:.3f} / {r['hits']:.0f} / {cell}" if a.ms else cell)
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train")
    t.add_argument("data", help="folder of simulated training sequences (out/det/train)")
    t.add_argument("--steps", type=int, default=1500)
    t.add_argument("--batch", type=int, default=4)
    t.add_argument("--crop", type=int, default=160)
    t.add_argument("--patch", type=int, default=8, help="N of the repeatability and peakiness windows, pixels")
    t.add_argument("--out", required=True)
    t.add_argument("--whole-frames", action="store_true",
                   help="train on whole frames, a batch of pairs per step (train_full), on --device")
    t.add_argument("--device", default="cpu")
    t.add_argument("--cache", help="an .npz that keeps the loaded pairs between runs")
    t.add_argument("--jobs", type=int, default=1, help="processes that load the pairs")
    t.add_argument("--position", type=float, default=0.0,
                   help="weight of the windowed expected-distance loss (position_loss)")
    t.add_argument("--lr", type=float, default=1e-3)
    t.add_argument("--peak-score", type=float, default=0.0,
                   help="weight of the peak-value cross-entropy (peak_score_loss)")
    t.add_argument("--minutes", type=float, default=0.0, help="stop after this many minutes")
    t.add_argument("--full", type=int, default=8, help="channels at full resolution")
    t.add_argument("--half", type=int, default=24, help="channels at half resolution")
    t.add_argument("--keep", type=lambda s: {int(k) for k in s.split(",")}, default=set(),
                   help="steps whose weights are also kept, as OUT.stepK.pt (comma-separated)")
    e = sub.add_parser("evaluate")
    e.add_argument("weights")
    e.add_argument("sequences", nargs="+", type=Path)
    e.add_argument("--geokey", action="store_true", help="GeoKey's rows as well")
    e.add_argument("--thresholds", type=lambda t: [float(v) for v in t.split(",")], default=[0.0],
                   help="heatmap values a keypoint must reach (comma-separated; a row each)")
    e.add_argument("--ms", action="store_true", help="GeoPatch's MS and correct matches too (slower)")
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    if a.command == "evaluate":
        evaluate(a)
    else:
        train_full(a) if a.whole_frames else train(a)


if __name__ == "__main__":
    main()
