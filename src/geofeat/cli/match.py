"""`geofeat match`: match the reference frame of a sequence to every other frame."""

from __future__ import annotations

import argparse
import warnings

from .common import (check_device, describe, descriptor_for_device, file_label, finish_skipped, frame_and_keypoints,
                     skip_frame)
from .options import device_option, frames_options, resolve_detection


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `match` to an argparse subparsers object; returns its parser."""
    p = subparsers.add_parser("match", help="match the reference frame of a sequence to every other frame")
    frames_options(p)
    p.add_argument("--out", required=True,
                   help="output folder (matches .h5, the features .h5 whose keypoints they index, pictures)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace what geofeat wrote in an existing non-empty OUT (other files stay)")
    device_option(p, ", and the matching,")
    p.set_defaults(func=run)
    return p


def picture_name(reference: str, target: str, label: str) -> str:
    """The file name of the picture of the matches of `reference` to `target` (`label`: `file_label`)."""
    return f"{reference}__{target}__{label}.png"


def run(args: argparse.Namespace) -> int:
    """Match the reference frame to every other frame, judged by the ground truth when there is one."""
    detection = resolve_detection(args)  # resolved once, for every frame
    gpu = check_device(args.device, args.descriptor)
    from tqdm import tqdm

    from ..groundtruth.sources import GroundTruth, correct_matches, judged_matches
    from ..depth import PROFILES, sequence_depth_profile
    from ..features import save_features, save_matches
    from ..inputs import resolve_radius
    from ..io import read_sequence
    from ..matching import match
    from ..outputs import check_out_dir, output_folder, plural, write_picture
    from ..viz import draw_matches

    seq = read_sequence(args.folder, depth_scale=args.depth_scale)
    if len(seq) < 2:
        raise ValueError(f"folder: {seq.folder} has a single frame; matching needs a reference and a target")
    label = file_label(args.descriptor)
    # every file at a fixed name: a user's file there (an `extract` features .h5) was found only when the
    # results were moved into place, after every pair was matched
    files = [f"matches-{label}.h5", f"features-{label}.h5", *(picture_name(seq.reference, n, label) for n in seq.targets)]
    out = check_out_dir(args.out, args.overwrite, files=files, inputs=[seq.folder])
    radius = resolve_radius(args.radius, seq)
    profile = sequence_depth_profile(seq, args.depth_profile)
    descriptor = descriptor_for_device(args, gpu, radius=radius, depth_config=PROFILES[profile])
    device = args.device if gpu else None  # the matching's (`geofeat.match`), beside the description's
    try:
        truth = GroundTruth(seq, None)
    except ValueError as error:
        if "no ground truth" not in str(error):
            raise
        truth = None  # no ground truth: matches are written, not judged
        if "csv landmarks in" in str(error):  # the user's landmarks, left unused: say why
            warnings.warn(f"{error}; matches are written without being judged")
    print(f"{seq.name}: depth profile {profile}, {detection}, "
          f"radius {radius:g} m, ground truth: "
          + ("none" if truth is None else "simulator (exact)" if truth.exact else "thin-plate spline on the landmarks"))
    if truth is not None and not truth.exact:
        for name in seq.names:  # the landmark validator, before any work
            seq.landmarks(name)
    try:
        ref, k_ref = frame_and_keypoints(seq, seq.reference, args)
    except ValueError as error:
        raise ValueError(f"frame {seq.reference}: the reference frame cannot be used ({error}); nothing to match") from None
    f_ref = describe(descriptor, ref, k_ref, gpu)
    total_matches, total_correct, total_unjudged = 0, 0, 0
    skipped: list[str] = []
    with output_folder(out) as tmp:
        matches_path = tmp / f"matches-{label}.h5"
        # the keypoints the matches index, hloc's way (features.h5 beside matches.h5): without them
        # matches0 pointed into keypoints no file held
        features_path = tmp / f"features-{label}.h5"
        save_features(features_path, f_ref, name=seq.reference)
        for name in tqdm(seq.targets, desc=f"match {args.descriptor}", unit="pair"):
            try:
                tgt, k_tgt = frame_and_keypoints(seq, name, args)
                f_tgt = describe(descriptor, tgt, k_tgt, gpu)
                m = match(f_ref, f_tgt, device=device)
            except ValueError as error:
                skip_frame(skipped, name, error)
                continue
            save_features(features_path, f_tgt, name=name)
            save_matches(matches_path, m, name=f"{seq.reference}/{name}")
            n_matches = int((m.matches0 >= 0).sum())
            total_matches += n_matches
            summary = plural(n_matches, "match", "matches")
            correct = judged = None
            # a target the landmarks' spline cannot map (fewer than 4 landmarks seen in both frames):
            # `map` raised, and the whole run ended with an error naming no frame, nothing written
            reason = truth.uncovered_reason(name) if truth is not None else None
            if reason is not None:
                total_unjudged += n_matches
                summary += f", not judged (no ground truth for {name}: {reason})"
            elif truth is not None:
                correct = correct_matches(truth, name, k_ref.xy, k_tgt.xy, m.matches0)
                judged = judged_matches(truth, name, k_tgt.xy, m.matches0)  # the others are not wrong, but unknown
                total_correct += int(correct.sum())
                unjudged = n_matches - int(judged.sum())  # drawn blue: neither counted correct nor wrong
                total_unjudged += unjudged
                summary += f", {int(correct.sum())} correct" + (f", {unjudged} not judged (no ground truth)" if unjudged else "")
            picture = draw_matches(ref, tgt, k_ref.xy, k_tgt.xy, m.matches0, correct, title=f"{args.descriptor}: {summary}",
                                   judged=judged)
            write_picture(tmp / picture_name(seq.reference, name, label), picture)
            tqdm.write(f"{seq.reference} -> {name}: {summary}")
        status = finish_skipped(skipped, len(seq.targets), "match")
    judged_total = (f", {total_correct} correct" + (f", {total_unjudged} not judged (no ground truth)" if total_unjudged else "")
                    if truth is not None else " (no ground truth)")
    print(f"total: {plural(total_matches, 'match', 'matches')}{judged_total}")
    print(f"wrote {out / f'matches-{label}.h5'}, the features they index ({out / f'features-{label}.h5'}) "
          f"and one match picture per pair in {out}")
    return status
