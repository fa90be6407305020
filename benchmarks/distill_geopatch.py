"""A narrower GeoPatch distilled from the shipped one (issue 21's CNN item: "a narrower network
distilled from v8"), to see whether it keeps the validation matching score.

    PYTHONPATH=src .venv/bin/python benchmarks/distill_geopatch.py patches TRAIN_FOLDER [...] --out P.npz
    PYTHONPATH=src .venv/bin/python benchmarks/distill_geopatch.py train P.npz --channels 16 32 64 --out S.pt
    PYTHONPATH=src .venv/bin/python benchmarks/val_score.py VAL S.pt --shipped

`patches`: polar patches (the shipped GeoPatch's radius and blur, each sequence's depth profile) of
GeoKey's and SIFT's keypoints on every frame of the training sequences, and the shipped network's
float32 torch descriptors of them (the teacher). `train`: a GeoPatchNet of the given widths learns
to give the teacher's descriptors: loss 1 - cosine to the teacher's descriptor, plus the squared
difference of the batch's cosine-similarity matrices (the teacher's neighbourhoods). Augmentation:
circular shifts of the angle axis by multiples of 4 columns, under which both networks' outputs are
exactly invariant (two 2x2 poolings, then a maximum over angle). Writes a checkpoint that
`val_score.py`, `geofeat bench --descriptors geopatch=S.pt` and `make_geopatch_onnx.py --weights`
read.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def make_patches(folders: list[str], out: str, per_detector: int) -> None:
    import torch
    from tqdm import tqdm

    import geofeat
    from geofeat.depth import sequence_depth_profile
    from geofeat.descriptors.geopatch import GeoPatch
    from geofeat.io import read_sequence

    teacher = GeoPatch(backend="torch", device="cpu")
    values, descriptors = [], []
    for folder in tqdm(folders, desc="sequences"):
        seq = read_sequence(folder)
        profile = sequence_depth_profile(seq)
        for name in seq.names:
            frame = seq.frame(name)
            for detector in ("geokey", "sift"):
                kps = geofeat.detect(frame, per_detector, detector=detector)
                if len(kps) == 0:
                    continue
                p = geofeat.polar_patches(frame, kps, radius=teacher.radius, depth_config=profile,
                                          blur_px=teacher.blur_px)
                v = p.values[p.valid]
                if len(v):
                    values.append(v.astype(np.float16))  # patch intensities in [0, 1]: 11 bits kept
                    with torch.inference_mode():
                        descriptors.append(teacher.describe(v.astype(np.float16).astype(np.float32)))
    np.savez(out, values=np.concatenate(values), descriptors=np.concatenate(descriptors))
    print(f"{sum(len(v) for v in values)} patches -> {out}")


def train(data: str, channels: tuple[int, int, int], out: str, epochs: int, batch: int, lr: float, seed: int,
          relation: float) -> None:
    import torch

    from geofeat.descriptors.geopatch import GeoPatchConfig
    from geofeat.descriptors.geopatch_net import GeoPatchNet, save_checkpoint

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    d = np.load(data)
    values = torch.from_numpy(d["values"])  # (M, R, A) float16
    target = torch.from_numpy(d["descriptors"])  # (M, 128) float32
    held = rng.permutation(len(values))
    test, fit = held[:4096], held[4096:]
    net = GeoPatchNet(GeoPatchConfig(channels=channels))
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    steps = epochs * (len(fit) // batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps, pct_start=0.1)
    print(f"{len(fit)} training patches, {len(test)} held out; {steps} steps of {batch}", flush=True)

    def held_out_cosine() -> tuple[float, float]:
        net.eval()
        with torch.inference_mode():
            s = net(values[test].float().unsqueeze(1))
        net.train()
        cos = (s * target[test]).sum(1)
        return float(cos.mean()), float(cos.min())

    t0 = time.perf_counter()
    step = 0
    for epoch in range(epochs):
        order = torch.from_numpy(rng.permutation(fit))
        for start in range(0, len(order) - batch + 1, batch):
            idx = order[start:start + batch]
            x = values[idx].float()
            shift = 4 * int(rng.integers(0, x.shape[2] // 4))
            x = torch.roll(x, shift, dims=2).unsqueeze(1)
            t = target[idx]
            s = net(x)
            loss = (1 - (s * t).sum(1)).mean()
            if relation:
                loss = loss + relation * ((s @ s.T - t @ t.T) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            step += 1
        mean, worst = held_out_cosine()
        print(f"epoch {epoch + 1}/{epochs}: loss {float(loss):.4f}, held-out cosine to the teacher mean {mean:.4f} "
              f"min {worst:.4f}, {time.perf_counter() - t0:.0f} s", flush=True)
    net.eval()
    save_checkpoint(out, net, distilled_from="shipped GeoPatch", epochs=epochs, channels=list(channels))
    print(f"-> {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("patches")
    p.add_argument("folders", nargs="+")
    p.add_argument("--out", required=True)
    p.add_argument("--per-detector", type=int, default=512)
    t = sub.add_parser("train")
    t.add_argument("data")
    t.add_argument("--channels", type=int, nargs=3, default=(16, 32, 64))
    t.add_argument("--out", required=True)
    t.add_argument("--epochs", type=int, default=10)
    t.add_argument("--batch", type=int, default=512)
    t.add_argument("--lr", type=float, default=3e-3)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--relation", type=float, default=1.0)
    a = ap.parse_args()
    if a.cmd == "patches":
        make_patches(a.folders, a.out, a.per_detector)
    else:
        train(a.data, tuple(a.channels), a.out, a.epochs, a.batch, a.lr, a.seed, a.relation)


if __name__ == "__main__":
    main()
