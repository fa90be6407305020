"""Write simulated sequences in the public dataset layout, plus exact dense ground truth.

A sequence folder gets, per frame `<name>` (`frame-000-master` is the reference, then
`frame-001`, ...):
    `<name>-rgb.png`    8-bit BGR,
    `<name>-depth.png`  16-bit camera Z in 0.1 mm units (`depth_scale` 0.0001 in geofeat.json; millimetres,
                        0.001, for a sequence whose depth may pass 6.55 m, `ClothScene.depth_bound`),
                        0 = background / hole,
    `<name>.csv`        the 100 best Harris corners of the reference tracked into this frame
                        (`id,x,y,valid`; pixels, OpenCV convention: the centre of the top-left
                        pixel is (0, 0); valid = 0 where occluded, off the cloth or off the image),
    `<name>-gt.npz`     dense ground truth (see `geofeat.groundtruth.simulator`),
and `intrinsics.xml`, `groundtruth.json`.

The folder is written under a temporary name next to OUT_DIR and moved into place at the end, so an
error never leaves a half-written sequence behind; `--overwrite` removes only files geofeat wrote
(`geofeat.outputs`), never a user's.
"""

from __future__ import annotations

import io
import json
import shutil
import warnings
import zipfile
from pathlib import Path

import cv2
import numpy as np

from ..inputs import check_bool, check_intrinsics_for_image, check_whole
from ..io import DEPTH_NO_DATA, write_intrinsics, write_landmarks
from ..outputs import SEQUENCE, check_out_dir, replace_folder, temporary_folder
from ..groundtruth.landmarks import MIN_LANDMARKS
from ..groundtruth.simulator import GT_JSON, GT_SUFFIX, FrameTruth, map_points
from .render import NEAR_M, clipped_in_view
from .scenes import SCENARIOS, ClothScene, SimFrame, default_intrinsics, get_preset
from .textures import choose_texture

REFERENCE_NAME = "frame-000-master"
N_LANDMARKS = 100
#: Fewer reference landmarks than this and `simulate` warns: `geofeat groundtruth` needs
#: `MIN_LANDMARKS` of them visible in both frames, and its robust fit drops up to a third.
FEW_LANDMARKS = 10
FORMAT_VERSION = 1
#: Bumped whenever the same settings and seed simulate other frames (groundtruth.json records it;
#: files without it are revision 1). 2: short `paper` / `hard` sequences take more sub-steps and
#: points behind a fold are hidden (2026-11-27).
SIMULATOR_REVISION = 2
#: Image sides (pixels) the simulator renders: from 32 (landmarks need a border) to 8192.
SIDE_RANGE_PX = (32, 8192)


def frame_name(index: int) -> str:
    """File stem of frame `index` (0 = reference)."""
    return REFERENCE_NAME if index == 0 else f"frame-{index:03d}"


def save_npz(path: str | Path, **arrays: np.ndarray) -> None:
    """`np.savez_compressed` with fixed zip timestamps, so that equal arrays give equal bytes."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for key, value in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asanyarray(value), allow_pickle=False)
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, buf.getvalue(), compresslevel=1)


def harris_landmarks(image: np.ndarray, mask: np.ndarray, n: int = N_LANDMARKS) -> np.ndarray:
    """(M, 2) float64 pixel positions (M <= n) of the strongest Harris corners of a uint8 BGR
    image inside `mask` (H, W) bool, at least 5 px from the cloth border and 8 px apart."""
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    inner = cv2.erode(mask.astype(np.uint8), np.ones((11, 11), np.uint8))
    corners = cv2.goodFeaturesToTrack(gray, maxCorners=n, qualityLevel=1e-6, minDistance=8, mask=inner,
                                      blockSize=5, useHarrisDetector=True, k=0.04)
    if corners is None:
        return np.zeros((0, 2))
    return corners.reshape(-1, 2).astype(np.float64)


#: Metres per unit of the depth PNGs the simulator writes (0.1 mm; `depth_scale` in geofeat.json).
#: Millimetre PNGs quantise close-up cloth in steps of up to half a pixel footprint, which the
#: full-resolution walk reads as noise: on `hard` scenes that cost the clean profile a fifth of its
#: matching score (BENCHMARKS.md, "Depth units"). 16 bits of 0.1 mm reach 6.55 m.
DEPTH_UNIT_M = 0.0001
#: The unit of a sequence whose depth may pass 6.55 m (a narrow --fov with the paper or hard preset's
#: scale swing or the scale scenario), chosen before simulating (`ClothScene.depth_bound`): millimetres, up to 65.5 m.
FAR_DEPTH_UNIT_M = 0.001


class DepthOverflowError(ValueError):
    """A depth does not fit a 16-bit PNG at the unit asked for."""


def max_depth_m(unit: float) -> float:
    """The farthest depth (metres) a 16-bit PNG in `unit` metres holds (`encode_depth`)."""
    return (DEPTH_NO_DATA - 1) * unit


def encode_depth(depth: np.ndarray, unit: float = DEPTH_UNIT_M) -> np.ndarray:
    """(H, W) float metres -> uint16 depth in `unit` metres (0 stays 0); DepthOverflowError past `max_depth_m`."""
    units = np.rint(np.asarray(depth, np.float64) / unit)
    if units.max(initial=0) >= DEPTH_NO_DATA:  # 65535 reads as missing (`io.read_depth`)
        raise DepthOverflowError(f"depth: {units.max() * unit:.2f} m does not fit a 16-bit PNG at {unit} m per unit")
    return units.astype(np.uint16)


def _check_args(scenario: str, n_frames: int, width: int, height: int, seed: int = 0, steps_per_frame: int = 6) -> None:
    if scenario not in SCENARIOS:
        raise ValueError(f"scenario: expected one of {', '.join(SCENARIOS)}, got {scenario!r}")
    if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 1:
        raise ValueError(f"n_frames: expected an integer >= 1 (the reference included), got {n_frames!r}")
    lo, hi = SIDE_RANGE_PX
    for what, side in (("width", width), ("height", height)):  # a float size would shift the principal point
        if check_whole(side, what, 1) < lo or side > hi:
            raise ValueError(f"{what}: expected {lo} to {hi} pixels, got {side}")
    check_whole(seed, "seed", 0)
    check_whole(steps_per_frame, "steps_per_frame", 1)  # 0: every frame a copy of the reference


def simulate_sequence(
    out_dir: str | Path,
    scenario: str = "deform",
    n_frames: int = 10,
    seed: int = 0,
    texture: str | Path | np.ndarray | None = None,
    width: int = 640,
    height: int = 480,
    kinect_noise: bool = False,
    progress: bool = True,
    texture_dir: str | Path | None = None,
    steps_per_frame: int = 6,
    overwrite: bool = False,
    preset: str = "mild",
    fov: float | None = None,
    motion_blur: bool = False,
) -> Path:
    """Simulate, render and write one sequence; returns the sequence folder.

    Args:
        out_dir: sequence folder to create (must not exist or be empty, unless `overwrite`).
        scenario: `deform` (a fixed camera; with the paper and hard presets it swings closer and farther
            and orbits the cloth), `rotate` (camera roll 0..180 degrees) or `scale` (camera moving back to
            twice the distance).
        n_frames: number of frames, the reference included (>= 1).
        seed: a whole number >= 0; everything random (texture choice, cloth, wind, pins, lights, noise) follows it.
        texture: image file, `"procedural"`, `"fabric"` or `"fabric:KIND"` (a generated fabric,
            `geofeat.sim.textures.FABRIC_KINDS`), an (H, W, 3) uint8 BGR array, or None (a packaged
            training photograph or a procedural texture, drawn from the seed).
        width, height: image size in pixels, whole numbers from 32 to 8192; intrinsics f = 525 * width / 640,
            centred.
        kinect_noise: write Kinect-like noisy depth with holes (ground truth stays exact).
        progress: show a tqdm progress bar.
        texture_dir: draw the texture from this folder instead.
        steps_per_frame: simulation steps between frames (>= 1).
        overwrite: replace an earlier simulation in out_dir: only the files geofeat wrote there (its
            `.geofeat-manifest.json`) are removed; a folder holding any other file is refused.
        preset: `mild` (the original scenes), `paper` (the paper's simulation section) or `hard`
            (strong folds, foreshortening, gusts, moving specular lights, noise); see
            `geofeat.sim.scenes.PRESETS`.
        fov: vertical field of view in degrees, strictly between 20 and 120 (None: Kinect-like
            f = 525 px at 640 x 480, 49.1 deg; the paper authors' renders: 90).
        motion_blur: blur the target frames along a random direction (up to the preset's length;
            `paper` and `hard` only, `mild` has none).
    """
    _check_args(scenario, n_frames, width, height, seed, steps_per_frame)
    for name, flag in (("kinect_noise", kinect_noise), ("motion_blur", motion_blur), ("overwrite", overwrite)):
        check_bool(flag, name)  # "false" from a config file was True: noisy depth, blur, or an earlier run replaced
    preset_obj = get_preset(preset)
    if motion_blur and not preset_obj.blur_px > 0:  # it blurred nothing, and groundtruth.json said motion_blur true
        raise ValueError(f"motion_blur: the {preset_obj.name} preset has no motion blur; simulate with the paper or "
                         "hard preset, or without motion blur")
    K = default_intrinsics(width, height, fov)
    try:  # an elongated image (32 x 640, or 1000 x 100 at 119 deg) was simulated and written, then refused by read_sequence
        check_intrinsics_for_image(K, (height, width), "K")
    except ValueError:
        raise ValueError(f"width, height, fov: a {width}x{height} image with "
                         f"{'f = 525 * width / 640' if fov is None else f'a vertical field of view of {fov:g} deg'} has "
                         f"f = {K[0, 0]:.4g} px, outside the 0.1 to 20 times the larger side that read_sequence "
                         "accepts; choose a less elongated size or another fov") from None
    out_dir = Path(out_dir)
    # overwrite replaces only what geofeat wrote there; a folder holding other files is refused
    check_out_dir(out_dir, overwrite, what="out_dir", strict=True, inputs=[texture_dir], writes=SEQUENCE)

    def scene() -> tuple[ClothScene, str]:  # everything follows the seed: each call makes the same scene
        rng = np.random.default_rng(seed)
        tex_image, tex_name = choose_texture(rng, texture, texture_dir)
        return ClothScene(scenario, int(n_frames), rng, tex_image, (height, width), K=K, kinect_noise=kinect_noise,
                          steps_per_frame=steps_per_frame, preset=preset_obj, motion_blur=motion_blur), tex_name

    meta = {"generator": "geofeat.sim", "format_version": FORMAT_VERSION, "simulator_revision": SIMULATOR_REVISION,
            "scenario": scenario, "seed": int(seed), "texture": None, "kinect_noise": bool(kinect_noise),
            "preset": preset_obj.name, "fov_deg": None if fov is None else float(fov), "motion_blur": bool(motion_blur)}
    first, meta["texture"] = scene()
    # the unit is chosen before simulating: a scene whose depth may pass what 16 bits of 0.1 mm hold was simulated
    # to the frame that passed it, then all over again in millimetres, without a word
    bound = first.depth_bound()
    unit = DEPTH_UNIT_M if bound < max_depth_m(DEPTH_UNIT_M) else FAR_DEPTH_UNIT_M
    try:
        return _simulate(out_dir, first, meta, progress, unit)
    except DepthOverflowError as error:
        if unit != DEPTH_UNIT_M:
            raise
        # `ClothScene.depth_bound` holds but for depth noise past 6 sigma
        warnings.warn(f"{out_dir}: {error.__cause__}, farther than the scene could reach ({bound:.2f} m): simulating "
                      f"it again in millimetres (depth_scale {FAR_DEPTH_UNIT_M:g} in geofeat.json)", stacklevel=2)
        return _simulate(out_dir, scene()[0], meta, progress, FAR_DEPTH_UNIT_M)


def _simulate(out_dir: Path, scene: ClothScene, meta: dict, progress: bool, depth_unit: float) -> Path:
    """Simulate `scene` and write it to `out_dir` (depth PNGs in `depth_unit` metres), or nothing on an error."""
    # built in geofeat's temporary folder (`partial_name`), which `find_sequences` passes over and a
    # rerun removes when a kill left it: the ".<name>.partial-<pid>" folder of a killed run stayed
    # for good, and a folder of sequences read it as a sequence (without geofeat.json, so with
    # the wrong depth scale)
    tmp = temporary_folder(out_dir)
    try:
        _write(tmp, scene, progress, shown=out_dir, meta=meta, depth_unit=depth_unit)
        replace_folder(tmp, out_dir)  # inside: a refusal or an interrupt here must not leave tmp behind
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, Exception):
            raise type(exc)(f"{exc} (nothing was written to {out_dir})") from exc
        raise
    return out_dir


def recorded_difference(folder: str | Path, **wanted) -> str | None:
    """Why the sequence simulated in `folder` is not what `simulate_sequence(folder, **wanted)` would
    write with this geofeat, or None when it is (as far as its groundtruth.json records).

    `wanted`: any of `simulate_sequence`'s `scenario`, `seed`, `n_frames`, `preset` (a name),
    `kinect_noise`, `fov` (degrees or None), `texture` (a path, compared by file name, or "procedural"
    / "fabric" / "fabric:KIND"), `width`, `height` (pixels), `motion_blur` and `steps_per_frame`; the simulator
    revision is always compared. For scripts that reuse earlier sequences: a folder made
    with other settings, or by an earlier simulator, is not a cache of this run.
    """
    path = Path(folder) / GT_JSON
    if not path.is_file():
        return f"{path} is missing"
    meta = json.loads(path.read_text())
    width, height = meta.get("image_size", (None, None))
    recorded = {"scenario": meta.get("scenario"), "seed": meta.get("seed"), "n_frames": meta.get("n_frames"),
                "preset": meta.get("preset"), "kinect_noise": meta.get("kinect_noise"), "fov": meta.get("fov_deg"),
                "texture": meta.get("texture"), "width": width, "height": height,
                "motion_blur": meta.get("motion_blur"),
                "steps_per_frame": meta.get("solver", {}).get("steps_per_frame")}
    given = dict(wanted)
    if "texture" in given and given["texture"] not in ("procedural", "fabric") and not str(given["texture"]).startswith("fabric:"):
        given["texture"] = Path(given["texture"]).name
    if given.get("fov") is not None:
        given["fov"] = float(given["fov"])
    unknown = sorted(set(given) - set(recorded))
    if unknown:
        raise TypeError(f"recorded_difference: unknown settings {unknown}")
    found = [f"{key} {recorded[key]!r} (wanted {value!r})" for key, value in given.items() if recorded[key] != value]
    revision = meta.get("simulator_revision", 1)
    if revision != SIMULATOR_REVISION:
        found.append(f"simulator revision {revision} (this geofeat simulates revision {SIMULATOR_REVISION})")
    return f"{folder} was simulated with " + ", ".join(found) if found else None


def _write(folder: Path, scene: ClothScene, progress: bool, meta: dict, shown: Path | None = None,
           depth_unit: float = DEPTH_UNIT_M) -> None:
    """Write the sequence into `folder`; `shown`: the folder its messages name (the sequence folder
    the user gave, not the temporary folder it is built in)."""
    scene.kinect_noise = bool(meta["kinect_noise"])
    cfg = scene.config
    write_intrinsics(folder / "intrinsics.xml", scene.K)
    names = [frame_name(i) for i in range(scene.n_frames)]
    frames = scene.frames()
    if progress:
        from tqdm import tqdm

        frames = tqdm(frames, total=scene.n_frames, desc=f"simulate {meta['scenario']}", unit="frame")
    ref_truth: FrameTruth | None = None
    landmarks = np.zeros((0, 2))
    clipped: list[str] = []  # frames where the cloth in view comes closer than the renderer draws
    for frame in frames:
        name = names[frame.index]
        truth = write_frame(folder, name, frame, depth_unit)
        if clipped_in_view(frame.vertices, scene.K, scene.size):
            clipped.append(name)
        if frame.index == 0:
            ref_truth = truth
            landmarks = harris_landmarks(frame.image, frame.render.mask)
            if len(landmarks) < FEW_LANDMARKS:
                warnings.warn(f"{shown or folder}: the reference frame has {len(landmarks)} landmarks (Harris corners at least "
                              f"5 px inside the cloth; {N_LANDMARKS} wanted), so the landmark CSVs are of little use: "
                              f"`geofeat groundtruth` needs {MIN_LANDMARKS} in both frames. A larger image or a "
                              "richer texture gives more.", stacklevel=2)
        assert ref_truth is not None
        xy, visible = map_points(ref_truth, truth, scene.K, cfg.spacing_m, landmarks)
        xy = np.where(np.isfinite(xy), xy, -1.0)
        write_landmarks(folder / f"{name}.csv", np.arange(len(landmarks)), xy, visible)
    if clipped:
        # a wide --fov puts the paper and hard presets' cloth a few tenths of a metre away, and their pins and
        # camera swing can bring it onto the lens: those frames showed holes or the inside of the cloth unannounced
        shown_names = ", ".join(clipped[:5]) + (", ..." if len(clipped) > 5 else "")
        warnings.warn(f"{shown or folder}: in {len(clipped)} of {scene.n_frames} frames ({shown_names}) the cloth in view "
                      f"comes closer than {NEAR_M * 100:g} cm to the camera, which the renderer does not draw: those "
                      "frames show holes in the cloth or its inside, as no camera would (their ground truth matches what "
                      "they show; groundtruth.json lists them as near_frames). A narrower --fov, a milder preset or "
                      "another seed keeps the cloth away.", stacklevel=2)
    meta = {
        **meta,
        "n_frames": scene.n_frames,
        "near_frames": clipped,
        "image_size": [scene.size[1], scene.size[0]],
        "grid": [cfg.rows, cfg.cols],
        "spacing_m": cfg.spacing_m,
        "cloth_size_m": [cfg.width_m, cfg.height_m],
        "solver": {"substeps": cfg.substeps, "passes": cfg.passes, "damping": cfg.damping, "dt2": cfg.dt2,
                   "steps_per_frame": scene.params.steps_per_frame, "bending_stiffness": cfg.bending_stiffness},
        "image_noise_sigma": scene.params.image_sigma,
        "frames": names,
        "conventions": {
            "pixels": "OpenCV: the centre of the top-left pixel is (0, 0); x = fx X / Z + cx",
            "depth_png": f"uint16 camera Z in units of depth_scale (geofeat.json, {depth_unit * 1e3:g} mm), "
                         "0 = background or hole",
            "uv": "metres on the flat rest cloth (geodesic distance = |uv1 - uv2|), -1 = background",
            "vertices": "(rows, cols, 3) particle positions in the frame's camera coordinates, metres",
            "pose": "R, t map reference-camera (world) coordinates to this frame's camera",
        },
    }
    (folder / GT_JSON).write_text(json.dumps(meta, indent=1))
    # the depth profile of what was rendered (`geofeat.depth_profile` measures the same on these frames)
    (folder / "geofeat.json").write_text(json.dumps({"depth_scale": depth_unit,
                                                    "depth_profile": "kinect" if meta["kinect_noise"] else "clean"}))


def write_frame(folder: Path, name: str, frame: SimFrame, depth_unit: float = DEPTH_UNIT_M) -> FrameTruth:
    """Write the PNGs (depth in `depth_unit` metres) and `<name>-gt.npz` of one frame; return its ground truth."""
    if not cv2.imwrite(str(folder / f"{name}-rgb.png"), frame.image):
        raise ValueError(f"out_dir: cannot write {folder / f'{name}-rgb.png'}")
    if not cv2.imwrite(str(folder / f"{name}-depth.png"), encode_depth(frame.depth, depth_unit)):
        raise ValueError(f"out_dir: cannot write {folder / f'{name}-depth.png'}")
    truth = FrameTruth(uv=frame.render.uv, vertices=frame.vertices)
    save_npz(folder / f"{name}{GT_SUFFIX}", uv=truth.uv, vertices=truth.vertices, R=frame.R, t=frame.t)
    return truth
