"""Image-patch datasets for the TFeat-/Log-Polar-style baselines, from the same sequences as GeoPatch's.

Data-agnostic: any sequence folder with ground-truth correspondences (`Sequence.correspondences`)
serves. For each sequence, SIFT keypoints of the reference frame get an id; in every target frame
SIFT is run again and a target keypoint whose ground-truth position in the reference lies within
the protocol's threshold of a reference keypoint gets that id. Patches use each frame's *own*
detected orientation and size, as at test time (mapping the reference keypoints instead would
hand the nets a perfect orientation they never get in the benchmark).
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from ..scoring import ground_truth_pairs
from ..descriptors.image_patch_nets import image_patches
from ..io import Sequence, find_sequences, read_sequence
from ..keypoints import detect
from .dataset import VALIDATION_KEYPOINTS, PatchSet, ValidationPair, distinct_points, validation_keypoints


def _to_uint8(values: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(values * 255), 0, 255).astype(np.uint8)


def sequence_image_patches(seq: Sequence, arch: str, n_keypoints: int = 512, first_id: int = 0) -> PatchSet:
    """(M, 32, 32) uint8 patches of `arch` with surface-point ids for one sequence."""
    ref = seq.frame(seq.reference)
    k_ref = detect(ref, n_keypoints, detector="sift")
    k_ref = k_ref[distinct_points(k_ref.xy)]  # one id per surface point (`dataset.SAME_POINT_PX`)
    patches, ids = [_to_uint8(image_patches(ref.image, k_ref, arch))], [np.arange(len(k_ref))]
    for name in seq.targets:
        tgt = seq.frame(name)
        k_tgt = detect(tgt, 2 * n_keypoints, detector="sift")
        mapped, visible = seq.correspondences(name, seq.reference, k_tgt.xy)
        gt = ground_truth_pairs(k_ref.xy, np.where(visible[:, None], mapped, np.nan))
        if not len(gt):
            continue
        patches.append(_to_uint8(image_patches(tgt.image, k_tgt[gt[:, 1]], arch)))
        ids.append(gt[:, 0])
    return PatchSet(np.concatenate(patches), np.concatenate(ids).astype(np.int64) + first_id)


def build_image_patch_set(paths, arch: str, n_keypoints: int = 512, progress: bool = True) -> PatchSet:
    """Patch set of all sequences under `paths` (see `geofeat.io.find_sequences`)."""
    sets, next_id = [], 0
    for folder in tqdm(find_sequences(paths), desc=f"{arch} patches", unit="seq", disable=not progress):
        s = sequence_image_patches(read_sequence(folder), arch, n_keypoints, first_id=next_id)
        next_id = int(s.ids.max()) + 1 if len(s) else next_id
        sets.append(s)
    if not sets:
        raise ValueError("data: no patches could be built")
    return PatchSet(np.concatenate([s.patches for s in sets]), np.concatenate([s.ids for s in sets]))


def image_validation_pairs(paths, arch: str, n_keypoints: int = VALIDATION_KEYPOINTS, max_pairs_per_sequence: int = 2) -> list[ValidationPair]:
    """Held-out reference-target pairs (protocol "detect", independent SIFT keypoints) with `arch`
    patches precomputed, for the training loop's per-epoch matching score."""
    pairs = []
    for _, ref, k_ref, targets in validation_keypoints(paths, n_keypoints, max_pairs_per_sequence):
        if not len(k_ref):
            continue
        p_ref = image_patches(ref.image, k_ref, arch)
        for tgt, k_tgt, mapped in targets:
            p_tgt = image_patches(tgt.image, k_tgt, arch)
            pairs.append(ValidationPair(p_ref, np.ones(len(p_ref), bool), p_tgt, np.ones(len(p_tgt), bool),
                                        ground_truth_pairs(k_ref.xy, mapped), n_keypoints))
    return pairs
