"""The `geofeat` command line: the parser and the commands (the demo in `cli/demo.py`; `simulate` and
`groundtruth` in `sim/command.py` and `groundtruth/command.py`, beside their modules)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from ..constants import DEFAULT_RADIUS_M, DEPTH_PROFILE_NAMES, DEPTH_SCALE_M, N_KEYPOINTS
from ..keypoints import KEYPOINT_SETS, check_detector_name
from .demo import run as _demo


def _file_label(descriptor: str) -> str:
    """A descriptor name fit for a file name ("geopatch=runs/a.pt" -> "geopatch-a")."""
    if "=" in descriptor:
        name, path = descriptor.split("=", 1)
        return f"{name}-{Path(path).stem}"
    return descriptor


def _features_path(out: Path, descriptor: str) -> Path:
    return out if out.suffix in (".h5", ".npz") else out / f"features-{descriptor}.h5"


def _skip_frame(skipped: list[str], name: str, error: Exception) -> None:
    """Report a frame that cannot be processed by name; the run goes on and exits 1 at the end."""
    from tqdm import tqdm

    skipped.append(name)
    tqdm.write(f"SKIPPED frame {name}: {str(error).splitlines()[0] if str(error) else type(error).__name__}")


def _finish_skipped(skipped: list[str], total: int, what: str) -> int:
    """Exit status after a run that skipped `skipped` of `total` frames (1 when any was skipped)."""
    if skipped and len(skipped) >= total:
        raise ValueError(f"{what}: every frame was skipped ({', '.join(skipped[:5])}); nothing written")
    if skipped:
        print(f"{len(skipped)} frame(s) SKIPPED: {', '.join(skipped)}", file=sys.stderr)
        return 1
    return 0


def _frame_and_keypoints(seq, name: str, args: argparse.Namespace):
    """(frame, keypoints) of frame `name` with the command's detector options; ValueError when the
    frame cannot be read or has no keypoints (extract and match skip such a frame by name)."""
    from ..keypoints import detect

    frame = seq.frame(name)
    kps = detect(frame, args.keypoints, detector=args.detector, keypoint_set=args.keypoint_set)
    if len(kps) == 0:
        raise ValueError("no keypoints detected")
    return frame, kps


def _extract(args: argparse.Namespace) -> int:
    import os

    from tqdm import tqdm

    from ..depth import PROFILES, sequence_depth_profile
    from ..descriptors import make_descriptor
    from ..features import save_features
    from ..inputs import resolve_radius
    from ..io import read_sequence
    from ..outputs import atomic_file, check_out_file, partial_name

    seq = read_sequence(args.folder, depth_scale=args.depth_scale)
    radius = resolve_radius(args.radius, seq)
    path = _features_path(Path(args.out), _file_label(args.descriptor))
    finals = [path] if path.suffix == ".h5" else [path.with_name(f"{path.stem}-{n}.npz") for n in seq.names]
    for final in finals:
        check_out_file(final, args.overwrite)
    profile = sequence_depth_profile(seq, args.depth_profile)
    descriptor = make_descriptor(args.descriptor, radius=radius, depth_config=PROFILES[profile])
    print(f"{seq.name}: depth profile {profile}, detector {args.detector}, keypoints {args.keypoint_set}, "
          f"radius {radius:g} m")
    skipped: list[str] = []
    written: list[tuple[Path, Path]] = []  # (temporary, final) of the .npz files
    with atomic_file(path) as h5_tmp:
        try:
            for name in tqdm(seq.names, desc=f"extract {args.descriptor}", unit="frame"):
                try:
                    frame, kps = _frame_and_keypoints(seq, name, args)
                    features = descriptor.compute(frame, kps)
                except ValueError as error:
                    _skip_frame(skipped, name, error)
                    continue
                if path.suffix == ".h5":
                    save_features(h5_tmp, features, name=name)
                else:
                    final = path.with_name(f"{path.stem}-{name}.npz")
                    tmp = partial_name(final)
                    save_features(tmp, features)
                    written.append((tmp, final))
            status = _finish_skipped(skipped, len(seq), "extract")
            for tmp, final in written:
                os.replace(tmp, final)
            written.clear()
        finally:
            for tmp, _ in written:
                tmp.unlink(missing_ok=True)
    where = path if path.suffix == ".h5" else path.with_name(f"{path.stem}-<frame>.npz")
    print(f"wrote {args.descriptor} features of {len(seq) - len(skipped)} frames of {seq.folder} to {where}")
    return status


def _match(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ..groundtruth.sources import GroundTruth, correct_matches
    from ..depth import PROFILES, sequence_depth_profile
    from ..descriptors import make_descriptor
    from ..features import save_matches
    from ..inputs import resolve_radius
    from ..io import read_sequence
    from ..matching import match
    from ..outputs import check_out_dir, output_folder
    from ..viz import draw_matches

    seq = read_sequence(args.folder, depth_scale=args.depth_scale)
    if len(seq) < 2:
        raise ValueError(f"folder: {seq.folder} has a single frame; matching needs a reference and a target")
    out = check_out_dir(args.out, args.overwrite)
    radius = resolve_radius(args.radius, seq)
    profile = sequence_depth_profile(seq, args.depth_profile)
    descriptor = make_descriptor(args.descriptor, radius=radius, depth_config=PROFILES[profile])
    label = _file_label(args.descriptor)
    try:
        truth = GroundTruth(seq, None)
    except ValueError as error:
        if "no ground truth" not in str(error):
            raise
        truth = None  # no ground truth: matches are written, not judged
    print(f"{seq.name}: depth profile {profile}, detector {args.detector}, keypoints {args.keypoint_set}, "
          f"radius {radius:g} m, ground truth: "
          + ("none" if truth is None else "simulator (exact)" if truth.exact else "thin-plate spline on the landmarks"))
    if truth is not None and not truth.exact:
        for name in seq.names:  # the landmark validator, before any work
            seq.landmarks(name)
    try:
        ref, k_ref = _frame_and_keypoints(seq, seq.reference, args)
    except ValueError as error:
        raise ValueError(f"frame {seq.reference}: the reference frame cannot be used ({error}); nothing to match") from None
    f_ref = descriptor.compute(ref, k_ref)
    total_matches, total_correct = 0, 0
    skipped: list[str] = []
    with output_folder(out) as tmp:
        matches_path = tmp / f"matches-{label}.h5"
        for name in tqdm(seq.targets, desc=f"match {args.descriptor}", unit="pair"):
            try:
                tgt, k_tgt = _frame_and_keypoints(seq, name, args)
                m = match(f_ref, descriptor.compute(tgt, k_tgt))
            except ValueError as error:
                _skip_frame(skipped, name, error)
                continue
            save_matches(matches_path, m, name=f"{seq.reference}/{name}")
            n_matches = int((m.matches0 >= 0).sum())
            total_matches += n_matches
            summary = f"{n_matches} matches"
            correct = None if truth is None else correct_matches(truth, name, k_ref.xy, k_tgt.xy, m.matches0)
            if correct is not None:
                total_correct += int(correct.sum())
                summary += f", {int(correct.sum())} correct"
            picture = draw_matches(ref, tgt, k_ref.xy, k_tgt.xy, m.matches0, correct, title=f"{args.descriptor}: {summary}")
            cv2.imwrite(str(tmp / f"{seq.reference}__{name}__{label}.png"), picture)
            tqdm.write(f"{seq.reference} -> {name}: {summary}")
        status = _finish_skipped(skipped, len(seq.targets), "match")
    print(f"total: {total_matches} matches" + (f", {total_correct} correct" if truth is not None else " (no ground truth)"))
    print(f"wrote {out / f'matches-{label}.h5'} and one match picture per pair in {out}")
    return status


def _train(args: argparse.Namespace) -> int:
    from functools import partial

    from ..descriptors.geopatch import GeoPatchConfig
    from ..train.dataset import PatchSet, build_patch_set, validation_pairs
    from ..train.loop import TrainConfig, train

    net = None  # geodesic polar patches with the depth profile asked for (auto: per sequence)
    build = partial(build_patch_set, depth_config=args.depth_profile)
    make_validation = partial(validation_pairs, depth_config=args.depth_profile)
    if args.net != "geopatch":  # image-patch baselines (tfeat-sim, logpolar-sim) on the same data
        from ..descriptors.image_patch_nets import ImagePatchNet, default_config
        from ..train.imagepatches import build_image_patch_set, image_validation_pairs

        net = ImagePatchNet(default_config(args.net))
        build = partial(build_image_patch_set, arch=args.net)
        make_validation = partial(image_validation_pairs, arch=args.net)
    cache = Path(str(args.out) + ".patches.npz")
    if args.resume and cache.is_file():
        data = PatchSet.load(cache)
        print(f"training patches: {len(data)} from {cache}")
    else:
        data = build(args.data, n_keypoints=args.keypoints)
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        data.save(cache)
        print(f"training patches: {len(data)} of {len(np.unique(data.ids))} surface points (cached in {cache})")
    validation = make_validation(args.val) if args.val else None
    config = TrainConfig(
        epochs=args.epochs, steps_per_epoch=args.steps, batch_size=args.batch_size, lr=args.lr,
        mining=args.mining, augment_shift=args.augment_shift, seed=args.seed,
        augment_photometric=args.augment_photometric,
        net=GeoPatchConfig(channels=tuple(args.channels), angle_pool=not args.no_angle_pool),
    )
    history = train(data, args.out, config, validation=validation, resume=args.resume, device=args.device, net=net,
                    init=args.init)
    print(f"wrote {args.out} (final loss {history['loss'][-1]:.4f}, validation MS {history['val_ms'][-1]:.3f}), "
          f"{args.out}.png and {args.out}.json")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from ..bench.report import detail_table, markdown_table, plot_curves, read_results
    from ..bench.runner import BenchConfig, run_benchmark
    from ..bench.timing import timing_table
    from ..depth import sequence_depth_profile
    from ..io import find_sequences, read_sequence
    from ..outputs import add_to_manifest, atomic_file

    def write(path: Path, text: str) -> None:
        with atomic_file(path) as tmp:
            tmp.write_text(text)
        add_to_manifest(path.parent, [path.name])

    config = BenchConfig(descriptors=tuple(d for d in args.descriptors.split(",") if d), protocol=args.protocol,
                         radius=args.radius, depth_scale=args.depth_scale, n_keypoints=args.keypoints,
                         tps_dir=args.tps_dir, keypoint_set=args.keypoint_set, depth_profile=args.depth_profile,
                         detector=args.detector, features=tuple(args.features or ()))
    out = Path(args.out)
    csv_path, failed = run_benchmark(args.datasets, out, config, workers=args.workers, scheduler=args.scheduler,
                                     overwrite=args.overwrite)
    rows = read_results(csv_path)
    if not rows:
        raise ValueError(f"datasets: no sequence could be evaluated ({len(failed)} failed)")
    table = markdown_table(rows)
    write(out / "table.md", table)
    print(table)
    if config.protocol == "detect":
        details = detail_table(rows)
        write(out / "details.md", details)
        print(details)
    for path in plot_curves(rows, out):
        add_to_manifest(out, [Path(path).name])
        print(f"wrote {path}")
    if args.timing:
        seq = read_sequence(find_sequences(args.datasets)[0], depth_scale=args.depth_scale)
        timing = timing_table(seq.frame(seq.reference), config.descriptors, args.radius or DEFAULT_RADIUS_M,
                              depth_profile=sequence_depth_profile(seq, args.depth_profile))
        write(out / "timing.md", timing)
        print(timing)
    print(f"wrote {csv_path} ({len(rows)} rows) and {out / 'table.md'}"
          + (f"; FAILED sequences: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


def _train_detector(args: argparse.Namespace) -> int:
    from ..train.detector import train_detector

    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    model, results = train_detector(args.data, args.val, args.out, n=args.keypoints, hidden=tuple(args.hidden),
                                    steps=args.steps, seed=args.seed, labels=args.labels)
    print("| scorer | NMS radius (px) | GeoPatch MS | MMA | repeatability | correct matches / pair |")
    print("|---|---|---|---|---|---|")
    for (name, radius), r in results.items():
        chosen = name == ("image + depth cues" if model.uses_depth_cues else "image cues") and radius == model.nms_radius
        print(f"| {name}{' (chosen)' if chosen else ''} | {radius:g} | {r['ms']:.3f} | {r['mma']:.3f} | "
              f"{r['repeatability']:.3f} | {r['hits']:.0f} |")
    print(f"wrote {args.out} (validation at {args.keypoints} keypoints per frame)")
    return 0


def _retrieval(args: argparse.Namespace) -> int:
    from ..apps.retrieval import run_retrieval

    acc, db = run_retrieval(args.datasets, args.out, tuple(d for d in args.descriptors.split(",") if d),
                            words=args.words, n_samples=args.samples, seed=args.seed, classes_file=args.classes,
                            n_keypoints=args.keypoints, tps_dir=args.tps_dir, radius=args.radius,
                            depth_scale=args.depth_scale, include_own_sequence=args.include_own_sequence,
                            overwrite=args.overwrite, detector=args.detector)
    out = Path(args.out)
    print((out / "retrieval.md").read_text())
    print(f"wrote {out / 'retrieval.csv'}, {out / 'acc_at_k.png'}, {out / 'top6.png'}")
    if db.skipped:
        print(f"{len(db.skipped)} frame(s) SKIPPED: {', '.join(db.skipped)}", file=sys.stderr)
    return 1 if db.skipped else 0


def _track(args: argparse.Namespace) -> int:
    from ..io import find_sequences
    from ..apps.tracking import write_tracking

    roi = None
    if args.roi is not None:
        roi = [v for v in args.roi.split(",") if v.strip()]
        if len(roi) != 4:
            raise ValueError(f"--roi: expected x0,y0,x1,y1 (four numbers, pixels), got {args.roi!r}")
    if args.lpips:
        raise ValueError("--lpips: LPIPS needs pretrained backbone weights that geofeat never downloads; "
                         "not supported in this build (SSIM and NCC are reported instead)")
    skipped: list[str] = []
    csv_path, table = write_tracking(find_sequences(args.sequences, unique_names=True), args.out,
                                     tuple(d for d in args.descriptors.split(",") if d), roi=roi,
                                     n_keypoints=args.keypoints, tps_dir=args.tps_dir, radius=args.radius,
                                     depth_scale=args.depth_scale, threshold_px=args.threshold,
                                     overwrite=args.overwrite, skipped=skipped, refine=args.refine,
                                     detector=args.detector)
    print((Path(args.out) / "tracking.md").read_text())
    print(f"wrote {csv_path}, {Path(args.out) / 'tracking.md'} and per sequence/descriptor grid.npz + track.gif")
    if skipped:
        print(f"{len(skipped)} frame(s) SKIPPED: {', '.join(skipped)}", file=sys.stderr)
    return 1 if skipped else 0


def build_parser() -> argparse.ArgumentParser:
    from ..descriptors import available_descriptors, check_descriptor_name

    def descriptor_name(text: str) -> str:
        try:
            return check_descriptor_name(text)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    def depth_profile_option(p: argparse.ArgumentParser, default: str | None) -> None:
        p.add_argument("--depth-profile", choices=DEPTH_PROFILE_NAMES, default=default,
                       help="depth preprocessing: kinect (hole filling, smoothing, half-resolution mesh), clean "
                            "(raw depth, holes filled, full-resolution mesh) or auto (chosen from the measured "
                            "depth noise; default, unless the sequence's geofeat.json names one)")

    def detector_name(text: str) -> str:
        try:
            return check_detector_name(text)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    def detector_option(p: argparse.ArgumentParser) -> None:
        p.add_argument("--detector", default="sift", type=detector_name,
                       help="keypoint detector: sift (OpenCV, default), geokey (learned, image + depth cues) or "
                            "geokey=WEIGHTS (from `geofeat train-detector`)")

    parser = argparse.ArgumentParser(prog="geofeat", description="Geodesic-aware local features on RGB-D images.")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="run the demo on the shipped real Kinect frame")
    demo.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    demo.add_argument("--radius", type=float, default=DEFAULT_RADIUS_M, help="geodesic radius, metres (default 0.075)")
    demo.add_argument("--angle", type=float, default=60.0, help="camera roll of the rotated pair, degrees (default 60)")
    demo.add_argument("--keypoints", type=int, default=1000, help="SIFT keypoints per frame (default 1000)")
    depth_profile_option(demo, "auto")
    demo.set_defaults(func=_demo)

    def frames_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("folder", help="a sequence folder in the public layout (<name>-rgb.png, <name>-depth.png, intrinsics.xml)")
        p.add_argument("--descriptor", default="geobit", type=descriptor_name,
                       help=f"one of {', '.join(available_descriptors())}, or geopatch=WEIGHTS.pt (default geobit)")
        p.add_argument("--keypoints", type=int, default=N_KEYPOINTS, help="keypoints per frame (default 2048)")
        detector_option(p)
        p.add_argument("--keypoint-set", choices=KEYPOINT_SETS, default="unique",
                       help="unique: one keypoint per position (default); protocol: SIFT's strongest as OpenCV returns them")
        depth_profile_option(p, None)
        p.add_argument("--radius", type=float, default=None, help="geodesic radius, metres (default 0.075)")
        p.add_argument("--depth-scale", type=float, default=None,
                       help=f"metres per depth-PNG unit (default: geofeat.json or {DEPTH_SCALE_M})")

    extract = sub.add_parser("extract", help="detect SIFT keypoints and describe every frame of a sequence")
    frames_options(extract)
    extract.add_argument("--out", required=True, help="features file (.h5 or .npz) or folder")
    extract.add_argument("--overwrite", action="store_true", help="replace an existing features file")
    extract.set_defaults(func=_extract)

    match = sub.add_parser("match", help="match the reference frame of a sequence to every other frame")
    frames_options(match)
    match.add_argument("--out", required=True, help="output folder (matches .h5 + pictures)")
    match.add_argument("--overwrite", action="store_true",
                       help="replace what geofeat wrote in an existing non-empty OUT (other files stay)")
    match.set_defaults(func=_match)

    bench = sub.add_parser("bench", help="matching score of descriptors on datasets in the public layout")
    bench.add_argument("datasets", nargs="+", help="sequence folders, or folders of sequences")
    bench.add_argument("--descriptors", default="geobit,geopatch,orb,sift",
                       help=f"comma-separated, from {','.join(available_descriptors())} (default geobit,geopatch,orb,sift)")
    bench.add_argument("--protocol", choices=("detect", "landmarks"), default="detect")
    bench.add_argument("--out", required=True, help="output folder: results.csv, table.md, plots, timing.md")
    bench.add_argument("--radius", type=float, default=None, help="geodesic radius, metres (default: geofeat.json or 0.075)")
    bench.add_argument("--depth-scale", type=float, default=None, help="metres per depth-PNG unit (default: geofeat.json or 0.001)")
    bench.add_argument("--keypoints", type=int, default=N_KEYPOINTS, help="keypoints per frame (default 2048)")
    detector_option(bench)
    bench.add_argument("--features", action="append", metavar="NAME=PATH",
                       help="also score features computed elsewhere: an hloc-style .h5 (groups <sequence>/<frame>) "
                            "or a folder of <frame>.npz with keypoints, descriptors and optional scores (repeatable)")
    bench.add_argument("--tps-dir", default=None, help="the authors' published TPS ground truth, one folder per sequence")
    bench.add_argument("--workers", type=int, default=1, help="local worker processes (sequences in parallel)")
    bench.add_argument("--scheduler", default=None, help="Dask scheduler address (e.g. tcp://host:8786); needs geofeat[dask]")
    bench.add_argument("--timing", action="store_true", help="also time f(.), extraction and matching for 250 and 2048 keypoints")
    bench.add_argument("--keypoint-set", choices=KEYPOINT_SETS, default="protocol",
                       help="protocol: OpenCV SIFT's strongest exactly as returned, duplicates kept (default, the "
                            "published protocol); unique: one keypoint per position")
    depth_profile_option(bench, None)
    bench.add_argument("--overwrite", action="store_true", help="redo every result (default: a rerun skips finished ones)")
    bench.set_defaults(func=_bench)

    tr = sub.add_parser("train", help="train GeoPatch on simulated sequences (see `geofeat simulate`)")
    tr.add_argument("--data", nargs="+", required=True, help="simulated sequence folders, or folders of them")
    tr.add_argument("--val", nargs="*", default=None, help="held-out simulated sequences for the per-epoch matching score")
    tr.add_argument("--out", required=True, help="weights file to write (e.g. geopatch.pt)")
    tr.add_argument("--epochs", type=int, default=10)
    tr.add_argument("--steps", type=int, default=200, help="batches per epoch (default 200)")
    tr.add_argument("--batch-size", type=int, default=1000, help="triplets per batch (default 1000, the paper's)")
    tr.add_argument("--lr", type=float, default=0.1, help="SGD learning rate (default 0.1, the paper's)")
    tr.add_argument("--mining", choices=("random", "hardest"), default="random",
                    help="negatives: random with anchor swap (the paper) or the hardest in the batch")
    tr.add_argument("--augment-shift", action="store_true", help="random circular shifts along the angle axis")
    tr.add_argument("--augment-photometric", action="store_true", help="random per-patch gamma and noise")
    tr.add_argument("--init", default=None, help="start from these GeoPatch weights ('shipped': geofeat's own)")
    tr.add_argument("--channels", type=int, nargs=3, default=(16, 32, 64), metavar=("C1", "C2", "C3"),
                    help="channels of the three convolutions (default 16 32 64; the paper's: 32 64 128)")
    tr.add_argument("--no-angle-pool", action="store_true", help="flatten instead of max-pooling over angle (ablation)")
    tr.add_argument("--keypoints", type=int, default=512, help="SIFT keypoints per reference frame (default 512)")
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--net", choices=("geopatch", "tfeat", "logpolar"), default="geopatch",
                    help="network: GeoPatch (geodesic patches) or an image-patch baseline (tfeat-sim, logpolar-sim)")
    tr.add_argument("--resume", action="store_true", help="continue from OUT.ckpt")
    tr.add_argument("--device", default=None, help="cpu or cuda (default: cuda when available)")
    depth_profile_option(tr, "auto")
    tr.set_defaults(func=_train)

    td = sub.add_parser("train-detector", help="train GeoKey, the learned keypoint detector, on simulated sequences")
    td.add_argument("--data", nargs="+", required=True, help="simulated sequence folders, or folders of them")
    td.add_argument("--val", nargs="+", required=True, help="held-out simulated sequences (choose the NMS radius)")
    td.add_argument("--out", required=True, help="weights file to write (e.g. geokey.pt; an .npz archive)")
    td.add_argument("--keypoints", type=int, default=1024, help="keypoints per frame for validation (default 1024)")
    td.add_argument("--hidden", type=int, nargs="+", default=(32, 32), help="hidden layer widths (default 32 32)")
    td.add_argument("--steps", type=int, default=3000, help="Adam steps (default 3000)")
    td.add_argument("--seed", type=int, default=0)
    td.add_argument("--labels", choices=("repeatable", "matchable"), default="repeatable",
                    help="training labels: found again within 1 px (default), or also matched by GeoPatch (slower)")
    td.set_defaults(func=_train_detector)

    def app_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("--descriptors", default="geopatch,geobit,sift",
                       help=f"comma-separated, from {','.join(available_descriptors())} (default geopatch,geobit,sift)")
        p.add_argument("--out", required=True, help="output folder")
        p.add_argument("--overwrite", action="store_true",
                       help="replace what geofeat wrote in an existing non-empty OUT (other files stay)")
        p.add_argument("--keypoints", type=int, default=N_KEYPOINTS, help="keypoints per frame (default 2048)")
        detector_option(p)
        p.add_argument("--tps-dir", default=None, help="the authors' TPS ground truth (objmask, warps), one folder per sequence")
        p.add_argument("--radius", type=float, default=None, help="geodesic radius, metres (default: geofeat.json or 0.075)")
        p.add_argument("--depth-scale", type=float, default=None, help="metres per depth-PNG unit (default: geofeat.json or 0.001)")

    ret = sub.add_parser("retrieval", help="object retrieval with a bag of visual words (Acc@K)")
    ret.add_argument("datasets", nargs="+", help="sequence folders, or folders of sequences")
    app_options(ret)
    ret.add_argument("--words", type=int, default=None,
                     help="visual words K (default: chosen per descriptor among 5,10,20,40,80 by validation on a "
                          "random half of the queries; Acc@K is then reported on the other half)")
    ret.add_argument("--include-own-sequence", action="store_true",
                     help="the database also holds the query's own sequence (default: only the other sequences, "
                          "the paper's setting)")
    ret.add_argument("--samples", type=int, default=10000, help="descriptors sampled for the vocabulary (default 10000)")
    ret.add_argument("--classes", default=None, help="CSV 'sequence,class' (default: class = sequence folder name)")
    ret.add_argument("--seed", type=int, default=0)
    ret.set_defaults(func=_retrieval)

    trk = sub.add_parser("track", help="track a template ROI through sequences (TPS + RANSAC)")
    trk.add_argument("sequences", nargs="+", help="sequence folders, or folders of sequences")
    app_options(trk)
    trk.add_argument("--roi", default=None, help="x0,y0,x1,y1 in reference pixels (default: object mask box shrunk by 10%%)")
    trk.add_argument("--threshold", type=float, default=3.0, help="RANSAC inlier threshold, pixels (default 3)")
    trk.add_argument("--refine", choices=("none", "photometric"), default="photometric",
                     help="after RANSAC + TPS, refine the warp densely against the template: photometric (the "
                          "refiner of 'geofeat groundtruth') or none (default photometric)")
    trk.add_argument("--lpips", action="store_true", help="LPIPS (needs local pretrained weights; not supported here)")
    trk.set_defaults(func=_track)

    from ..sim import command as sim_command

    sim_command.add_parser(sub).set_defaults(func=sim_command.run)

    from ..groundtruth import command as gt_command

    gt_command.add_parser(sub).set_defaults(func=gt_command.run)
    return parser


def is_interrupt(error: BaseException) -> bool:
    """True for Ctrl-C, also when a compiled (numba) kernel surfaces it as a SystemError."""
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        if isinstance(error, SystemError) and "KeyboardInterrupt" in str(error):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


#: Exit status of a run stopped by Ctrl-C (128 + SIGINT, as shells report it).
EXIT_INTERRUPTED = 130


def main(argv: list[str] | None = None) -> int:
    """Run the command line: 0 success, 1 something was skipped or failed (named in the output),
    2 bad input (one-line error), 130 interrupted (finished results are kept)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"geofeat {args.command}: interrupted; finished results are kept", file=sys.stderr)
        return EXIT_INTERRUPTED
    except SystemError as error:
        if not is_interrupt(error):
            raise
        print(f"geofeat {args.command}: interrupted; finished results are kept", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (ValueError, OSError) as error:  # user errors; programming errors keep their traceback
        text = " ".join(str(error).split()) or type(error).__name__
        print(f"geofeat {args.command}: error: {text}", file=sys.stderr)
        return 2
