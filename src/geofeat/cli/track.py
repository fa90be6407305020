"""`geofeat track`: track a template region through sequences (TPS fitted by RANSAC or by local
consistency, then optionally refined photometrically)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..apps.tracking import DEFAULT_REFINE, RANSAC_THRESHOLD_PX, REFINE_MODES
from ..outputs import plural
from .common import check_devices
from .options import app_options, device_option, names, positive_number


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `track` to an argparse subparsers object; returns its parser."""
    p = subparsers.add_parser("track", help="track a template ROI through sequences (robust TPS, photometric refinement)")
    p.add_argument("sequences", nargs="+", help="sequence folders, or folders of sequences")
    app_options(p)
    p.add_argument("--roi", default=None, help="x0,y0,x1,y1 in reference pixels (default: object mask box shrunk by 10%%)")
    p.add_argument("--threshold", type=positive_number, default=RANSAC_THRESHOLD_PX,
                   help=f"inlier threshold of the spline fits (RANSAC and local consistency), pixels (default {RANSAC_THRESHOLD_PX:g})")
    p.add_argument("--refine", choices=REFINE_MODES, default=DEFAULT_REFINE,
                   help="after the robust TPS fit, refine the warp densely against the template: photometric (the "
                        f"refiner of 'geofeat groundtruth') or none (default {DEFAULT_REFINE})")
    p.add_argument("--lpips", action="store_true", help="LPIPS (needs local pretrained weights; not supported here)")
    device_option(p, ", and its mutual matching,", "; the other descriptors on the CPU")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Track the template ROI through every sequence; writes track.csv, tracking.md, grids and GIFs."""
    from ..apps.tracking import failed_rows, write_tracking

    roi = None
    if args.roi is not None:
        roi = [v for v in args.roi.split(",") if v.strip()]
        if len(roi) != 4:
            raise ValueError(f"--roi: expected x0,y0,x1,y1 (four numbers, pixels), got {args.roi!r}")
    if args.lpips:
        raise ValueError("--lpips: LPIPS needs pretrained backbone weights that geofeat never downloads; "
                         "not supported in this build (SSIM and NCC are reported instead)")
    device = check_devices(args.device, names(args.descriptors))
    skipped: list[str] = []
    # the folders as given: an --out inside a folder of sequences is refused too (`refuse_input_folder`)
    csv_path, table = write_tracking(args.sequences, args.out,
                                     names(args.descriptors), roi=roi,
                                     n_keypoints=args.keypoints, tps_dir=args.tps_dir, radius=args.radius,
                                     depth_scale=args.depth_scale, threshold_px=args.threshold,
                                     overwrite=args.overwrite, skipped=skipped, refine=args.refine,
                                     detector=args.detector, device=device)
    print((Path(args.out) / "tracking.md").read_text(encoding="utf-8"))
    print(f"wrote {csv_path}, {Path(args.out) / 'tracking.md'} and per sequence/descriptor grid.npz + track.gif")
    if skipped:
        print(f"{plural(len(skipped), 'frame')} SKIPPED: {', '.join(skipped)}", file=sys.stderr)
    # the table printed above counts each descriptor's failed frames; a run that tracked none is
    # no success (it exited 0)
    failed, total = failed_rows(csv_path)
    if failed == total:
        print(f"track: no frame was tracked: the fit failed (or the frame was skipped) for every target frame "
              f"and descriptor ({failed} of {total}); track.csv and tracking.md hold the failed rows", file=sys.stderr)
        return 1
    return 1 if skipped else 0
