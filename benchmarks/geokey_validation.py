"""GeoKey's validation figures (GeoPatch MS, MMA, correct matches, repeatability, reference keypoints)
for weights files and selection settings, on simulated sequences with ground truth.

Each entry is WEIGHTS[:key=value,...]: `shipped` or a weights file, then any of `threshold`,
`min_fraction`, `denoise` (`geofeat.detectors.geokey.detect_geokey`'s options; `threshold=-inf` with
`min_fraction=0` gives the n best). `--sift` adds SIFT's own figures (the admissibility reference of
`geofeat train-detector`). `--by-preset` reports the sequences whose folder names hold `hard` and
`paper` separately.

    PYTHONPATH=src python benchmarks/geokey_validation.py out/det2/val/* --entries shipped shipped:denoise=2 \\
        out/gk_d2.npz shipped:threshold=-inf,min_fraction=0 --by-preset
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from geofeat.detectors.geokey import detect_geokey, load_geokey
from geofeat.keypoints import detect_sift
from geofeat.train.detector import validation_scores

OPTIONS = ("threshold", "min_fraction", "denoise")


def parse_entry(text: str):
    """'WEIGHTS[:key=value,...]' -> (label, detector callable (frame, n) -> Keypoints)."""
    weights, _, settings = text.partition(":")
    options = {}
    for item in filter(None, settings.split(",")):
        key, _, value = item.partition("=")
        if key not in OPTIONS:
            raise SystemExit(f"--entries: unknown setting {key!r} in {text!r}; known: {', '.join(OPTIONS)}")
        options[key] = float(value)
    model = load_geokey(None if weights == "shipped" else weights)
    return text, lambda frame, n: detect_geokey(frame, n, model, **options)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequences", nargs="+", type=Path, help="simulated sequence folders with ground truth")
    ap.add_argument("--entries", nargs="+", default=["shipped"], help="WEIGHTS[:key=value,...] (see above)")
    ap.add_argument("--keypoints", default="1024,2048")
    ap.add_argument("--sift", action="store_true", help="also SIFT's keypoints")
    ap.add_argument("--by-preset", action="store_true", help="`hard` and `paper` sequences separately")
    a = ap.parse_args()
    counts = [int(n) for n in a.keypoints.split(",")]
    groups = {"all": a.sequences}
    if a.by_preset:
        groups = {p: [s for s in a.sequences if p in s.name] for p in ("hard", "paper")}
    detectors = [parse_entry(e) for e in a.entries] + ([("SIFT", detect_sift)] if a.sift else [])
    print(f"{len(a.sequences)} sequences; load average {os.getloadavg()[0]:.2f}")
    print("| sequences | entry | keypoints | MS | MMA | correct matches / pair | repeatability | reference keypoints / frame |")
    print("|---|---|---|---|---|---|---|---|")
    for group, folders in groups.items():
        for label, detector in detectors:
            for n in counts:
                t = time.perf_counter()
                r = validation_scores(folders, detector, n)
                print(f"| {group} ({len(folders)}) | {label} | {n} | {r['ms']:.4f} | {r['mma']:.3f} | {r['hits']:.1f} | "
                      f"{r['repeatability']:.3f} | {r['n_ref']:.0f} |   ({time.perf_counter() - t:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
