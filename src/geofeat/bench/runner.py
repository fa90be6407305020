"""`geofeat bench`: matching score of several descriptors on datasets in the public layout.

Work unit = one sequence (independent of the others): a local process pool (`workers`) or a Dask
cluster (`scheduler` address) runs them; every finished sequence appends its rows to
`results.csv` at once, so an interrupted run keeps what it finished, and a failed sequence is
reported by name while the others go on. A rerun into the same folder skips the (sequence,
descriptor) results already there, unless `overwrite`.

Keypoints (`keypoint_set`): "protocol" (default) = OpenCV SIFT's n strongest exactly as OpenCV
returns them, as the published protocol; "unique" = one keypoint per position, on depth. Each
sequence is described with one depth profile: the one asked for (`depth_profile`), else its
geofeat.json's, else the one `geofeat.depth_profile` picks on its reference frame; results.csv
records the keypoint set and the profile used.

`device` "cuda" / "cuda:N" describes and matches GeoPatch on the GPU path, the other descriptors on
the CPU (`geofeat.descriptors.describer.Describer`); results.csv records each row's device, and a
rerun on another device is refused, so that one results.csv never mixes the two devices' timings.
"""

from __future__ import annotations

import csv
import io
import json
import multiprocessing
import os
import time
import traceback
import warnings
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..constants import N_KEYPOINTS
from ..depth import check_profile, sequence_depth_profile
from ..descriptors import OpenCVDescriptor, check_descriptor_name, make_descriptor, refuse_repeated
from ..inputs import check_depth_scale, check_radius, check_threads, check_tps_dir, check_whole, resolve_radius
from ..io import Sequence, files_digest, find_sequences, frame_names, path_list, read_sequence, sequence_digest
from ..outputs import (add_to_manifest, append_line_durably, atomic_file, check_out_dir, plural, read_manifest,
                       refuse_input_folder, write_manifest)
from ..keypoints import Keypoints, check_detector_name, detect, resolve_keypoint_set
from ..matching import match
from ..features import Features
from ..gpu import gpu_descriptors, wants_gpu
from .external import ExternalFeatures, check_extract_sources, check_one_source_per_frame, parse_features_option
from .report import CURVES
from ..descriptors.describer import Describer
from ..groundtruth.simulator import GT_JSON
from ..groundtruth.sources import GroundTruth, refuse_partial_simulator_truth
from ..scoring import ground_truth_pairs, score_detect, score_landmarks

COLUMNS = ["sequence", "reference", "target", "descriptor", "detector", "protocol", "keypoint_set", "depth_profile",
           "device", "ms", "mma", "repeatability", "hits", "n_gt", "n_ref", "n_tgt", "seconds_extract", "seconds_match",
           "angle_deg", "scale"]
#: The files `geofeat bench` writes into its output folder (results.csv and config.json here, the
#: reports in `geofeat.cli.bench` and `geofeat.bench.report.plot_curves`).
REPORTS = ("table.md", "details.md", "timing.md") + tuple(f"ms_vs_{kind}.png" for _, kind, _, _ in CURVES)
OUTPUT_FILES = ("results.csv", "config.json") + REPORTS
#: Settings that must be equal for a rerun to reuse the results already in the output folder.
REUSE_KEYS = ("protocol", "detector", "features", "keypoint_set", "depth_profile", "radius", "depth_scale", "n_keypoints", "tps_dir",
              "device")


@dataclass
class BenchConfig:
    """What to run. radius in metres; depth_scale in metres per depth-PNG unit (None: the dataset's
    geofeat.json or 0.001)."""

    descriptors: tuple[str, ...] = ("geobit", "orb", "sift")
    protocol: str = "detect"
    radius: float | None = None
    depth_scale: float | None = None
    n_keypoints: int = N_KEYPOINTS
    tps_dir: str | None = None
    #: None: "protocol" with SIFT; GeoKey's keypoints are one per position, "unique" (the only set it takes)
    keypoint_set: str | None = None
    depth_profile: str | None = None
    detector: str = "sift"
    #: "NAME=PATH" feature sets computed elsewhere (`geofeat.bench.external`), scored beside the descriptors
    features: tuple[str, ...] = ()
    #: None (or "cpu"): every descriptor on the CPU; "cuda" / "cuda:N": GeoPatch described and matched on
    #: that GPU, the other descriptors on the CPU (`geofeat.gpu.gpu_descriptors`, which refuses a device
    #: that no descriptor would use)
    device: str | None = None

    def __post_init__(self) -> None:
        self.detector = check_detector_name(self.detector)
        self.features = tuple(str(f) for f in self.features)
        external = [parse_features_option(f)[0] for f in self.features]
        if len(set(external)) != len(external):
            raise ValueError(f"features: names must differ, got {external}")
        if self.features and self.protocol != "detect":
            raise ValueError("features: external features are scored with protocol 'detect' only")
        if self.protocol not in ("detect", "landmarks"):
            raise ValueError(f"protocol: expected 'detect' or 'landmarks', got {self.protocol!r}")
        self.keypoint_set = resolve_keypoint_set(self.detector, self.keypoint_set, "protocol")
        # checked here, not in each sequence (where every one would fail alike, after config.json is written)
        if self.radius is not None:
            self.radius = check_radius(self.radius, "radius")
        if self.depth_scale is not None:
            self.depth_scale = check_depth_scale(self.depth_scale, "depth_scale")
        self.n_keypoints = check_whole(self.n_keypoints, "n_keypoints")
        if self.depth_profile is not None:
            self.depth_profile = check_profile(self.depth_profile)
        if not self.descriptors and not self.features:
            raise ValueError("descriptors: at least one descriptor (or --features) is needed")
        # validates the names (and that weights files exist) without building anything
        self.descriptors = tuple(check_descriptor_name(d) for d in self.descriptors)
        refuse_repeated(self.descriptors)  # each would write its rows again into results.csv
        clash = set(external) & set(self.descriptors)
        if clash:
            raise ValueError(f"features: {sorted(clash)} is also a descriptor name; rename the feature set")
        gpu_descriptors(self.descriptors, self.device)
        self.device = str(self.device) if wants_gpu(self.device) else None  # "cpu" is the default's run

    @property
    def methods(self) -> tuple[str, ...]:
        """Every result name: the descriptors, then the external feature sets."""
        return self.descriptors + tuple(parse_features_option(f)[0] for f in self.features)


def _pose_change(seq: Sequence, target: str) -> tuple[float, float]:
    """Camera roll (degrees) and scale (reference depth / target depth) of a simulated pair; NaN if unknown."""
    try:
        with np.load(seq.folder / f"{seq.reference}-gt.npz") as a, np.load(seq.folder / f"{target}-gt.npz") as b:
            R = b["R"] @ a["R"].T
            angle = abs(float(np.degrees(np.arctan2(R[1, 0], R[0, 0]))))
            scale = float(np.median(a["vertices"][..., 2]) / np.median(b["vertices"][..., 2]))
        return angle, scale
    except (OSError, KeyError):
        return float("nan"), float("nan")


def _pixel_grid(shape: tuple[int, int], step: int = 4) -> np.ndarray:
    """(N, 2) pixels every `step` px over an image of `shape` (H, W)."""
    ys, xs = np.mgrid[0:shape[0]:step, 0:shape[1]:step]
    return np.stack([xs.ravel(), ys.ravel()], axis=1).astype(float)


def _covers_no_pixel(truth: GroundTruth, target: str, known: np.ndarray, shape: tuple[int, int]) -> bool:
    """True when the ground truth maps no pixel of `target` (no object there): its pair cannot be
    scored (MS would be 0 / 0), so it is skipped rather than counted as 0. `known`: which of the
    target's keypoints have a ground truth (the grid is tried only when none has)."""
    return not known.any() and not truth.map(target, _pixel_grid(shape))[1].any()


def _empty_row_score(n_ref: int, n_tgt: int):
    from ..scoring import PairScore

    return PairScore(ms=0.0, mma=0.0, hits=0, n_ref=n_ref, n_tgt=n_tgt, n_gt=0)


#: Keypoints `_warm_up` describes before anything is timed.
WARM_UP_KEYPOINTS = 8


def _warm_up(describe: Describer, frame, kps: Keypoints) -> None:
    """Describe the first `WARM_UP_KEYPOINTS` of `kps` on `frame` with every descriptor, untimed, so
    that one-time costs of describing (numba's compilation or cache loading, a network's first run)
    fall outside `seconds_extract`. The reference's description time counts in every pair of its
    sequence, so without this the first sequence a process scores carried the compilation (a minute
    for GeoBit on a fresh install) in each of its pairs, not in the first one only. (Matching is not
    warmed: which Hamming kernel runs depends on the descriptors, so a few keypoints compile another
    one; its compilation stays in the seconds_match of the pair that first needs it.)"""
    describe(frame, kps[:WARM_UP_KEYPOINTS])


def evaluate_sequence(folder: str | Path, config: BenchConfig, descriptors: tuple[str, ...] | None = None) -> list[dict]:
    """All (reference, target) pairs of one sequence for each descriptor (default: the config's):
    result rows (see COLUMNS). The reference frame is described once."""
    requested = config.methods if descriptors is None else tuple(descriptors)
    names = tuple(n for n in requested if n in config.descriptors)
    external = [ExternalFeatures(*parse_features_option(f)) for f in config.features]
    external = [e for e in external if e.name in requested]
    seq = read_sequence(folder, depth_scale=config.depth_scale)
    if len(seq) < 2:
        raise ValueError(f"sequence {seq.name}: needs a reference and at least one target frame")
    ref = seq.frame(seq.reference)
    profile = sequence_depth_profile(seq, config.depth_profile, ref) if names else ""
    describe = Describer(names, resolve_radius(config.radius, seq), profile or "kinect", device=config.device)
    rows = []
    if config.protocol == "landmarks":
        # annotated positions have no orientation: every descriptor describes them at angle 0 by
        # design, so the OpenCV baselines are told so (and do not warn about unoriented keypoints)
        for descriptor in describe.descriptors.values():
            if isinstance(descriptor, OpenCVDescriptor):
                descriptor.use_angle = False
        ids_r, xy_r, vis_r = seq.landmarks(seq.reference)
        k_ref = Keypoints(xy_r[vis_r], np.zeros(vis_r.sum()), np.full(vis_r.sum(), 8.0), np.zeros(vis_r.sum()))
    else:
        truth = GroundTruth(seq, config.tps_dir)
        if truth.tps is None and not truth.exact:  # not the landmarks' spline in place of a damaged simulator truth
            refuse_partial_simulator_truth(seq)
        k_ref = detect(ref, config.n_keypoints, detector=config.detector, keypoint_set=config.keypoint_set)
        k_ref = k_ref[truth.reference_keep(k_ref.xy)]
        if not len(k_ref) and not truth.reference_keep(_pixel_grid(seq.shape)).any():
            raise ValueError(f"sequence {seq.name}: the ground truth covers no pixel of the reference frame "
                             f"{seq.reference} (no object there), so no pair can be scored")
        rows += [dict(r, depth_profile=profile) for e in external for r in evaluate_external(seq, truth, e, config)]
    if not names:
        return rows
    if len(k_ref):
        _warm_up(describe, ref, k_ref)
    f_ref = describe(ref, k_ref) if len(k_ref) else None
    for target in seq.targets:
        reason = truth.uncovered_reason(target) if config.protocol == "detect" else None
        if reason is not None:
            tqdm.write(f"{seq.name}: no ground truth for {target} ({reason}); pair skipped")
            continue
        if config.protocol == "landmarks":
            ids_t, xy_t, vis_t = seq.landmarks(target)
            if not np.isin(ids_t[vis_t], ids_r[vis_r]).any():  # no query: a score of 0 would mean nothing
                tqdm.write(f"{seq.name}: no landmark id visible in both {seq.reference} and {target}; pair skipped")
                continue
        frame = seq.frame(target)
        angle, scale = _pose_change(seq, target)
        if config.protocol == "landmarks":
            k_tgt = Keypoints(xy_t[vis_t], np.zeros(vis_t.sum()), np.full(vis_t.sum(), 8.0), np.zeros(vis_t.sum()))
        else:
            k_tgt = detect(frame, config.n_keypoints, detector=config.detector, keypoint_set=config.keypoint_set)
            mapped, known = truth.map(target, k_tgt.xy)
            if _covers_no_pixel(truth, target, known, seq.shape):
                tqdm.write(f"{seq.name}: the ground truth covers no pixel of {target}; pair skipped")
                continue
            k_tgt, mapped = k_tgt[known], mapped[known]
            gt = ground_truth_pairs(k_ref.xy, mapped)
        f_tgt = describe(frame, k_tgt) if len(k_tgt) and f_ref is not None else None
        for name in names:
            t_match, t_extract = 0.0, 0.0
            if f_tgt is None:  # nothing to match on one side: the pair scores 0
                s = _empty_row_score(len(k_ref), len(k_tgt))
            else:
                (fr, tr), (ft, tt) = f_ref[name], f_tgt[name]
                t = time.perf_counter()
                m = match(fr, ft, device=describe.match_device(name))
                t_match, t_extract = time.perf_counter() - t, tr + tt
                if config.protocol == "landmarks":
                    s = score_landmarks(m.matches0, ids_r[vis_r], ids_t[vis_t])
                else:
                    s = score_detect(m.matches0, gt, len(k_ref), len(k_tgt))
            rows.append(dict(sequence=seq.name, reference=seq.reference, target=target, descriptor=name,
                             detector=config.detector if config.protocol == "detect" else "landmarks",
                             protocol=config.protocol, keypoint_set=config.keypoint_set, depth_profile=profile,
                             device=describe.match_device(name) or "cpu",
                             ms=s.ms, mma=s.mma, repeatability=s.n_gt / max(min(s.n_ref, s.n_tgt), 1),
                             hits=s.hits, n_gt=s.n_gt, n_ref=s.n_ref, n_tgt=s.n_tgt,
                             seconds_extract=t_extract, seconds_match=t_match, angle_deg=angle, scale=scale))
    return rows


def evaluate_external(seq: Sequence, truth: GroundTruth, features: ExternalFeatures, config: BenchConfig) -> list[dict]:
    """Rows of one external feature set on every pair of `seq`: its own keypoints and descriptors,
    filtered and scored exactly as geofeat's (reference keypoints on the object, target keypoints
    with a reliable ground truth, one-way nearest neighbour, hits within 3 px)."""
    f_ref = features.load(seq.name, seq.reference, config.n_keypoints, seq.shape)
    keep = truth.reference_keep(f_ref.keypoints)
    f_ref = Features(f_ref.keypoints[keep], f_ref.descriptors[keep], f_ref.valid[keep])
    rows = []
    for target in seq.targets:
        reason = truth.uncovered_reason(target)
        if reason is not None:
            tqdm.write(f"{seq.name}: no ground truth for {target} ({reason}); pair skipped for {features.name}")
            continue
        f_tgt = features.load(seq.name, target, config.n_keypoints, seq.shape)
        d_tgt, d_ref = f_tgt.descriptors, f_ref.descriptors
        # another kind (float against uint8) failed in `match` naming neither the set nor the frame, or,
        # with a `metric` stored, was matched across the two kinds
        if d_tgt.shape[1:] != d_ref.shape[1:] or d_tgt.dtype.kind != d_ref.dtype.kind:
            raise ValueError(f"features {features.name}: {seq.name}/{target} has {d_tgt.dtype} descriptors of shape "
                             f"{d_tgt.shape[1:]}, {seq.reference} {d_ref.dtype} of {d_ref.shape[1:]}; every frame's "
                             "must be of one kind and size")
        mapped, known = truth.map(target, f_tgt.keypoints)
        if _covers_no_pixel(truth, target, known, seq.shape):
            tqdm.write(f"{seq.name}: the ground truth covers no pixel of {target}; pair skipped for {features.name}")
            continue
        f_tgt = Features(f_tgt.keypoints[known], f_tgt.descriptors[known], f_tgt.valid[known])
        gt = ground_truth_pairs(f_ref.keypoints, mapped[known])
        t = time.perf_counter()
        if len(f_ref) and len(f_tgt):
            s = score_detect(match(f_ref, f_tgt, metric=features.metric).matches0, gt, len(f_ref), len(f_tgt))
        else:
            s = _empty_row_score(len(f_ref), len(f_tgt))
        angle, scale = _pose_change(seq, target)
        rows.append(dict(sequence=seq.name, reference=seq.reference, target=target, descriptor=features.name,
                         detector="external", protocol="detect", keypoint_set="external", depth_profile="", device="cpu",
                         ms=s.ms, mma=s.mma, repeatability=s.n_gt / max(min(s.n_ref, s.n_tgt), 1), hits=s.hits,
                         n_gt=s.n_gt, n_ref=s.n_ref, n_tgt=s.n_tgt, seconds_extract=0.0,
                         seconds_match=time.perf_counter() - t, angle_deg=angle, scale=scale))
    return rows


def _run_one(folder: str, config: BenchConfig, descriptors: tuple[str, ...]) -> tuple[str, list[dict] | None, str | None]:
    try:
        return folder, evaluate_sequence(folder, config, descriptors), None
    except SystemError:  # an interpreter-level error, e.g. Ctrl-C inside a numba kernel: stop the run
        raise
    except Exception as error:  # reported by name; the other sequences go on
        return folder, None, f"{type(error).__name__}: {error}\n{traceback.format_exc(limit=3)}"


_FLOAT_COLUMNS = ("ms", "mma", "repeatability", "seconds_extract", "seconds_match", "angle_deg", "scale")
_INT_COLUMNS = ("hits", "n_gt", "n_ref", "n_tgt")


def _parses(row: list[str]) -> bool:
    """True for a complete results.csv row: every column, numbers where numbers belong."""
    if len(row) != len(COLUMNS) or not row[0]:
        return False
    values = dict(zip(COLUMNS, row))
    try:
        for key in _FLOAT_COLUMNS:
            float(values[key])
        for key in _INT_COLUMNS:
            int(values[key])
    except ValueError:
        return False
    return True


def _sequence_of(line: str) -> str:
    row = next(csv.reader([line]), [])
    return row[0] if row else ""


def repair_results(csv_path: Path) -> int:
    """Drop from results.csv what a kill during an append can leave: a last line without its newline
    and any unparsable row, together with the other rows of that sequence just before it (rows of
    one sequence are appended in one write, so a torn write cuts only the end of that block). The
    dropped results are recomputed by the rerun. Returns the number of lines dropped."""
    text = csv_path.read_text(encoding="utf-8")
    lines = text.splitlines(keepends=True)
    if not lines:
        return 0
    kept: list[str] = [lines[0]]
    dropped = 0
    for line in lines[1:]:
        row = next(csv.reader([line]), [])
        if line.endswith("\n") and _parses(row):
            kept.append(line)
            continue
        dropped += 1
        prefix = row[0] if row else ""  # the broken row's sequence, perhaps cut short
        block = _sequence_of(kept[-1]) if len(kept) > 1 else None
        if block is not None and block.startswith(prefix):
            while len(kept) > 1 and _sequence_of(kept[-1]) == block:
                kept.pop()
                dropped += 1
    if dropped:
        with atomic_file(csv_path) as tmp:
            tmp.write_text("".join(kept), encoding="utf-8")
    return dropped


def _finished(csv_path: Path) -> set[tuple[str, str]]:
    """(sequence, descriptor) pairs whose rows are in results.csv (a sequence's rows are appended at once)."""
    if not csv_path.is_file():
        return set()
    with open(csv_path, newline="", encoding="utf-8") as fh:
        return {(row["sequence"], row["descriptor"]) for row in csv.DictReader(fh)}


def _append_rows(csv_path: Path, rows: list[dict]) -> None:
    """Append a sequence's rows to results.csv in one durable write (see `repair_results`)."""
    buffer = io.StringIO()
    csv.DictWriter(buffer, COLUMNS, lineterminator="\n").writerows(rows)
    if buffer.getvalue():
        append_line_durably(csv_path, buffer.getvalue())


def _settings(config: BenchConfig) -> dict:
    """The settings a rerun must share, as config.json stores them (JSON turns tuples into lists)."""
    return json.loads(json.dumps({key: asdict(config)[key] for key in REUSE_KEYS}))


#: How `settings_differences` shows an unset setting (None in BenchConfig, null in config.json).
_UNSET = {"depth_profile": "the default (geofeat.json's, else auto)", "radius": "the default (geofeat.json's or 0.075)",
          "depth_scale": "the default (geofeat.json's or 0.001)", "tps_dir": "none", "keypoint_set": "the default",
          "device": "the CPU"}


def _shown(key: str, value) -> str:
    """A setting as a person reads it in the refusal message: a name bare (auto, not "auto"), an unset
    one in words (not null), a list comma-separated."""
    if value is None:
        return _UNSET.get(key, "unset")
    if isinstance(value, str):
        return value
    if isinstance(value, (list, tuple)):
        return ", ".join(map(str, value)) or "none"
    return json.dumps(value)


def _chosen_per_sequence(profile: str | None) -> bool:
    """True for a depth-profile setting that leaves the choice to each sequence: None (its
    geofeat.json's, else measured) or "auto" (measured; in a config.json written before the two
    differed, "auto" meant what None means now)."""
    return profile is None or profile == "auto"


def _profile_differences(there: str | None, now: str | None, csv_path: Path, folders: list[str],
                         config: BenchConfig) -> list[str]:
    """The depth-profile part of `settings_differences`. A named profile must be the same name. When
    both runs leave the choice to each sequence (None or "auto"), and they are not both None, the
    profile each finished sequence was described with (results.csv) is compared with the one this
    run would choose for it (`sequence_depth_profile`, measuring when it must): None and "auto"
    differ only for a sequence whose geofeat.json names a profile other than the measured one."""
    if there == now and there != "auto":
        return []
    said = f"depth_profile {_shown('depth_profile', there)} there, {_shown('depth_profile', now)} now"
    if not (_chosen_per_sequence(there) and _chosen_per_sequence(now)):
        return [said]
    with open(csv_path, newline="", encoding="utf-8") as fh:  # complete rows only: a torn last line is dropped on resuming
        rows = [dict(zip(COLUMNS, row)) for row in list(csv.reader(fh))[1:] if _parses(row)]
    recorded = {row["sequence"]: row["depth_profile"] for row in rows if row["depth_profile"]}
    for folder in folders:
        name = Path(folder).name
        if name not in recorded:
            continue
        try:
            chosen = sequence_depth_profile(read_sequence(folder, depth_scale=config.depth_scale), now)
        except ValueError:  # a sequence that cannot be read now fails by name in the run
            continue
        if chosen != recorded[name]:
            return [f"{said}: {name} was described with {recorded[name]}, now it would be with {chosen}"]
    return []


def settings_differences(before: dict, config: BenchConfig, csv_path: Path, folders: list[str]) -> list[str]:
    """What makes `config` another run than the one config.json's `before` describes, one phrase per
    setting ("n_keypoints 200 there, 100 now"); empty for the same run. The depth profile is
    compared by what it chooses (`_profile_differences`)."""
    there = {key: before.get(key) for key in REUSE_KEYS}
    now = _settings(config)
    differences = [f"{key} {_shown(key, there[key])} there, {_shown(key, now[key])} now"
                   for key in REUSE_KEYS if key != "depth_profile" and there[key] != now[key]]
    if differences:  # another run already: the profiles are compared by name, without reading a sequence
        if there["depth_profile"] != now["depth_profile"]:
            differences.append(f"depth_profile {_shown('depth_profile', there['depth_profile'])} there, "
                               f"{_shown('depth_profile', now['depth_profile'])} now")
        return differences
    return _profile_differences(there["depth_profile"], now["depth_profile"], csv_path, folders, config)


def run_benchmark(datasets, out: str | Path, config: BenchConfig, workers: int = 1,
                  scheduler: str | None = None, progress: bool = True,
                  overwrite: bool = False) -> tuple[Path, list[str]]:
    """Evaluate every sequence under `datasets`; write OUT/results.csv incrementally.

    A rerun into the same folder with the same settings evaluates only the (sequence, descriptor)
    results not yet in results.csv (a row cut short by a kill is dropped and recomputed, see
    `repair_results`); with other settings it raises ValueError unless `overwrite`, which starts the
    file anew and removes the earlier run's reports (`REPORTS`, those geofeat wrote). A non-empty
    `out` without results.csv needs `overwrite`; files geofeat did not write are never replaced. Sequence names must be unique (results are keyed by them). Ctrl-C stops the
    run (KeyboardInterrupt) and leaves the finished rows in place. Returns the csv path and the names of failed sequences (with
    reasons printed)."""
    # local processes: 100000 were spawned until the machine ran out of memory
    workers = check_threads(workers, "workers", unit="worker processes")
    if scheduler:  # before any folder is written: a missing optional package is bad input, not a traceback
        try:
            import dask.distributed  # noqa: F401
        except ImportError as error:
            raise ValueError(f"scheduler: a Dask scheduler needs dask[distributed] (pip install 'geofeat[dask]'): "
                             f"{error}") from None
    out = Path(out)
    csv_path = out / "results.csv"
    folders = [str(f) for f in find_sequences(datasets, unique_names=True)]
    # a sequence folder (or a folder inside one, or inside a folder of sequences) for `out`, resumed or
    # not: the results would be written among the user's files
    refuse_input_folder(out, [*path_list(datasets), *folders, config.tps_dir], "--out",
                        "bench would write its results among the input's files")
    if not csv_path.is_file():
        # a non-empty folder without results.csv is not a bench to resume; --overwrite replaces none of the user's files
        check_out_dir(out, overwrite, files=OUTPUT_FILES)
    elif out.exists() and not out.is_dir():
        raise ValueError(f"out: {out} is a file, not a folder")
    else:  # a rerun (resumed or --overwrite) writes its reports again: never over a file of the user's there;
        # --overwrite starts results.csv and config.json anew, a resumed run appends to results.csv and
        # rewrites config.json: never a copy the user put there (not in the manifest), which --overwrite
        # replaced when its header was bench's, and a resumed run appended to (and listed as geofeat's)
        check_out_dir(out, True, files=OUTPUT_FILES)
        if csv_path.is_symlink() and not overwrite:  # the rows would be appended to the file it points to
            raise ValueError(f"--out: {csv_path} is a symbolic link (to {os.readlink(csv_path)}); a resumed bench "
                             "appends only to a results.csv of its own: remove the link, or use --overwrite or "
                             "another --out")
    short = [Path(f).name for f in folders if len(frame_names(f)) < 2]
    if short and len(short) == len(folders):  # nothing to evaluate: say so before writing config.json and results.csv
        raise ValueError(f"datasets: no sequence has a reference and a target frame ({plural(len(short), 'sequence')} "
                         f"of one frame or none: {', '.join(short[:5])}{', ...' if len(short) > 5 else ''})")
    check_tps_dir(config.tps_dir)
    if config.device is not None and not scheduler:  # one error here, not one per sequence (a cluster's workers: theirs)
        from ..gpu import require_cuda

        require_cuda(config.device)
    for name in config.descriptors:  # weights that cannot be read: one error naming them, not one per sequence
        if "=" in name:
            make_descriptor(name)
    if config.features:  # before any work: a shared group would score a sequence with another's features
        external = [ExternalFeatures(*parse_features_option(f)) for f in config.features]
        check_one_source_per_frame(external, {Path(f).name: frame_names(f) for f in folders})
        check_extract_sources(external, folders)
    done = _open_results(out, config, overwrite, progress, folders)
    work = []
    for folder in folders:
        name = Path(folder).name
        todo = tuple(d for d in config.methods if (name, d) not in done)
        if todo:
            work.append((folder, todo))
    if work:  # rows are added: an earlier timing.md (`geofeat bench --timing`) would lack their descriptors
        _remove_timing(out, progress)
    skipped = len(folders) - len(work)
    if skipped and progress:
        tqdm.write(f"bench: {plural(skipped, 'sequence')} already in {csv_path}, skipped (--overwrite to redo)")
    failed = []
    bar = tqdm(total=len(work), desc="bench", unit="seq", disable=not progress)

    def record(folder: str, rows: list[dict] | None, error: str | None) -> None:
        if error is not None:
            failed.append(Path(folder).name)
            tqdm.write(f"FAILED {Path(folder).name}: {error.splitlines()[0]}")
        else:
            _append_rows(csv_path, rows)
        bar.update(1)

    _run_all(work, config, workers, scheduler, record)
    bar.close()
    return csv_path, failed


def _open_results(out: Path, config: BenchConfig, overwrite: bool, progress: bool,
                  folders: list[str]) -> set[tuple[str, str]]:
    """Make OUT/results.csv ready for `run_benchmark` on the sequence `folders`: resume it (same
    settings, `settings_differences`, columns, and folders for the finished sequences' names; a row
    cut short is dropped) unless `overwrite`, else start it with its header; write OUT/config.json
    (with the folder of each sequence) and record both files in the manifest.
    Returns the (sequence, descriptor) results already there."""
    csv_path = out / "results.csv"
    config_path = out / "config.json"
    resume = csv_path.is_file() and not overwrite
    made_by = provenance(config)  # hashes the weights files once
    feature_digests = _feature_digests(config, folders)
    header = None
    if csv_path.is_file():
        with open(csv_path, newline="", encoding="utf-8") as fh:
            header = next(csv.reader(fh), None)
    # (a results.csv geofeat did not write was refused before: `run_benchmark`'s `check_out_dir`)
    if resume and header == COLUMNS and not _finished(csv_path):
        # no result there (every sequence of the earlier run failed, or it was stopped before its first):
        # nothing to keep, so other settings are no reason to refuse the folder ("holds results made with
        # other settings", asking for --overwrite)
        resume = False
    if resume:
        try:
            before = json.loads(config_path.read_text(encoding="utf-8")) if config_path.is_file() else {}
        except ValueError:
            raise ValueError(f"out: {config_path} is not valid JSON; use --overwrite or another --out") from None
        if not isinstance(before, dict):
            raise ValueError(f"out: {config_path} holds {before!r}, not the settings of a bench run; use --overwrite "
                             "or another --out")
        differences = settings_differences(before, config, csv_path, folders)
        if differences:
            raise ValueError(f"out: {out} holds results made with other settings ({'; '.join(differences)}); use "
                             "--overwrite or another --out")
        if header != COLUMNS:
            raise ValueError(f"out: {csv_path} has other columns (an older geofeat?); use --overwrite")
        changed = _changed_weights(before.get("provenance") or {}, made_by)
        if changed:
            raise ValueError(f"out: {out} holds results made with other weights at the same path ({', '.join(changed)} "
                             "changed since: retrained?); use --overwrite or another --out")
        dropped = repair_results(csv_path)
        if dropped and progress:
            tqdm.write(f"bench: dropped {plural(dropped, 'incomplete row')} at the end of {csv_path}; "
                       + ("it is" if dropped == 1 else "they are") + " recomputed")
        done = _finished(csv_path)
        # a finished sequence's name read from another folder now: its rows would be taken for this one's
        read_from = before.get("sequences") if isinstance(before.get("sequences"), dict) else {}
        finished = {name for name, _ in done}
        moved = [f"{name} read from {read_from[name]} there, from {path} now"
                 for name, path in _read_from(folders).items() if name in finished and read_from.get(name, path) != path]
        if moved:
            raise ValueError(f"out: {out} holds results of another sequence of the same name ({'; '.join(moved)}); "
                             "use --overwrite or another --out")
        absent = sorted(finished - {Path(f).name for f in folders})
        if absent:  # the reports read results.csv: they averaged these, unchecked and ungrouped, with this run's
            listed = ", ".join(f"{name} (from {read_from[name]})" if name in read_from else name for name in absent[:5])
            raise ValueError(f"out: {out} holds results of {listed}{', ...' if len(absent) > 5 else ''}, not among the "
                             "datasets given; the reports would average them with this run's: give their folders too, "
                             "or use --overwrite or another --out")
        read_from = {**read_from, **_read_from(folders)}
        digests = _digests(folders, config.tps_dir)
        stored = before.get("sequence_digests") if isinstance(before.get("sequence_digests"), dict) else {}
        changed = sorted(name for name in finished if name in digests and name in stored
                         and not _same_files(stored[name], digests[name]))
        if changed:  # their rows describe the frames that were there before
            raise ValueError(f"out: {out} holds results of {', '.join(changed)}, whose files changed since (a frame "
                             f"replaced, added or removed, its {GT_JSON}, or its TPS files made again); use "
                             "--overwrite or another --out")
        unchecked = sorted(name for name in finished if name in digests and isinstance(stored.get(name), str)
                           and _GT_PART not in stored[name] and f"{_GT_PART}none" not in digests[name])
        if unchecked:  # accepted: see `_same_files`
            warnings.warn(f"out: {config_path} was written by an older geofeat, whose record of each sequence's "
                          f"files left out {GT_JSON}: the finished results of {', '.join(unchecked)} are kept, "
                          f"checked against their frames and <frame>-gt.npz files but not their {GT_JSON}; if one "
                          "changed since that run, use --overwrite or another --out to score them again",
                          stacklevel=2)
        digests = {**stored, **digests}
        stored_features = before.get("feature_digests") if isinstance(before.get("feature_digests"), dict) else {}
        rewritten = sorted(f"{name} of {sequence}" for sequence, name in done if name in feature_digests
                           and sequence in feature_digests[name]
                           and isinstance(stored_features.get(name), dict)
                           and stored_features[name].get(sequence, feature_digests[name][sequence])
                           != feature_digests[name][sequence])
        if rewritten:  # their rows score the features that were there before
            raise ValueError(f"out: {out} holds results of the --features {', '.join(rewritten)}, whose files "
                             "changed since (a frame's features rewritten, added or removed); use --overwrite or "
                             "another --out")
        feature_digests = {name: {**(stored_features.get(name) if isinstance(stored_features.get(name), dict)
                                     else {}), **per_sequence}
                           for name, per_sequence in feature_digests.items()}
    else:
        with atomic_file(csv_path) as tmp:
            with open(tmp, "w", newline="", encoding="utf-8") as fh:
                csv.DictWriter(fh, COLUMNS, lineterminator="\n").writeheader()
        done = set()
        read_from = _read_from(folders)
        digests = _digests(folders, config.tps_dir)
        ours = read_manifest(out)
        for name in REPORTS:  # the earlier run's reports, which this run may not rewrite (details.md, a curve)
            if name in ours:
                (out / name).unlink(missing_ok=True)
    with atomic_file(config_path) as tmp:
        tmp.write_text(json.dumps({**asdict(config), "provenance": made_by, "sequences": read_from,
                                   "sequence_digests": digests, "feature_digests": feature_digests}, indent=1), encoding="utf-8")
    add_to_manifest(out, ["results.csv", "config.json"])
    return done


def _remove_timing(out: Path, progress: bool) -> None:
    """Remove the timing.md that geofeat wrote in `out` (its manifest lists it), before rows are added
    to results.csv: it timed the descriptors of the results as they were, and a resumed run, which
    may add descriptors, writes it again only with --timing (it stayed, without those descriptors)."""
    timing, ours = out / "timing.md", read_manifest(out)
    if "timing.md" in ours and (timing.is_file() or timing.is_symlink()):
        timing.unlink()
        write_manifest(out, [rel for rel in ours if rel != "timing.md"])  # a file of that name is no longer ours
        if progress:
            tqdm.write(f"bench: removed {timing}, which timed the results before this run's "
                       "(--timing times them all again)")


def _read_from(folders: list[str]) -> dict[str, str]:
    """For config.json: the folder (absolute, links resolved) each sequence name was read from, so
    that a rerun does not take the results of one sequence for another's of the same name."""
    return {Path(f).name: str(Path(f).resolve()) for f in folders}


#: Marks the digest of a sequence's groundtruth.json in `_digests` (config.json written before it lacks it).
_GT_PART = "+gt:"


def _digests(folders: list[str], tps_dir: str | None = None) -> dict[str, str]:
    """For config.json: each sequence's `io.sequence_digest` (its frames' files: colour, depth, csv,
    <frame>-gt.npz; intrinsics.xml, geofeat.json), then "+gt:" and the digest of its simulator's
    groundtruth.json ("none" without one: the grid spacing the exact correspondences are computed
    with), so that a rerun does not keep the rows of a sequence whose frames or ground truth were
    replaced in place since; with `tps_dir`, then "+tps:" and the digest of the sequence's TPS files
    there (`tps_digest`): ground truth made again by `geofeat groundtruth`, or a relative --tps-dir
    given from another folder, changes the rows' ground truth as much."""
    out = {}
    for f in folders:
        settings = Path(f) / GT_JSON
        digest = f"{sequence_digest(f)}{_GT_PART}{files_digest([settings]) if settings.is_file() else 'none'}"
        out[Path(f).name] = digest + (f"+tps:{tps_digest(tps_dir, Path(f).name)}" if tps_dir is not None else "")
    return out


def _same_files(stored, now: str) -> bool:
    """Whether the digest config.json `stored` for a sequence and its digest `now` (`_digests`) say
    the same files. A digest an older geofeat stored has no "+gt:" part (its groundtruth.json was
    left out): it is compared with `now` without that part, and so accepted when every other file is
    unchanged (the caller says that its groundtruth.json was not checked). Refusing it instead would
    send every earlier run, hours of scoring, to --overwrite; the older digest still checks the
    <frame>-gt.npz files, which change with any re-simulation."""
    if not isinstance(stored, str):
        return False
    if _GT_PART in stored:
        return stored == now
    head, _, tail = now.partition(_GT_PART)
    return stored == head + tail[len(tail.split("+", 1)[0]):]


def tps_digest(tps_dir: str, name: str) -> str:
    """`io.files_digest` of the non-hidden files in the TPS folder of sequence `name` under `tps_dir`
    (`groundtruth.sources.tps_folder`); "none" when it has none."""
    from ..groundtruth.sources import tps_folder
    from ..io import files_digest

    folder = tps_folder(str(tps_dir), name)
    if folder is None:
        return "none"
    return files_digest(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))


def _feature_digests(config: BenchConfig, folders: list[str]) -> dict[str, dict[str, str]]:
    """For config.json: per --features set, each sequence's `ExternalFeatures.digest`, so that a rerun
    does not keep the rows of features rewritten at the same path since (as weights are compared
    by their SHA-256)."""
    out: dict[str, dict[str, str]] = {}
    for option in config.features:
        features = ExternalFeatures(*parse_features_option(option))
        out[features.name] = {Path(f).name: features.digest(Path(f).name, frame_names(f)) for f in folders}
    return out


def provenance(config: BenchConfig) -> dict:
    """What made the numbers besides the settings, for config.json: the geofeat version, the GeoPatch
    backend the shipped weights run on here (bf16, int8: scores agree to about 0.001, not to the
    bit), and the SHA-256 of the GeoKey weights the detector loads."""
    from .. import __version__
    from ..descriptors.geopatch import resolve_backend
    from ..descriptors.geopatch_onnx import file_sha256

    info: dict = {"geofeat": __version__}
    if "geopatch" in config.descriptors:  # on the GPU path: the torch backend (`Describer`)
        info["geopatch_backend"] = "torch" if config.device else resolve_backend(None, None, "cpu")
    if config.protocol == "detect" and config.detector.startswith("geokey"):
        from ..detectors.geokey import SHIPPED_WEIGHTS

        _, _, weights = config.detector.partition("=")
        path = Path(weights) if weights else SHIPPED_WEIGHTS
        info["detector_weights_sha256"] = file_sha256(path) if path.is_file() else None
    named = {d: Path(d.partition("=")[2]) for d in config.descriptors if "=" in d}  # "geopatch=W.pt"
    if named:
        info["descriptor_weights_sha256"] = {d: file_sha256(p) if p.is_file() else None for d, p in named.items()}
    return info


def _changed_weights(before: dict, now: dict) -> list[str]:
    """The weights files whose SHA-256 in config.json's provenance `before` differs from `now` (the
    same path retrained since): their earlier rows would be mixed with new ones under one name.
    A field an older config.json lacks is not compared."""
    changed = []
    old, new = before.get("detector_weights_sha256"), now.get("detector_weights_sha256")
    if old is not None and new is not None and old != new:
        changed.append("the detector's")
    old_d, new_d = before.get("descriptor_weights_sha256") or {}, now.get("descriptor_weights_sha256") or {}
    changed += [repr(d) for d in sorted(set(old_d) & set(new_d)) if old_d[d] is not None and old_d[d] != new_d[d]]
    return changed


def _run_all(work: list[tuple[str, tuple[str, ...]]], config: BenchConfig, workers: int, scheduler: str | None,
             record: Callable[[str, list[dict] | None, str | None], None]) -> None:
    """`_run_one` on every (sequence folder, descriptors) of `work`, on a dask scheduler, in `workers`
    processes, or here; `record(folder, rows, error)` is called with each result as it finishes."""
    if scheduler:
        from dask.distributed import Client, as_completed as dask_completed

        try:
            client = Client(scheduler)
        except (ValueError, OSError, TypeError) as error:  # dask's own message named no option
            raise ValueError(f"scheduler: cannot reach a Dask scheduler at {scheduler!r} ({error}); expected an "
                             "address such as tcp://host:8786") from None
        with client:
            futures = [client.submit(_run_one, f, config, todo, pure=False) for f, todo in work]
            for fut in dask_completed(futures):
                record(*fut.result())
    elif workers > 1:
        # spawn, not fork: the numba/OpenMP thread pool of this process must not be forked
        with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = [pool.submit(_run_one, f, config, todo) for f, todo in work]
            for fut in as_completed(futures):
                record(*fut.result())
    else:
        for f, todo in work:
            record(*_run_one(f, config, todo))
