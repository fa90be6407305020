"""Ground truth of a pair behind one interface: `GroundTruth.map(target, xy) -> (xy_ref, valid)` maps
pixels of a target frame to reference pixels from (in this order) the authors' TPS files
(`<frame>_theta.npy`, written by `geofeat groundtruth`), the simulator's exact correspondences, or a
thin-plate spline on the csv landmarks. The benchmark, `geofeat match`, tracking and the object mask
use it."""

from __future__ import annotations

import warnings
from pathlib import Path

import cv2
import numpy as np

from ..inputs import as_points, check_tps_dir
from ..io import Sequence
from ..scoring import ground_truth_pairs
from ..tps import ThinPlateSpline
from .landmarks import MIN_LANDMARKS, inside_hull, landmark_spline

__all__ = ["GroundTruth", "correct_matches", "judged_matches", "tps_folder", "load_authors_spline",
           "refuse_partial_simulator_truth", "missing_ssim_maps", "without_ssim_maps"]


def _has_tps_files(folder: Path) -> bool:
    return folder.is_dir() and (any(folder.glob("*_theta.npy")) or any(folder.glob("*_objmask.png")))


def tps_folder(tps_dir: str, name: str) -> Path | None:
    """The folder of TPS files of sequence `name` under `tps_dir`: the first of `tps_dir/name` and
    `tps_dir/name/name` (groundtruth run with `--out tps_dir/name`) that holds TPS files (`*_theta.npy`
    or `*_objmask.png`), else the one `tps_dir/*/name` that does; None when none does. ValueError when
    several `tps_dir/*/name` do (two datasets with a sequence of this name: the first by name was
    taken without a word)."""
    root = Path(tps_dir)
    for candidate in (root / name, root / name / name):
        if _has_tps_files(candidate):
            return candidate
    found = [c for c in sorted(root.glob(f"*/{name}")) if _has_tps_files(c)]
    if len(found) > 1:
        raise ValueError(f"tps-dir: {len(found)} folders hold TPS files for sequence {name} ("
                         f"{', '.join(str(f) for f in found[:4])}); pass the one meant as --tps-dir "
                         f"({found[0].parent})")
    return found[0] if found else None


def missing_ssim_maps(folder: Path, targets: list[str] | None = None) -> tuple[list[str], list[str]]:
    """The target frames that the TPS files in `folder` give a spline (`<k>_theta.npy`), among
    `targets` (default: every such file's frame), and the names of the SSIM maps (`<k>_SSIM.png`,
    the protocol's step 3) missing for them."""
    suffix = "_theta.npy"
    if targets is None:
        targets = sorted(p.name[: -len(suffix)] for p in folder.glob(f"*{suffix}") if not p.name.startswith("."))
    covered = [t for t in targets if (folder / f"{t}{suffix}").is_file()]
    return covered, [f"{t}_SSIM.png" for t in covered if not (folder / f"{t}_SSIM.png").is_file()]


def without_ssim_maps(tps_dir: str, names) -> list[str]:
    """The sequences among `names` whose TPS files under `tps_dir` have no SSIM map for any target
    frame: their target keypoints were kept by the object masks alone (`GroundTruth` warns), for
    the notes of `geofeat bench`'s reports."""
    out = []
    for name in names:
        folder = tps_folder(tps_dir, name)
        if folder is not None:
            covered, missing = missing_ssim_maps(folder)
            if covered and len(missing) == len(covered):
                out.append(name)
    return out


def _on_mask(mask: np.ndarray | None, xy: np.ndarray) -> np.ndarray:
    """(N,) bool: pixels xy (N, 2) on the (H, W) mask, read at `mask[int(y), int(x)]` as the authors'
    matching-score protocol reads its object masks (`shared/reference/matching_score_protocol.md`):
    truncation, not the nearest pixel, so that `--tps-dir` scores match theirs; False off the image
    (outside -0.5 .. W - 0.5), where clipping would read the border pixel of the mask instead."""
    if mask is None:
        return np.ones(len(xy), bool)
    H, W = mask.shape
    with np.errstate(invalid="ignore"):
        inside = (xy[:, 0] >= -0.5) & (xy[:, 0] <= W - 0.5) & (xy[:, 1] >= -0.5) & (xy[:, 1] <= H - 0.5)
    x = np.clip(np.where(inside, xy[:, 0], 0).astype(int), 0, W - 1)
    y = np.clip(np.where(inside, xy[:, 1], 0).astype(int), 0, H - 1)
    return inside & (mask[y, x] > 0)


def load_authors_spline(folder: Path, frame: str, size: tuple[int, int]) -> ThinPlateSpline:
    """The authors' target -> reference spline of `frame` (`<frame>_theta.npy`, `<frame>_ctrlpts.npy` in
    `folder`); size: (W, H) of the frame, pixels."""
    return ThinPlateSpline.from_authors_arrays(np.load(folder / f"{frame}_theta.npy"),
                                               np.load(folder / f"{frame}_ctrlpts.npy"), size)


class GroundTruth:
    """Target -> reference mapping of a pair, from (in this order) the authors' TPS files, the
    simulator's exact correspondences, or a thin-plate spline on the csv landmarks.

    Attributes:
        seq: the sequence.
        tps: the folder of the authors' TPS files of the sequence, None when not used.
        exact: True when the simulator's exact correspondences are used.
    """

    def __init__(self, seq: Sequence, tps_dir: str | None) -> None:
        self.seq = seq
        check_tps_dir(tps_dir)
        self.tps = tps_folder(tps_dir, seq.name) if tps_dir else None
        if tps_dir and self.tps is None:
            raise ValueError(f"tps-dir: no TPS files (<frame>_theta.npy, <frame>_objmask.png) for sequence {seq.name} "
                             f"in {Path(tps_dir) / seq.name} or {Path(tps_dir)}/*/{seq.name}")
        if self.tps is not None:
            self._check_ssim_maps()
        self.exact = self.tps is None and seq.has_ground_truth()
        if self.tps is None and not self.exact and not seq.has_landmarks():
            missing = seq.without_landmarks()
            csv = "no csv landmarks" if len(missing) == len(seq) else (  # some: the spline needs every frame's
                f"csv landmarks in {len(seq) - len(missing)} of {len(seq)} frames only, none for "
                f"{', '.join(missing[:5])}{', ...' if len(missing) > 5 else ''}")
            raise ValueError(f"sequence {seq.name}: no ground truth (no simulator files, {csv}, no TPS files)")

    def _check_ssim_maps(self) -> None:
        """The SSIM maps of the TPS files (`<k>_SSIM.png`: target keypoints are kept where > 0.25, the
        protocol's step 3) for every target frame they give a spline, or for none. A missing one
        skipped the filter for its frame alone, without a word: ValueError naming them when some are
        there and others not; a warning, once per sequence, when none is (the object masks alone
        decide which target keypoints are scored)."""
        covered, missing = missing_ssim_maps(self.tps, self.seq.targets)
        if missing and len(missing) < len(covered):
            raise ValueError(f"tps-dir: {self.tps} has an SSIM map (<k>_SSIM.png, the protocol's step 3) for "
                             f"{len(covered) - len(missing)} of the {len(covered)} target frames of {self.seq.name} "
                             f"with a spline, not {', '.join(missing[:5])}{', ...' if len(missing) > 5 else ''}: "
                             "restore them, or make the TPS files again (geofeat groundtruth)")
        if missing:
            warnings.warn(f"tps-dir: {self.tps} has no SSIM map (<k>_SSIM.png) for any target frame of "
                          f"{self.seq.name}: step 3 of the protocol (target keypoints kept where SSIM > 0.25) is "
                          "skipped, the object masks alone decide which are scored", stacklevel=3)

    def _mask(self, frame: str) -> np.ndarray | None:
        """The (H, W) uint8 object mask of `frame` in the TPS files (None without them); ValueError when
        it is missing or of another size than the sequence's frames."""
        if self.tps is None:
            return None
        m = self._read_map(f"{frame}_objmask.png")
        if m is None:
            raise ValueError(f"tps-dir: missing {self.tps / f'{frame}_objmask.png'}")
        return m

    def _read_map(self, name: str) -> np.ndarray | None:
        """The (H, W) uint8 picture `name` of the TPS files (an object mask, an SSIM map), read as stored;
        None when there is no such file. ValueError when it cannot be read or is of another size than
        the sequence's frames: such a map is read at the keypoints' pixels, so one made for another
        size (an SSIM map of half the size kept the target keypoints of one corner only) scored the
        pair on other keypoints without a word; the spline is normalised by the mask's size."""
        path = self.tps / name
        if not path.is_file():
            return None
        m = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
        if m is None:
            raise ValueError(f"tps-dir: {path} is not an image OpenCV can read; make the TPS files again "
                             "(geofeat groundtruth)")
        shape = self.seq.shape
        if shape is not None and m.shape != tuple(shape):
            raise ValueError(f"tps-dir: {path} is {m.shape[1]}x{m.shape[0]}, the frames of {self.seq.folder} "
                             f"{shape[1]}x{shape[0]}; TPS files map pixels of the image size they were made for: "
                             "make them again for these frames (geofeat groundtruth)")
        return m

    def reference_keep(self, xy: np.ndarray) -> np.ndarray:
        """Reference keypoints on the object (the simulator's visible surface, the TPS files' object
        mask; inside the landmarks' hull for landmark TPS)."""
        if self.exact:
            return self.seq.correspondences(self.seq.reference, self.seq.reference, xy)[1]
        keep = _on_mask(self._mask(self.seq.reference), xy)
        if self.tps is None:
            ids, lm, vis = self.seq.landmarks(self.seq.reference)
            _check_landmarks(int(vis.sum()))
            keep &= inside_hull(lm[vis], xy)
        return keep

    def covers(self, target: str) -> bool:
        """False for a target frame that the TPS files leave out (e.g. one `geofeat groundtruth`
        marked failed), or, with the landmarks' spline, that has fewer than `MIN_LANDMARKS` landmarks
        visible in both it and the reference (no spline: `map` would raise): the benchmark skips
        that pair and says so (`uncovered_reason`)."""
        return self.uncovered_reason(target) is None

    def uncovered_reason(self, target: str) -> str | None:
        """Why `target` has no ground truth (`covers`), in words; None when it has one."""
        if self.tps is not None:
            return None if (self.tps / f"{target}_theta.npy").is_file() else f"no {target}_theta.npy in the TPS files"
        if self.exact:
            return None
        ids_r, _, vis_r = self.seq.landmarks(self.seq.reference)
        ids_t, _, vis_t = self.seq.landmarks(target)
        common = len(np.intersect1d(ids_r[vis_r], ids_t[vis_t]))
        if common < MIN_LANDMARKS:
            return (f"{common} landmarks visible in both it and the reference, and the landmarks' spline needs "
                    f">= {MIN_LANDMARKS}")
        return None

    def map(self, target: str, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map pixels of frame `target` to the reference frame.

        Args:
            target: a target frame name of the sequence.
            xy: (N, 2) pixels of the target frame.
        Returns:
            xy_ref: (N, 2) reference pixels, NaN where the ground truth is unknown or unreliable (off
                the simulated surface or occluded; off the TPS files' object mask or below their SSIM
                threshold; outside the landmarks' convex hull).
            valid: (N,) bool, True where xy_ref is known.
        """
        xy = as_points(xy, "xy")
        if self.tps is not None:
            mask = self._mask(target)
            out = load_authors_spline(self.tps, target, (mask.shape[1], mask.shape[0]))(xy)
            ok = _on_mask(mask, xy)
            ssim = self._read_map(f"{target}_SSIM.png")
            if ssim is not None:
                ok &= _on_mask((ssim.astype(np.float32) / 255.0 > 0.25).astype(np.uint8), xy)
        elif self.exact:
            out, ok = self.seq.correspondences(target, self.seq.reference, xy)
        else:
            ids_r, xy_r, vis_r = self.seq.landmarks(self.seq.reference)
            ids_t, xy_t, vis_t = self.seq.landmarks(target)
            common, ir, it = np.intersect1d(ids_r[vis_r], ids_t[vis_t], return_indices=True)
            _check_landmarks(len(common))
            lm_t = xy_t[vis_t][it]
            out, ok = landmark_spline(lm_t, xy_r[vis_r][ir])(xy), inside_hull(lm_t, xy)
        valid = ok & np.isfinite(out).all(axis=1)
        return np.where(valid[:, None], out, np.nan), valid

    def project(self, target: str, xy_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Where reference pixels lie in frame `target`, seen or hidden (simulated sequences only).

        Args:
            target: a target frame name of the sequence.
            xy_ref: (N, 2) reference pixels.
        Returns:
            (xy, visible): (N, 2) frame pixels where the surface point under each reference pixel
            projects (NaN off the surface), and (N,) bool, True where that point is seen in the frame
            (not hidden under a fold, facing the camera, inside the image); None without the
            simulator's exact correspondences (TPS files and landmarks only map frame -> reference).
        """
        if not self.exact:
            return None
        return self.seq.correspondences(self.seq.reference, target, as_points(xy_ref, "xy_ref"))


def refuse_partial_simulator_truth(seq: Sequence) -> None:
    """ValueError when `seq` holds some of the simulator's ground-truth files but not all
    (`groundtruth.json` and a `<frame>-gt.npz` for every frame). `GroundTruth` then takes the
    landmarks' spline for every pair of the sequence; the benchmark refuses that (it scored the
    sequence against other ground truth without a word, other keypoints kept: MS 0.158 became 0.177
    on a `paper` sequence missing one target's file). A sequence with none of the `<frame>-gt.npz`
    files passes (scored with its landmarks)."""
    from .simulator import GT_JSON, GT_SUFFIX, missing_ground_truth

    missing = missing_ground_truth(seq)
    if not missing or len([m for m in missing if m != GT_JSON]) == len(seq.names):  # whole, or none of the frames'
        return
    raise ValueError(f"sequence {seq.name}: the simulator's ground truth is incomplete in {seq.folder} (missing "
                     f"{', '.join(missing[:5])}{', ...' if len(missing) > 5 else ''}); its exact correspondences need "
                     f"{GT_JSON} and every frame's <frame>{GT_SUFFIX}: restore them, or remove every <frame>{GT_SUFFIX} "
                     "to score the sequence with its csv landmarks")


def _check_landmarks(n: int) -> None:
    if n < MIN_LANDMARKS:
        raise ValueError(f"landmarks: a thin-plate spline needs >= {MIN_LANDMARKS} landmarks visible in both frames, got {n}")


def correct_matches(truth: GroundTruth, target: str, ref_xy: np.ndarray, tgt_xy: np.ndarray,
                    matches0: np.ndarray) -> np.ndarray:
    """(n_ref,) bool: is reference keypoint i's match (matches0[i], -1 = none) a ground-truth pair of the
    protocol (the target keypoint whose ground-truth position in the reference is within 3 px of i,
    first in target order)? The count of True equals the benchmark's hits on the same keypoints."""
    mapped = truth.map(target, tgt_xy)[0]
    pairs = ground_truth_pairs(as_points(ref_xy, "ref_xy"), mapped)
    partner = np.full(len(ref_xy), -2, np.int64)
    partner[pairs[:, 0]] = pairs[:, 1]
    return np.asarray(matches0) == partner


def judged_matches(truth: GroundTruth, target: str, tgt_xy: np.ndarray, matches0: np.ndarray) -> np.ndarray:
    """(n_ref,) bool: can reference keypoint i's match (matches0[i], -1 = none: False) be judged, its
    target keypoint having a ground-truth position in the reference (`GroundTruth.map`: not occluded,
    off the surface or outside the landmarks' hull)? The protocol drops the others before scoring,
    so `correct_matches`' False means wrong only where this is True."""
    matches0 = np.asarray(matches0)
    known = truth.map(target, tgt_xy)[1]
    has = matches0 >= 0
    judged = np.zeros(len(matches0), bool)
    judged[has] = known[matches0[has]]
    return judged
