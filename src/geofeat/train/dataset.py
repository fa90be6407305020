"""Patch datasets for training GeoPatch, built from simulated sequences with exact ground truth.

For each sequence, SIFT keypoints of the reference frame are followed into every other frame with
the simulator's correspondences; the polar patches of a surface point in all frames where it is
visible share one id (a keypoint within `SAME_POINT_PX` of a stronger one gets none: the same point).
Positives are two patches of one id; negatives come from other ids.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..scoring import ground_truth_pairs
from ..depth import DepthConfig, PROFILES, sequence_depth_profile
from ..geodesic.polar import polar_patches
from ..inputs import resolve_radius
from ..io import Sequence, find_sequences, read_sequence, sequence_digest
from ..keypoints import detect


@dataclass
class PatchSet:
    """Polar patches with surface-point ids.

    Attributes:
        patches: (M, R, A) uint8 intensities (x 255).
        ids: (M,) int64 surface-point id; equal ids = the same surface point.
        source: what the patches were built from (a JSON-able dict, e.g. the `train` command's
            sequence folders and options), saved with them so that a cache is not reused for other
            data; None when unknown.
    """

    patches: np.ndarray
    ids: np.ndarray
    source: dict | None = None

    def save(self, path: str | Path) -> None:
        """Write a compressed .npz archive, whole or not at all (`geofeat.outputs.write_npz`)."""
        import json

        from ..outputs import write_npz

        arrays = {"patches": self.patches, "ids": self.ids}
        if self.source is not None:
            arrays["source"] = np.array(json.dumps(self.source, sort_keys=True))
        write_npz(path, arrays, compressed=True)

    @classmethod
    def load(cls, path: str | Path) -> "PatchSet":
        """Read what `save` wrote; ValueError naming the file when it is not such an archive."""
        import json

        try:
            with np.load(path) as data:
                source = json.loads(str(data["source"])) if "source" in data.files else None
                return cls(data["patches"], data["ids"], source)
        except (OSError, ValueError, KeyError, EOFError) as error:
            raise ValueError(f"patches: cannot read {path} as a patch set of `geofeat train` "
                             f"({type(error).__name__}); delete it to rebuild it") from None

    def __len__(self) -> int:
        return len(self.ids)

    def digest(self) -> str:
        """Hex digest of the patches and their ids (shapes, dtypes and bytes): what `train` records in
        its checkpoint, so that resuming on other patches is refused."""
        import hashlib

        h = hashlib.blake2b(digest_size=16)
        for array in (np.ascontiguousarray(self.patches), np.ascontiguousarray(self.ids)):
            h.update(f"{array.dtype.str}{array.shape}".encode())
            h.update(memoryview(array).cast("B"))
        return h.hexdigest()


def _to_uint8(values: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(values * 255), 0, 255).astype(np.uint8)


def _sequence_config(seq: Sequence, depth_config: DepthConfig | str | None, ref) -> DepthConfig:
    if isinstance(depth_config, DepthConfig):
        return depth_config
    return PROFILES[sequence_depth_profile(seq, depth_config, ref)]


#: Reference keypoints closer than this many pixels to a stronger one are one surface point (SIFT
#: finds a blob at two scales a fraction of a pixel apart): only the stronger gets an id, so that no
#: triplet takes the other, nearly the same patch, for a negative.
SAME_POINT_PX = 1.0


def distinct_points(xy: np.ndarray, px: float = SAME_POINT_PX) -> np.ndarray:
    """(N,) bool: the keypoints `xy` (best first) farther than `px` from every stronger one kept."""
    from scipy.spatial import cKDTree

    keep = np.ones(len(xy), bool)
    if len(xy) > 1:
        for i, j in sorted(cKDTree(xy).query_pairs(px)):  # i < j: i's fate is settled first
            if keep[i]:
                keep[j] = False
    return keep


def sequence_patches(seq: Sequence, n_keypoints: int = 512, radius: float | None = None,
                     depth_config: DepthConfig | str | None = None, first_id: int = 0) -> PatchSet:
    """Patches of the reference frame's SIFT keypoints in every frame where they are visible.
    `radius`: geodesic radius, metres (None: the sequence's, `inputs.resolve_radius`, as every
    command reads it: its geofeat.json `radius`, else 0.075 m; a fixed default here trained on
    patches of another radius than `bench` describes the same sequence with).
    `depth_config`: a DepthConfig or a profile name, resolved once for the sequence (as the bench does:
    `depth.sequence_depth_profile`; None: the sequence's geofeat.json profile, else measured)."""
    radius = resolve_radius(radius, seq)
    ref = seq.frame(seq.reference)
    depth_config = _sequence_config(seq, depth_config, ref)
    kps = detect(ref, n_keypoints, detector="sift")
    kps = kps[distinct_points(kps.xy)]
    if not len(kps):
        return PatchSet(np.zeros((0, 32, 32), np.uint8), np.zeros(0, np.int64))
    p_ref = polar_patches(ref, kps.xy, radius=radius, depth_config=depth_config)
    patches, ids = [_to_uint8(p_ref.values[p_ref.valid])], [np.flatnonzero(p_ref.valid)]
    for name in seq.targets:
        mapped, visible = seq.correspondences(seq.reference, name, kps.xy)
        keep = np.flatnonzero(visible & p_ref.valid)
        if not len(keep):
            continue
        p = polar_patches(seq.frame(name), mapped[keep], radius=radius, depth_config=depth_config)
        patches.append(_to_uint8(p.values[p.valid]))
        ids.append(keep[p.valid])
    return PatchSet(np.concatenate(patches), np.concatenate(ids).astype(np.int64) + first_id)


def build_patch_set(paths, n_keypoints: int = 512, radius: float | None = None,
                    depth_config: DepthConfig | str | None = None, progress: bool = True) -> PatchSet:
    """Patch set of all sequences under `paths` (see `geofeat.io.find_sequences`); `radius`: see
    `sequence_patches` (None: each sequence's own)."""
    sets, next_id = [], 0
    for folder in tqdm(find_sequences(paths), desc="patches", unit="seq", disable=not progress):
        seq = read_sequence(folder)
        s = sequence_patches(seq, n_keypoints, radius, depth_config, first_id=next_id)
        next_id = int(s.ids.max()) + 1 if len(s) else next_id
        sets.append(s)
    if not sets:
        raise ValueError("data: no patches could be built")
    return PatchSet(np.concatenate([s.patches for s in sets]), np.concatenate([s.ids for s in sets]))


def check_simulated(paths, what: str) -> list[Path]:
    """The sequence folders under `paths` (`find_sequences`), each with the simulator's ground truth
    and at least one target frame beside its reference (training and validation work on pairs);
    ValueError naming `what` (data, val) otherwise. Checked before any patch is built."""
    folders = find_sequences(paths, what=what)
    for folder in folders:
        seq = read_sequence(folder)
        if not seq.has_ground_truth():
            raise ValueError(f"{what}: {folder} has no simulator ground truth (geofeat simulate writes it)")
        if not seq.targets:
            raise ValueError(f"{what}: {folder} has only its reference frame; training and validation need pairs "
                             "(geofeat simulate --frames 2 or more)")
    return folders


def warn_if_not_held_out(data_folders: list[Path], val_folders: list[Path], what: str = "val",
                         data_what: str = "data") -> None:
    """A UserWarning when validation sequences are also training sequences (the same folder given
    twice, inside a folder of sequences given as data, or a copy of one: the same frames, such as two
    simulations with the same --seed): validation is then not held out, and its scores flatter what
    was trained (train-detector also chooses its settings on them). Another when a validation
    sequence is textured with an image file that textures a training sequence (`recorded_photo`;
    compared by file name, all groundtruth.json records).
    Another when two training sequences are one: its points are trained twice, and `train` draws one
    point's two copies as each other's negatives."""
    import warnings

    digests = {}  # `sequence_digest`: equal for two copies, or two simulations with the same seed and settings
    for f in data_folders:
        digests.setdefault(sequence_digest(f), []).append(Path(f))
    twice = [group for group in digests.values() if len(group) > 1]
    if twice:
        pairs = ", ".join(f"{a} and {b}" for a, *rest in twice[:3] for b in rest[:1])
        warnings.warn(f"{data_what}: {pairs} hold the same frames (copies, or simulated with the same --seed and "
                      "settings), so their points are trained twice as if they were different points; simulate "
                      "each sequence with its own --seed", UserWarning, stacklevel=2)
    trained = {Path(f).resolve() for f in data_folders}
    shared, same, reported = [], [], set()
    for f in val_folders:
        if Path(f).resolve() in trained:
            shared.append(str(f))
        elif (twin := digests.get(sequence_digest(f))) is not None:
            same.append(f"{f} (= {twin[0]})")
        else:
            continue
        reported.add(str(f))
    if shared:
        warnings.warn(f"{what}: {', '.join(shared[:3])}{', ...' if len(shared) > 3 else ''} is also under {data_what}, "
                      "so validation is not held out and its scores flatter the training", UserWarning, stacklevel=2)
    if same:
        warnings.warn(f"{what}: {', '.join(same[:3])}{', ...' if len(same) > 3 else ''} holds the same frames as a "
                      f"sequence under {data_what} (a copy, or simulated with the same --seed and settings), so "
                      "validation is not held out and its scores flatter the training; simulate the validation "
                      "sequences with seeds of their own", UserWarning, stacklevel=2)
    # other frames, but an image that textures a training sequence too (`simulate`'s default draws from the
    # packaged photographs): the validation score then measures pictures the network was trained on
    trained_on = {}  # image file name -> the first training sequence it textures
    for f in data_folders:
        if (photo := recorded_photo(f)) is not None:
            trained_on.setdefault(photo, Path(f))
    seen = [f"{f} ({photo}, as {trained_on[photo]})" for f in val_folders
            if str(f) not in reported and (photo := recorded_photo(f)) in trained_on]
    if seen:
        warnings.warn(f"{what}: {', '.join(seen[:3])}{', ...' if len(seen) > 3 else ''} is textured with an image "
                      f"that also textures a sequence under {data_what}, so validation is not held out in texture "
                      "and its scores flatter the training; simulate the validation sequences with images of "
                      "their own (--texture, --texture-dir)", UserWarning, stacklevel=2)


def recorded_photo(folder: str | Path) -> str | None:
    """The file name of the image a simulated sequence was textured with (its groundtruth.json
    `texture`), or None for a generated texture ("procedural", "fabric", "fabric:KIND", drawn anew from
    each seed), an array, or a folder that records none."""
    from ..groundtruth.simulator import GT_JSON, read_metadata

    if not (Path(folder) / GT_JSON).is_file():
        return None
    texture = read_metadata(folder).get("texture")
    if not isinstance(texture, str) or texture in ("procedural", "fabric", "array") or texture.startswith("fabric:"):
        return None
    return texture


#: SIFT keypoints asked for per frame of the validation pairs (`validation_pairs`) that score each
#: epoch of `train`.
VALIDATION_KEYPOINTS = 1024


@dataclass
class ValidationPair:
    """Everything protocol "detect" needs for one pair, with patches precomputed.

    ref_patches (n_ref, R, A) float32, ref_valid (n_ref,), tgt_patches, tgt_valid, gt_pairs (M, 2);
    n_keypoints: the SIFT keypoints asked for per frame (for the label of the score, `validation_measure`)."""

    ref_patches: np.ndarray
    ref_valid: np.ndarray
    tgt_patches: np.ndarray
    tgt_valid: np.ndarray
    gt_pairs: np.ndarray
    n_keypoints: int = VALIDATION_KEYPOINTS


def validation_keypoints(paths, n_keypoints: int = VALIDATION_KEYPOINTS, max_pairs_per_sequence: int = 2, progress: bool = True):
    """Held-out pairs as protocol "detect" sees them, per sequence under `paths`: yields
    (seq, reference frame, its SIFT keypoints, [(target frame, its SIFT keypoints with ground truth,
    their (M, 2) ground-truth positions in the reference, pixels)]). Target keypoints without ground
    truth in the reference are dropped (protocol step 3). `progress`: a progress bar over sequences."""
    for folder in tqdm(find_sequences(paths), desc="validation pairs", unit="seq", disable=not progress):
        seq = read_sequence(folder)
        ref = seq.frame(seq.reference)
        targets = []
        step = max(1, len(seq.targets) // max_pairs_per_sequence)
        for name in seq.targets[::step][:max_pairs_per_sequence]:
            tgt = seq.frame(name)
            k_tgt = detect(tgt, n_keypoints, detector="sift")
            mapped, visible = seq.correspondences(name, seq.reference, k_tgt.xy)
            if visible.any():
                targets.append((tgt, k_tgt[visible], mapped[visible]))
        yield seq, ref, detect(ref, n_keypoints, detector="sift"), targets


def validation_pairs(paths, n_keypoints: int = VALIDATION_KEYPOINTS, radius: float | None = None,
                     depth_config: DepthConfig | str | None = None, max_pairs_per_sequence: int = 2) -> list[ValidationPair]:
    """Reference-target pairs of held-out sequences with independently detected SIFT keypoints and
    the simulator's ground truth, geodesic polar patches precomputed, for a per-epoch matching score.
    `radius`: see `sequence_patches` (None: each sequence's own)."""
    pairs = []
    for seq, ref, k_ref, targets in validation_keypoints(paths, n_keypoints, max_pairs_per_sequence):
        if not len(k_ref):
            continue
        config = _sequence_config(seq, depth_config, ref)
        seq_radius = resolve_radius(radius, seq)
        p_ref = polar_patches(ref, k_ref.xy, radius=seq_radius, depth_config=config)
        for tgt, k_tgt, mapped in targets:
            p_tgt = polar_patches(tgt, k_tgt.xy, radius=seq_radius, depth_config=config)
            pairs.append(ValidationPair(p_ref.values, p_ref.valid, p_tgt.values, p_tgt.valid,
                                        ground_truth_pairs(k_ref.xy, mapped), n_keypoints))
    return pairs
