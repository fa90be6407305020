"""`geofeat groundtruth`: dense ground truth (the authors' TPS files) for sequences annotated with landmarks."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ..outputs import plural
from .options import depth_scale_option, number_at_least


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `groundtruth` to an argparse subparsers object; returns its parser."""
    from ..groundtruth.defaults import DEFAULT_DEPTH_MARGIN_M, DEFAULT_MARGIN_PX, DEFAULT_SPACING_PX

    p = subparsers.add_parser(
        "groundtruth",
        help="dense ground truth (the authors' TPS files) for sequences annotated with landmarks",
        description="Landmarks (<name>.csv in every frame) -> robust thin-plate spline per frame -> photometric "
        "refinement on a regular control-point grid -> OUT/<sequence>/<k>_theta.npy, <k>_ctrlpts.npy, "
        "<frame>_objmask.png, <k>_SSIM.png (read by `geofeat bench --tps-dir OUT`), report.csv/json and "
        "<k>_overlay.png pictures.",
    )
    p.add_argument("sequences", nargs="+", type=Path, help="sequence folders, or folders of sequences")
    p.add_argument("--out", required=True, type=Path, help="output folder (one sub-folder per sequence)")
    p.add_argument("--no-refine", action="store_true", help="landmark-only spline, no photometric refinement")
    p.add_argument("--spacing", type=number_at_least(2), default=None,
                   help=f"control-point spacing of the refinement in reference pixels (default {DEFAULT_SPACING_PX:g}; "
                        "not with --no-refine)")
    p.add_argument("--margin", type=number_at_least(0), default=DEFAULT_MARGIN_PX,
                   help=f"object mask: pixels beyond the landmarks' convex hull (default {DEFAULT_MARGIN_PX:g})")
    p.add_argument("--depth-margin", type=number_at_least(0), default=DEFAULT_DEPTH_MARGIN_M,
                   help=f"object mask: metres beyond the landmarks' depth range (default {DEFAULT_DEPTH_MARGIN_M:g})")
    depth_scale_option(p)  # the depth-units warning advises it, and the object mask keeps depths by metres
    again = p.add_mutually_exclusive_group()
    again.add_argument("--overwrite", action="store_true",
                       help="replace what geofeat wrote in existing OUT/<sequence> folders (other files stay)")
    again.add_argument("--resume", action="store_true",
                       help="keep the OUT/<sequence> folders an earlier (interrupted) run finished with the same "
                            "settings, and make the others")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run `groundtruth`; ValueError on bad input. Returns 0, or 1 when a frame failed."""
    from ..io import find_sequences, read_sequence
    from ..outputs import GROUND_TRUTH, check_out_dir, refuse_input_folder
    from ..groundtruth.pipeline import (GroundTruthConfig, check_config, check_sequence, finished_result,
                                       generate_ground_truth, result_files)

    from ..groundtruth.defaults import DEFAULT_SPACING_PX

    if args.no_refine and args.spacing is not None:  # it was accepted and ignored (and then refused --resume)
        raise ValueError(f"--spacing: {args.spacing:g} is the control-point spacing of the photometric refinement, "
                         "which --no-refine leaves out; drop one of them")
    spacing = DEFAULT_SPACING_PX if args.spacing is None else args.spacing
    config = GroundTruthConfig(refine=not args.no_refine, spacing=spacing, margin_px=args.margin,
                               depth_margin_m=args.depth_margin)
    check_config(config)
    folders = find_sequences(args.sequences, unique_names=True)
    if args.out.exists() and not args.out.is_dir():
        raise ValueError(f"--out: {args.out} is a file, not a folder")
    refuse_input_folder(args.out, [*args.sequences, *folders])  # resumed or not; each OUT/<sequence> below too
    done = []  # sequences an earlier run finished (--resume)
    sequences = {}
    for folder in folders:  # every input and output is checked before the first frame is refined
        seq = sequences[folder] = read_sequence(folder, depth_scale=args.depth_scale)
        check_sequence(seq, config)
        if args.resume and finished_result(args.out / folder.name, seq, config):
            done.append(folder)
            continue
        try:
            check_out_dir(args.out / folder.name, args.overwrite, files=result_files(seq), inputs=folders,
                          writes=GROUND_TRUTH)
        except ValueError as error:  # a rerun after an interrupt: say how to keep what was finished
            if (args.out / folder.name / "report.json").is_file() and not args.resume:
                raise ValueError(f"{error}; or pass --resume to keep the sequences an earlier run finished") from None
            raise
    if done:
        print(f"kept {plural(len(done), 'sequence')} finished by an earlier run: {', '.join(f.name for f in done)}")
    failed = []
    for folder in folders:
        if folder in done:
            continue
        out = args.out / folder.name
        reports = generate_ground_truth(sequences[folder], out, config, progress=not args.no_progress,
                                        overwrite=args.overwrite)
        ok = [r for r in reports if r.status == "ok"]
        bad = [r for r in reports if r.status != "ok"]
        if ok:
            # the residual is in-sample (the landmarks made the spline); leave-one-out tells how well it
            # predicts a point between landmarks, so both are printed, named
            print(f"{folder.name}: {len(ok)} of {plural(len(reports), 'frame')}, landmark residual "
                  f"{sum(r.landmark_median_px for r in ok) / len(ok):.2f} px (the mean over frames of each frame's median; "
                  "in-sample; leave-one-out "
                  f"{_mean_finite([r.loo_median_px for r in ok])}), SSIM "
                  f"{sum(r.ssim_before for r in ok) / len(ok):.3f} -> {sum(r.ssim_after for r in ok) / len(ok):.3f}, "
                  f"{sum(r.seconds for r in ok) / len(ok):.2f} s/frame; wrote {out}")
        for r in bad:
            print(f"{folder.name}: FAILED frame {r.frame}: {r.reason} (no TPS files written for it)")
            failed.append(f"{folder.name}/{r.frame}")
    if failed:
        print(f"{plural(len(failed), 'frame')} failed; see report.csv in each output folder")
    return 1 if failed else 0


def _mean_finite(values: list[float]) -> str:
    """The mean of the finite `values` in pixels, "n/a" when none is (too few landmarks to leave one out)."""
    finite = [v for v in values if math.isfinite(v)]
    return f"{sum(finite) / len(finite):.2f} px" if finite else "n/a"
