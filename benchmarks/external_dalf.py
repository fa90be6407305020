"""Run DALF (Potje et al., CVPR 2023: the same authors' learned detector + descriptor) on every frame of
geofeat sequences and write its features for `geofeat bench --features DALF=OUT`.

DALF is not a dependency of geofeat and none of its code is in this repository: this script imports
it from a checkout of verlab/DALF_CVPR_2023 that you make yourself, in a scratch environment with
kornia (DALF's only extra; its `torchvision.transforms` import is unused at inference and may be
satisfied by an empty stub module):

    git clone https://github.com/verlab/DALF_CVPR_2023 /tmp/dalf
    pip install --target /tmp/dalf-site kornia kornia_rs --no-deps
    PYTHONPATH=/tmp/dalf-site:/tmp/dalf .venv/bin/python benchmarks/external_dalf.py \\
        out/difficulty/paper --out out/dalf/paper [--top-k 2048]
    .venv/bin/geofeat bench out/difficulty/paper --descriptors geopatch --features DALF=out/dalf/paper \\
        --keypoints 1024 --out out/bench-dalf

Writes OUT/<sequence>/<frame>.npz with `keypoints` (N, 2) pixels, `descriptors` (N, 128) float32
and `scores` (N,) (DALF's normalised detection map value; the bench keeps the best --keypoints).
DALF sees the colour image only, with its default settings (single scale, NMS threshold 25).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np

import geofeat
from geofeat.io import RGB_SUFFIX, find_sequences


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("datasets", nargs="+", help="sequence folders, or folders of them")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--top-k", type=int, default=2048)
    args = ap.parse_args()

    import torch
    from modules.models.DALF import DALF_extractor  # from the user's DALF checkout on PYTHONPATH

    torch.set_num_threads(os.cpu_count() or 1)
    dalf = DALF_extractor(dev=torch.device("cuda" if torch.cuda.is_available() else "cpu"))
    seconds, frames = 0.0, 0
    for folder in find_sequences(args.datasets):
        seq = geofeat.read_sequence(folder)
        out = args.out / seq.name
        out.mkdir(parents=True, exist_ok=True)
        for name in seq.names:
            bgr = cv2.imread(str(seq.folder / f"{name}{RGB_SUFFIX}"), cv2.IMREAD_COLOR)
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)  # DALF reads RGB uint8
            t0 = time.perf_counter()
            kps, desc = dalf.detectAndCompute(np.ascontiguousarray(rgb), top_k=args.top_k)
            seconds += time.perf_counter() - t0
            frames += 1
            xy = np.array([k.pt for k in kps], dtype=np.float32).reshape(-1, 2)
            score = np.array([k.response for k in kps], dtype=np.float32)
            np.savez(out / f"{name}.npz", keypoints=xy, descriptors=desc.astype(np.float32), scores=score)
        print(f"{seq.name}: {len(seq.names)} frames, last {len(xy)} keypoints")
    print(f"DALF: {frames} frames, {seconds / max(frames, 1):.2f} s per frame (load average {os.getloadavg()[0]:.2f})")


if __name__ == "__main__":
    main()
