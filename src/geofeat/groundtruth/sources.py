"""Every source of correspondences behind one interface, `GroundTruth`: the authors' TPS files
(`<frame>_theta.npy`, `_ctrlpts.npy`, `_objmask.png`, `_SSIM.png`), the simulator's exact
truth (`geofeat.truth`), or a thin-plate spline on the csv landmarks. The benchmark, `geofeat
match`, tracking and the object masks read ground truth from here."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.spatial import Delaunay

from ..inputs import check_tps_dir
from ..io import Sequence
from ..scoring import ground_truth_pairs

__all__ = ["GroundTruth", "LandmarkTPS", "authors_tps_warp", "correct_matches", "tps_folder"]


class LandmarkTPS:
    """Thin-plate spline from target to reference pixels fitted to landmarks visible in both frames
    (scipy RBFInterpolator). Points outside the convex hull of the target landmarks map to NaN."""

    def __init__(self, tgt_xy: np.ndarray, ref_xy: np.ndarray, smoothing: float = 0.0) -> None:
        tgt_xy, ref_xy = np.asarray(tgt_xy, float), np.asarray(ref_xy, float)
        if len(tgt_xy) < 4:
            raise ValueError(f"landmarks: a thin-plate spline needs >= 4 landmarks visible in both frames, got {len(tgt_xy)}")
        self._rbf = RBFInterpolator(tgt_xy, ref_xy, kernel="thin_plate_spline", smoothing=smoothing)
        self._hull = Delaunay(tgt_xy)

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        if len(xy) == 0:
            return np.zeros((0, 2))
        out = self._rbf(xy)
        out[self._hull.find_simplex(xy) < 0] = np.nan
        return out


def authors_tps_warp(xy: np.ndarray, theta: np.ndarray, ctrlpts: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The authors' published target->reference warp (`<k>_theta.npy`, `<k>_ctrlpts.npy`).

    Args:
        xy: (N, 2) target pixels. theta: (1, T+3, 2) or (T+3, 2) = [w (T, 2); a (3, 2)].
        ctrlpts: (T, 2) control points. size: (W, H) of the images (the TPS works in coordinates
            normalised by (W, H)).
    Returns:
        (N, 2) reference pixels: warped = p + [1, x, y] a + U w, U = d^2 log(d + 1e-6).
    """
    theta = np.asarray(theta, float).reshape(-1, 2)
    ctrl = np.asarray(ctrlpts, float).reshape(-1, 2)
    T = ctrl.shape[0]
    if theta.shape[0] != T + 3:
        raise ValueError(f"theta: expected {T + 3} rows for {T} control points, got {theta.shape[0]}")
    w, a = theta[:T], theta[T:]
    wh = np.asarray(size, float)
    p = np.asarray(xy, float).reshape(-1, 2) / wh
    d = np.linalg.norm(p[:, None, :] - ctrl[None, :, :], axis=-1)
    U = d**2 * np.log(d + 1e-6)
    affine = np.concatenate([np.ones((len(p), 1)), p], axis=1) @ a
    return (p + affine + U @ w) * wh


def _has_tps_files(folder: Path) -> bool:
    return folder.is_dir() and (any(folder.glob("*_theta.npy")) or any(folder.glob("*_objmask.png")))


def tps_folder(tps_dir: str, name: str) -> Path | None:
    """The folder of TPS files of sequence `name` under `tps_dir`: the first of `tps_dir/name`,
    `tps_dir/name/name` (groundtruth run with `--out tps_dir/name`) and `tps_dir/*/name` that holds
    TPS files (`*_theta.npy` or `*_objmask.png`); None when none does."""
    root = Path(tps_dir)
    for candidate in [root / name, root / name / name, *sorted(root.glob(f"*/{name}"))]:
        if _has_tps_files(candidate):
            return candidate
    return None


def _on_mask(mask: np.ndarray | None, xy: np.ndarray) -> np.ndarray:
    if mask is None:
        return np.ones(len(xy), bool)
    x = np.clip(xy[:, 0].astype(int), 0, mask.shape[1] - 1)
    y = np.clip(xy[:, 1].astype(int), 0, mask.shape[0] - 1)
    return mask[y, x] > 0


class GroundTruth:
    """Target -> reference mapping of a pair, from (in this order) the authors' TPS files, the
    simulator's exact correspondences, or a thin-plate spline on the csv landmarks."""

    def __init__(self, seq: Sequence, tps_dir: str | None) -> None:
        self.seq = seq
        check_tps_dir(tps_dir)
        self.tps = tps_folder(tps_dir, seq.name) if tps_dir else None
        if tps_dir and self.tps is None:
            raise ValueError(f"tps-dir: no TPS files (<frame>_theta.npy, <frame>_objmask.png) for sequence {seq.name} "
                             f"in {Path(tps_dir) / seq.name} or {Path(tps_dir)}/*/{seq.name}")
        self.exact = self.tps is None and seq.has_ground_truth()
        if self.tps is None and not self.exact and not seq.has_landmarks():
            raise ValueError(f"sequence {seq.name}: no ground truth (no simulator files, no csv landmarks, no TPS files)")

    def _mask(self, frame: str) -> np.ndarray | None:
        if self.tps is None:
            return None
        m = cv2.imread(str(self.tps / f"{frame}_objmask.png"), cv2.IMREAD_GRAYSCALE)
        if m is None:
            raise ValueError(f"tps-dir: missing {self.tps / f'{frame}_objmask.png'}")
        return m

    def reference_keep(self, xy: np.ndarray) -> np.ndarray:
        """Reference keypoints on the object (the simulator's visible surface, the TPS files' object
        mask; inside the landmarks' hull for landmark TPS)."""
        if self.exact:
            return self.seq.correspondences(self.seq.reference, self.seq.reference, xy)[1]
        keep = _on_mask(self._mask(self.seq.reference), xy)
        if self.tps is None and not self.exact:
            ids, lm, vis = self.seq.landmarks(self.seq.reference)
            keep &= np.isfinite(LandmarkTPS(lm[vis], lm[vis])(xy)).all(axis=1)
        return keep

    def covers(self, target: str) -> bool:
        """False for a target frame that the TPS files leave out (e.g. one `geofeat groundtruth`
        marked failed): the benchmark skips that pair and says so."""
        return self.tps is None or (self.tps / f"{target}_theta.npy").is_file()

    def target_to_reference(self, target: str, xy: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """(N, 2) target pixels -> reference pixels, NaN where the ground truth is unreliable."""
        if self.tps is not None:
            theta = np.load(self.tps / f"{target}_theta.npy")
            ctrl = np.load(self.tps / f"{target}_ctrlpts.npy")
            out = authors_tps_warp(xy, theta, ctrl, (shape[1], shape[0]))
            ssim = cv2.imread(str(self.tps / f"{target}_SSIM.png"), cv2.IMREAD_GRAYSCALE)
            ok = _on_mask(self._mask(target), xy)
            if ssim is not None:
                ok &= _on_mask((ssim.astype(np.float32) / 255.0 > 0.25).astype(np.uint8), xy)
            out[~ok] = np.nan
            return out
        if self.exact:
            mapped, visible = self.seq.correspondences(target, self.seq.reference, xy)
            return np.where(visible[:, None], mapped, np.nan)
        ids_r, xy_r, vis_r = self.seq.landmarks(self.seq.reference)
        ids_t, xy_t, vis_t = self.seq.landmarks(target)
        common, ir, it = np.intersect1d(ids_r[vis_r], ids_t[vis_t], return_indices=True)
        return LandmarkTPS(xy_t[vis_t][it], xy_r[vis_r][ir])(xy)


def correct_matches(truth: GroundTruth, target: str, ref_xy: np.ndarray, tgt_xy: np.ndarray,
                    matches0: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(n_ref,) bool: is reference keypoint i's match (matches0[i], -1 = none) a ground-truth pair of the
    protocol (the target keypoint whose ground-truth position in the reference is within 3 px of i,
    first in target order)? The count of True equals the benchmark's hits on the same keypoints."""
    mapped = truth.target_to_reference(target, np.asarray(tgt_xy, float).reshape(-1, 2), shape)
    pairs = ground_truth_pairs(np.asarray(ref_xy, float).reshape(-1, 2), mapped)
    partner = np.full(len(ref_xy), -2, np.int64)
    partner[pairs[:, 0]] = pairs[:, 1]
    return np.asarray(matches0) == partner
