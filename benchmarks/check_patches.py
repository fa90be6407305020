"""Check that f(.) gives the same patches as a reference revision of geofeat (default: the commit
before the speed work, 0a68b13), on the Kinect demo frame with 2048 SIFT keypoints, for the default
depth config and the full-resolution one (`fill='idw', smooth_levels=0, mesh_scale=1.0`).

Run: python benchmarks/check_patches.py [--ref REV] [--tol 1e-5]
The reference source is taken with `git archive REV src` into a temporary folder and run in a
subprocess; prints the largest differences and exits 1 if any exceeds the tolerance.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CONFIGS = {"default": {}, "clean": {"fill": "idw", "smooth_levels": 0, "mesh_scale": 1.0}}
FIELDS = ("values", "coords", "points", "rings_reached", "valid")

PATCHES = """
import sys, cv2, numpy as np, geofeat
from geofeat.depth import DepthConfig
frame = geofeat.read_demo_frame()
gray = np.clip(frame.image * 255 + 0.5, 0, 255).astype(np.uint8)
sift = cv2.SIFT_create(nfeatures=2048, contrastThreshold=0.004)
xy = np.array([k.pt for k in sorted(sift.detect(gray, None), key=lambda k: -k.response)])
out = {"xy": xy}
for name, kwargs in %r.items():
    P = geofeat.polar_patches(frame, xy, depth_config=DepthConfig(**kwargs))
    for f in %r:
        out[name + "_" + f] = getattr(P, f)
np.savez(sys.argv[1], **out)
"""


def patches(src: Path, out: Path) -> dict:
    code = PATCHES % (CONFIGS, FIELDS)
    subprocess.run([sys.executable, "-c", code, str(out)], check=True, env={"PYTHONPATH": str(src)},
                   cwd=str(out.parent))
    return dict(np.load(out))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ref", default="0a68b13", help="git revision of the reference (default %(default)s)")
    parser.add_argument("--tol", type=float, default=1e-5)
    args = parser.parse_args()
    repo = Path(__file__).resolve().parent.parent
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        archive = subprocess.run(["git", "-C", str(repo), "archive", args.ref, "src"], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tmp)], input=archive, check=True)
        ref = patches(tmp / "src", tmp / "ref.npz")
        new = patches(repo / "src", tmp / "new.npz")
    worst = 0.0
    for name in CONFIGS:
        valid = ref[name + "_valid"]
        same = np.array_equal(valid, new[name + "_valid"]) and np.array_equal(
            ref[name + "_rings_reached"], new[name + "_rings_reached"])
        diffs = {f: float(np.nanmax(np.abs(new[f"{name}_{f}"][valid] - ref[f"{name}_{f}"][valid]), initial=0.0))
                 for f in ("values", "coords", "points")}
        worst = max([worst, *diffs.values()] + ([np.inf] if not same else []))
        print(f"{name}: {len(valid)} keypoints, {int(valid.sum())} valid; validity and rings reached "
              f"{'identical' if same else 'DIFFER'}; largest difference: values {diffs['values']:.3g}, "
              f"coords {diffs['coords']:.3g} px, points {diffs['points']:.3g} m")
    ok = worst <= args.tol
    print(f"{'OK' if ok else 'FAIL'}: patches within {args.tol:g} of revision {args.ref}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
