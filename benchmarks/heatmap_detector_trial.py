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

    PYTHONPATH=src .venv/bin/python benchmarks/heatmap_detector_trial.py train out/det/train --steps 1500 --keep 500 --out OUT.pt
    PYTHONPATH=src .venv/bin/python benchmarks/heatmap_detector_trial.py evaluate OUT.pt out/det2/val/*hard* [--geokey]
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
from geofeat.train.detector import repeatability


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
        x = (image - image.mean(dim=(2, 3), keepdim=True)) / (image.std(dim=(2, 3), keepdim=True) + 1e-3)
        full = F.relu(self.full2(F.relu(self.full1(x))))
        half = F.relu(self.half3(F.relu(self.half2(F.relu(self.half1(full))))))
        half = F.interpolate(half, size=full.shape[-2:], mode="bilinear", align_corners=False)
        return torch.sigmoid(self.out(F.relu(self.joined(torch.cat([full, half], 1)))))


def load_pairs(folders: list[Path]) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """(reference image (H, W), target image (H, W), target pixel -> reference pixel (H, W, 2), visible
    (H, W) bool) for every target of every sequence; pixels not visible map to -1000."""
    pairs = []
    for folder in folders:
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


def train(a: argparse.Namespace) -> None:
    folders = sorted(p for p in Path(a.data).iterdir() if p.is_dir())
    pairs = load_pairs(folders)
    print(f"{len(pairs)} pairs from {len(folders)} sequences; load average {os.getloadavg()[0]:.2f}")
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    net = HeatmapNet()
    opt = torch.optim.Adam(net.parameters(), 1e-3)
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
            grid = torch.from_numpy(np.stack([mapped[..., 0] / (w - 1) * 2 - 1, mapped[..., 1] / (h - 1) * 2 - 1], -1))
            warped = F.grid_sample(s_ref, grid[None], align_corners=True)
            mask = torch.from_numpy(vis.astype(np.float32))[None, None]
            loss = loss + repeatability_loss(s_tgt, warped, mask, a.patch) + 0.5 * (
                peakiness_loss(s_tgt, a.patch) + peakiness_loss(s_ref, a.patch))
        loss = loss / a.batch
        opt.zero_grad()
        loss.backward()
        opt.step()
        history.append(float(loss.detach()))
        if (step + 1) % 100 == 0 or step + 1 == a.steps:
            print(f"step {step + 1}: loss {np.mean(history[-100:]):.4f} ({time.perf_counter() - start:.0f} s)", flush=True)
            torch.save(net.state_dict(), a.out)
        if step + 1 in a.keep:
            torch.save(net.state_dict(), Path(a.out).with_suffix(f".step{step + 1}.pt"))


def heatmap_detector(net: HeatmapNet, radius: int = 3):
    """(frame, n) -> Keypoints: the heatmap's n highest local maxima on the surface."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))

    def detect(frame, n):
        with torch.no_grad():
            heat = net(torch.from_numpy(frame.image.astype(np.float32))[None, None])[0, 0].numpy()
        ok = depth_edge_distance(frame.depth, float(frame.K[0, 0]), geokey.DEPTH_EDGE_STEP_FOOTPRINTS,
                                 fy=float(frame.K[1, 1])) >= geokey.DEPTH_EDGE_MARGIN_PX
        b = geokey.BORDER_PX
        ok[:b], ok[-b:], ok[:, :b], ok[:, -b:] = False, False, False, False
        y, x = np.nonzero((heat >= cv2.dilate(heat, kernel)) & ok)
        order = np.argsort(-heat[y, x], kind="stable")[:n]
        xy = geokey.refine_peaks(heat, np.stack([x[order], y[order]], 1).astype(np.float64))
        return Keypoints(xy, np.zeros(len(xy)), np.full(len(xy), 8.0), heat[y[order], x[order]].astype(np.float64))

    return detect


def evaluate(a: argparse.Namespace) -> None:
    net = HeatmapNet()
    net.load_state_dict(torch.load(a.weights))
    net.eval()
    detectors = {"heatmap network": heatmap_detector(net)}
    if a.geokey:
        detectors["GeoKey, shipped rule"] = lambda f, n: geokey.detect_geokey(f, n)
        detectors["GeoKey, n best"] = lambda f, n: geokey.detect_geokey(f, n, threshold=-np.inf, min_fraction=0)
    print(f"{len(a.sequences)} sequences; load average {os.getloadavg()[0]:.2f}")
    print("| detector | 1024: repeatability / ground-truth pairs / reference keypoints | 2048: the same |")
    print("|---|---|---|")
    for name, detect in detectors.items():
        cells = []
        for n in (1024, 2048):
            r = repeatability(a.sequences, detect, n)
            cells.append(f"{r['repeatability']:.3f} / {r['pairs']:.0f} / {r['n_ref']:.0f}")
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
    t.add_argument("--keep", type=lambda s: {int(k) for k in s.split(",")}, default=set(),
                   help="steps whose weights are also kept, as OUT.stepK.pt (comma-separated)")
    e = sub.add_parser("evaluate")
    e.add_argument("weights")
    e.add_argument("sequences", nargs="+", type=Path)
    e.add_argument("--geokey", action="store_true", help="GeoKey's rows as well")
    a = ap.parse_args()
    torch.set_num_threads(2)
    train(a) if a.command == "train" else evaluate(a)


if __name__ == "__main__":
    main()
