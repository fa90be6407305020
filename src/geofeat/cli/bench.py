"""`geofeat bench`: matching score of descriptors on datasets in the public layout."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..constants import N_KEYPOINTS
from ..descriptors import available_descriptors
from ..keypoints import KEYPOINT_SETS
from .common import check_devices
from .options import (depth_profile_option, depth_scale_option, detector_option, device_option, keypoint_count,
                      keypoint_set_for, names, radius_option, whole_number)


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `bench` to an argparse subparsers object; returns its parser."""
    p = subparsers.add_parser("bench", help="matching score of descriptors on datasets in the public layout")
    p.add_argument("datasets", nargs="+", help="sequence folders, or folders of sequences")
    p.add_argument("--descriptors", default="geobit,geopatch,orb,sift",
                   help=f"comma-separated, from {','.join(available_descriptors())} (default geobit,geopatch,orb,sift)")
    p.add_argument("--protocol", choices=("detect", "landmarks"), default="detect",
                   help="detect: keypoints detected independently in each frame, the paper's protocol (default); "
                        "landmarks: the csv landmarks of every frame are described and matched")
    p.add_argument("--out", required=True, help="output folder: results.csv, table.md, plots, timing.md")
    radius_option(p)
    depth_scale_option(p)
    p.add_argument("--keypoints", type=keypoint_count, default=N_KEYPOINTS, help="keypoints per frame (default 2048)")
    detector_option(p)
    p.add_argument("--features", action="append", metavar="NAME=PATH",
                   help="also score features computed elsewhere: an hloc-style .h5 (groups <sequence>/<frame>) "
                        "or a folder of <frame>.npz with keypoints, descriptors and optional scores, or the DIR/NAME.npz "
                        "given to `geofeat extract --out` (repeatable)")
    p.add_argument("--tps-dir", default=None, help="the authors' published TPS ground truth, one folder per sequence")
    p.add_argument("--workers", type=whole_number(1), default=1, help="local worker processes (sequences in parallel)")
    p.add_argument("--scheduler", default=None, help="Dask scheduler address (e.g. tcp://host:8786); needs geofeat[dask]")
    p.add_argument("--timing", action="store_true", help="also time f(.), extraction and matching for 250 and 2048 keypoints")
    p.add_argument("--keypoint-set", choices=KEYPOINT_SETS, default=None,
                   help="SIFT keypoints only. protocol: OpenCV SIFT's strongest exactly as returned, duplicates "
                        "kept (default, the published protocol); unique: one keypoint per position")
    depth_profile_option(p, None)
    p.add_argument("--overwrite", action="store_true", help="redo every result (default: a rerun skips finished ones)")
    device_option(p, ", and its matching,", "; the other descriptors on the CPU. results.csv records each row's "
                  "device, table.md names them, and --timing times GeoPatch there; resuming OUT on another device "
                  "is refused")
    # None until run() resolves them, so that --keypoints 2048 or --detector sift given with
    # --protocol landmarks is reported as unused too, not only values other than the defaults
    p.set_defaults(func=run, keypoints=None, detector=None)
    return p


def run(args: argparse.Namespace) -> int:
    """Run the benchmark and write results.csv, table.md, details.md, plots (timing.md with --timing)."""
    from ..bench.report import (detail_table, markdown_table, plot_curves, read_results, scenario_groups,
                                unscored_pairs_note)
    from ..bench.runner import BenchConfig, run_benchmark
    from ..bench.timing import timing_table
    from ..depth import sequence_depth_profile
    from ..inputs import resolve_radius
    from ..io import find_sequences, frame_names, read_sequence, reference_name
    from ..outputs import add_to_manifest, atomic_file, plural

    def write(path: Path, text: str) -> None:
        with atomic_file(path) as tmp:
            tmp.write_text(text, encoding="utf-8")
        add_to_manifest(path.parent, [path.name])

    given = {"--keypoints": args.keypoints is not None, "--detector": args.detector is not None,
             "--keypoint-set": args.keypoint_set is not None}
    args.keypoints = N_KEYPOINTS if args.keypoints is None else args.keypoints
    args.detector = "sift" if args.detector is None else args.detector
    if args.protocol == "landmarks":  # the annotated landmarks are described: nothing is detected
        unused = [flag for flag, named in given.items() if named]
        if unused:
            print(f"bench: --protocol landmarks describes the annotated landmarks themselves; {', '.join(unused)} "
                  "not used")
        args.keypoints, args.detector, args.keypoint_set = N_KEYPOINTS, "sift", None  # the same run whatever they say
    device = check_devices(args.device, names(args.descriptors))
    config = BenchConfig(descriptors=names(args.descriptors), protocol=args.protocol,
                         radius=args.radius, depth_scale=args.depth_scale, n_keypoints=args.keypoints,
                         tps_dir=args.tps_dir, keypoint_set=keypoint_set_for(args.detector, args.keypoint_set, "protocol"),
                         depth_profile=args.depth_profile,
                         detector=args.detector, features=tuple(args.features or ()), device=device)
    out = Path(args.out)
    csv_path, failed = run_benchmark(args.datasets, out, config, workers=args.workers, scheduler=args.scheduler,
                                     overwrite=args.overwrite)
    rows = read_results(csv_path)
    if not rows:
        raise ValueError(f"datasets: no sequence could be evaluated ({len(failed)} failed)")
    group_of = scenario_groups(find_sequences(args.datasets))  # simulated sequences: their scenario
    note = ""
    if config.tps_dir and config.protocol == "detect":
        from ..groundtruth.sources import without_ssim_maps

        unfiltered = without_ssim_maps(config.tps_dir, dict.fromkeys(r["sequence"] for r in rows))
        if unfiltered:
            note = (f"\nSSIM filter (protocol step 3) skipped for {', '.join(unfiltered)}: no <k>_SSIM.png in "
                    "their TPS files, so the object masks alone decide which target keypoints are scored.\n")
    frames_of = {f.name: frame_names(f) for f in find_sequences(args.datasets)}
    note += unscored_pairs_note(rows, {seq: [n for n in frames if n != reference_name(frames)]
                                       for seq, frames in frames_of.items() if frames})
    table = markdown_table(rows, group_of) + note
    write(out / "table.md", table)
    print(table)
    if config.protocol == "detect":
        details = detail_table(rows) + note
        write(out / "details.md", details)
        print(details)
    for path in plot_curves(rows, out, group_of):
        add_to_manifest(out, [Path(path).name])
        print(f"wrote {path}")
    # timed on the first sequence that did not fail: a failed first one (an unreadable reference frame)
    # raised its error after the results were written, exit 2 with no timing.md and no FAILED line
    timed = [f for f in find_sequences(args.datasets) if f.name not in failed] if args.timing else []
    if args.timing and not timed:
        print("timing: every sequence failed; timing.md not written")
    if timed:
        seq = read_sequence(timed[0], depth_scale=args.depth_scale)
        # every descriptor of results.csv, those an earlier run scored too (a resumed run may name fewer)
        external = set(config.methods) - set(config.descriptors)
        described = tuple(dict.fromkeys([*config.descriptors, *(r["descriptor"] for r in rows
                                                                if r["descriptor"] not in external)]))
        timing = timing_table(seq.frame(seq.reference), described, resolve_radius(args.radius, seq),
                              depth_profile=sequence_depth_profile(seq, args.depth_profile), device=config.device)
        write(out / "timing.md", timing)
        print(timing)
    print(f"wrote {csv_path} ({plural(len(rows), 'row')}) and {out / 'table.md'}"
          + (f"; FAILED sequences: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0
