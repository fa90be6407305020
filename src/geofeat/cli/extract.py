"""`geofeat extract`: detect keypoints and describe every frame of a sequence."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .common import (check_device, describe, descriptor_for_device, features_path, file_label, finish_skipped,
                     frame_and_keypoints, is_h5, skip_frame)
from .options import device_option, frames_options, resolve_detection


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `extract` to an argparse subparsers object; returns its parser."""
    p = subparsers.add_parser("extract", help="detect keypoints and describe every frame of a sequence")
    frames_options(p)
    p.add_argument("--out", required=True, help="features file (.h5 or .npz) or folder")
    p.add_argument("--overwrite", action="store_true", help="replace an existing features file")
    device_option(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Describe every frame of a sequence and write the features file(s); 1 when a frame was skipped."""
    detection = resolve_detection(args)  # resolved once, for every frame
    gpu = check_device(args.device, args.descriptor)
    import os

    from tqdm import tqdm

    from ..depth import PROFILES, sequence_depth_profile
    from ..features import features_source_record, save_features
    from ..inputs import resolve_radius
    from ..io import read_sequence
    from ..outputs import (atomic_file, check_out_file, claim_output, clear_stale_partials, partial_name, plural,
                           record_written, refuse_input_folder, signals_deferred)

    seq = read_sequence(args.folder, depth_scale=args.depth_scale)
    radius = resolve_radius(args.radius, seq)
    path = features_path(Path(args.out), file_label(args.descriptor))
    finals = [path] if is_h5(path) else [path.with_name(f"{path.stem}-{n}.npz") for n in seq.names]
    # --out naming the sequence folder, or a file or folder inside it: the features among its frames
    refuse_input_folder(args.out, [seq.folder], "--out",
                        f"extract would write {path.name if is_h5(path) else f'{path.stem}-<frame>.npz'} among "
                        "its files")
    refuse_result_file(finals)
    claim_output(path)  # one claim for the .h5, or for the prefix of the one file per frame
    source = earlier = None  # the .h5 is written whole, so it never mixes two runs' features
    if not is_h5(path):  # before "exists; pass --overwrite", which does not say whose features are there
        source = sequence_source(seq)
        earlier = check_same_source(path, source, args.overwrite)
    for final in finals:
        check_out_file(final, args.overwrite, claim=False)
    if not is_h5(path):  # a killed run's half-written .npz files (the .h5's `atomic_file` clears its own)
        clear_stale_partials(*finals)
    profile = sequence_depth_profile(seq, args.depth_profile)
    descriptor = descriptor_for_device(args, gpu, radius=radius, depth_config=PROFILES[profile])
    print(f"{seq.name}: depth profile {profile}, {detection}, "
          f"radius {radius:g} m")
    skipped: list[str] = []
    written: list[tuple[Path, Path]] = []  # (temporary, final) of the .npz files
    counts: list[int] = []  # keypoints of each frame written
    with atomic_file(path) as h5_tmp:
        try:
            for name in tqdm(seq.names, desc=f"extract {args.descriptor}", unit="frame"):
                try:
                    frame, kps = frame_and_keypoints(seq, name, args)
                    features = describe(descriptor, frame, kps, gpu)
                except ValueError as error:
                    skip_frame(skipped, name, error)
                    continue
                counts.append(len(features))
                if is_h5(path):
                    save_features(h5_tmp, features, name=name)
                else:
                    final = path.with_name(f"{path.stem}-{name}.npz")
                    tmp = partial_name(final)
                    save_features(tmp, features)
                    written.append((tmp, final))
            status = finish_skipped(skipped, len(seq), "extract")
            # as the .h5 (replaced whole) has no group for it: a skipped frame's file from an earlier run,
            # which --overwrite let replace, would mix that run's features with this one's; so would, with
            # --overwrite, the earlier run's files for frames this run does not write (another sequence's)
            new = {final.name for _, final in written}
            stale = [] if is_h5(path) else [f for f in (path.with_name(f"{path.stem}-{n}.npz") for n in skipped)
                                            if f.exists() or f.is_symlink()]
            if args.overwrite:
                stale += [f for f in earlier_files(path, earlier) if f.name not in new and f not in stale]
            # geofeat's files, so that a folder command names them as extract's (not "geofeat did not write")
            record_written([path] if is_h5(path) else [*(final for _, final in written),
                                                       features_source_record(path)], "extract")
            with signals_deferred():  # all the frames' files, or none: never this run's beside an earlier one's
                for tmp, final in written:
                    os.replace(tmp, final)
                written.clear()
                for final in stale:
                    final.unlink()
                if source is not None:  # the files of this prefix, and the sequence they are features of
                    write_source(path, source, new, [] if args.overwrite else earlier_files(path, earlier))
            if stale:
                print(f"removed {', '.join(str(f) for f in stale)}: features of an earlier run for frames not "
                      "written in this one", file=sys.stderr)
        finally:
            for tmp, _ in written:
                tmp.unlink(missing_ok=True)
    where = path if is_h5(path) else path.with_name(f"{path.stem}-<frame>.npz")
    per_frame = "" if not counts else (f" ({min(counts)}" + (f"-{max(counts)}" if max(counts) != min(counts) else "")
                                       + f" keypoints per frame of --keypoints {args.keypoints})")
    print(f"wrote {args.descriptor} features of {plural(len(seq) - len(skipped), 'frame')} of {seq.folder}{per_frame} to {where}")
    return status


def refuse_result_file(finals: list[Path]) -> None:
    """ValueError when one of the files `finals` that extract would write is listed in the manifest of
    its folder (`geofeat.outputs.read_manifest`): a file of another command's result folder, such as
    the features-<descriptor>.h5 that `geofeat match` writes beside the matches indexing its keypoints
    (extract records its own files apart, `geofeat.outputs.written_by`, which this does not read).
    Checked before "exists; pass --overwrite", which replaced it, and the matches then pointed into
    another run's keypoints without a word."""
    from ..outputs import MANIFEST, read_manifest

    for final in finals:
        if final.name in read_manifest(final.parent):
            raise ValueError(f"--out: {final} belongs to the results in {final.parent} (its {MANIFEST} lists it: another "
                             "geofeat command wrote it, as `geofeat match` writes the features its matches index); "
                             "replacing it would mix two runs' results, with or without --overwrite: choose another --out")


def sequence_source(seq) -> dict[str, str]:
    """What identifies the sequence `seq` (an `io.Sequence`) in a source record: its folder (absolute)
    and its reference frame's name and `io.frame_digest` (a cheap fingerprint of its content)."""
    from ..io import frame_digest

    return {"sequence": str(Path(seq.folder).resolve()), "reference": seq.reference,
            "reference_digest": frame_digest(seq.folder, seq.reference)}


def check_same_source(path: Path, source: dict[str, str], overwrite: bool) -> dict | None:
    """Refuse, before any work, to add the features of the sequence `source` (`sequence_source`) to the
    files `<stem>-<frame>.npz` of the .npz `path` that an earlier run wrote of another sequence (told by
    its reference frame's content, as `bench --features` tells it: a sequence moved or renamed since is
    the same one; the same folder whose reference frame changed is not), naming both: the prefix would hold
    two sequences' features, and `bench --features` read either for the frames of one. With
    `overwrite` the earlier files are replaced whole instead (removed when this run's are in place).
    Returns the earlier record (`geofeat.features.read_features_source`), None when there is none."""
    from ..features import features_source_record, read_features_source

    earlier = read_features_source(path)
    if earlier is None or overwrite or not earlier_files(path, earlier):
        return earlier
    if earlier.get("reference_digest") == source["reference_digest"]:
        return earlier
    if earlier.get("sequence") != source["sequence"]:
        why = f"of {earlier.get('sequence')}, not of {source['sequence']}"
    else:
        why = (f"of {source['sequence']} as it was when they were written: its reference frame "
               f"{source['reference']} has changed since")
    raise ValueError(f"--out: {path.parent} holds {path.stem}-<frame>.npz features {why} ({features_source_record(path).name}); "
                     "this run's would mix with them under one name: pass --overwrite to replace them all, or choose "
                     "another --out")


def earlier_files(path: Path, earlier: dict | None) -> list[Path]:
    """The files of the earlier record `earlier` (`geofeat.features.read_features_source`) of the .npz `path` that still exist:
    only `<stem>-<frame>.npz` names beside `path`, whatever the record says."""
    if earlier is None:
        return []
    names = [n for n in earlier["files"] if isinstance(n, str) and n.startswith(f"{path.stem}-") and n.endswith(".npz")
             and Path(n).name == n]
    return [path.with_name(n) for n in sorted(set(names)) if path.with_name(n).is_file()]


def write_source(path: Path, source: dict[str, str], written: set[str], kept: list[Path]) -> None:
    """Write the source record of the .npz `path` (`geofeat.features.features_source_record`): the sequence `source` and the
    file names `written` by this run and `kept` from an earlier run of the same sequence."""
    from ..features import features_source_record
    from ..outputs import atomic_file, json_text

    files = sorted(written | {f.name for f in kept})
    with atomic_file(features_source_record(path)) as tmp:
        tmp.write_text(json_text({"generator": "geofeat extract", **source, "files": files}, indent=1), encoding="utf-8")
