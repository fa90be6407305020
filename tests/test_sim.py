"""Tests of the cloth simulator: isometry, exact ground truth, determinism, bad input."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from geofeat.io import read_sequence
from geofeat.sim import ClothScene, correspondences, has_ground_truth, simulate_sequence
from geofeat.sim import writer as writer_mod
from geofeat.cli import main
from geofeat.cli.simulate import add_parser
from geofeat.sim.cloth import Cloth, ClothConfig
from geofeat.sim.noise import finish_image
from geofeat.groundtruth.simulator import read_frame_truth, read_metadata, surface_coordinates, surface_to_points
from geofeat.sim.textures import packaged_texture_dir, procedural_texture, read_texture

TEXTURE = packaged_texture_dir() / "kodak_kodim23.jpg"


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "deform"
    simulate_sequence(out, "deform", n_frames=8, seed=1, texture=TEXTURE, width=320, height=240, progress=False)
    return read_sequence(out)


def _bilinear(img: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples of (H, W) img at (N, 2) xy; ok where all four neighbours are non-zero."""
    H, W = img.shape
    x0 = np.clip(np.floor(xy[:, 0]).astype(int), 0, W - 2)
    y0 = np.clip(np.floor(xy[:, 1]).astype(int), 0, H - 2)
    fx, fy = xy[:, 0] - x0, xy[:, 1] - y0
    n = [img[y0, x0], img[y0, x0 + 1], img[y0 + 1, x0], img[y0 + 1, x0 + 1]]
    val = n[0] * (1 - fx) * (1 - fy) + n[1] * fx * (1 - fy) + n[2] * (1 - fx) * fy + n[3] * fx * fy
    return val, np.all([v > 0 for v in n], axis=0)


def _backproject(xy: np.ndarray, z: np.ndarray, K: np.ndarray) -> np.ndarray:
    return np.stack([(xy[:, 0] - K[0, 2]) / K[0, 0] * z, (xy[:, 1] - K[1, 2]) / K[1, 1] * z, z], axis=1)


def test_isometry_neighbour_distances():
    rng = np.random.default_rng(5)
    scene = ClothScene("deform", 2, rng, procedural_texture(rng), size=(120, 160))
    for _ in range(20):
        scene.advance(6)
        structural, diagonal = scene.cloth.strain(0), scene.cloth.strain(1)
        # all but a handful of the 9460 edges within 2 % (the rest sit at crease tips, see cloth.py)
        assert np.percentile(structural, 99.9) < 0.02
        assert np.percentile(structural, 99) < 0.01
        assert structural.max() < 0.03
        assert np.percentile(diagonal, 99.9) < 0.02  # the rigid triangle diagonals
    # the cloth really moved: not a trivially rigid result
    assert np.abs(scene.cloth.pos - scene.cloth.prev).sum() > 0
    assert np.ptp(scene.cloth.pos[:, 2]) > 0.01


def test_block_parallel_sweep_is_independent_of_the_thread_count():
    """The parallel sweep is a Gauss-Seidel sweep in a fixed order: blocks of equal parity share no
    particle, so one thread and all threads give the same bytes."""
    import numba

    def simulate(threads: int) -> np.ndarray:
        cloth = Cloth(ClothConfig(rows=30, cols=20))
        cloth.pin([0, 19])
        before = numba.get_num_threads()
        numba.set_num_threads(threads)
        try:
            for _ in range(5):
                cloth.step(gravity=np.array([0.0, 0.002, 0.0]), wind=np.array([0.0, 0.0, 0.001]))
        finally:
            numba.set_num_threads(before)
        return cloth.pos

    one, many = simulate(1), simulate(numba.config.NUMBA_NUM_THREADS)
    assert np.array_equal(one, many) and np.ptp(one[:, 1]) > 0.01
    cfg = ClothConfig(rows=30, cols=20)
    cloth = Cloth(cfg)
    block_rows = [set() for _ in range(len(cloth._block_start) - 1)]
    for b in range(len(block_rows)):
        sel = cloth.pairs[cloth._block_start[b]:cloth._block_start[b + 1]]
        block_rows[b] = set((sel // cfg.cols).ravel().tolist())
        assert np.all(cloth.kind[cloth._block_start[b]:cloth._soft_start[b]] < 2)
        assert np.all(cloth.kind[cloth._soft_start[b]:cloth._block_start[b + 1]] >= 2)
    for b in range(len(block_rows) - 2):
        assert not block_rows[b] & block_rows[b + 2]
    assert cloth._block_start[-1] == len(cloth.rest)


def test_pixel_noise_is_gaussian_with_the_requested_sigma():
    grey = np.full((240, 320, 3), 0.5, np.float32)
    img = finish_image(grey, np.ones((240, 320), bool), np.zeros(3), 3.0, np.random.default_rng(0))
    noise = img.astype(np.float64) - 127.5
    # rounding to integers adds 1/12 to the variance
    assert abs(noise.std() - np.sqrt(9 + 1 / 12)) < 0.03
    assert abs(noise.mean()) < 0.02
    assert abs(np.corrcoef(noise[..., 0].ravel(), noise[..., 1].ravel())[0, 1]) < 0.01
    assert abs(np.corrcoef(noise[:, 1:, 0].ravel(), noise[:, :-1, 0].ravel())[0, 1]) < 0.01
    again = finish_image(grey, np.ones((240, 320), bool), np.zeros(3), 3.0, np.random.default_rng(0))
    assert np.array_equal(img, again)


def test_sequence_layout(seq):
    assert len(seq) == 8 and seq.reference == "frame-000-master"
    assert has_ground_truth(seq)
    f = seq.frame(0)
    assert f.shape == (240, 320)
    assert np.allclose(seq.K, [[262.5, 0, 159.5], [0, 262.5, 119.5], [0, 0, 1]])
    valid = f.depth > 0
    assert 0.15 < valid.mean() < 0.9  # cloth fills a good part of the frame, background = 0
    assert 0.75 < np.median(f.depth[valid]) < 1.2
    ids, xy, vis = seq.landmarks(0)
    assert len(ids) == 100 and vis.all()
    meta = read_metadata(seq.folder)
    assert meta["grid"] == [60, 80] and meta["frames"] == seq.names


def test_depth_and_K_agree_with_the_particle_surface(seq):
    meta = read_metadata(seq.folder)
    for name in (seq.names[0], seq.names[-1]):
        truth = read_frame_truth(seq.folder, name)
        depth = seq.frame(name).depth
        ys, xs = np.nonzero(depth > 0)
        xy = np.stack([xs, ys], axis=1).astype(np.float64)
        P = _backproject(xy, depth[ys, xs].astype(np.float64), seq.K)
        Q = surface_to_points(truth.uv[ys, xs].astype(np.float64), truth.vertices, meta["spacing_m"])
        err = np.linalg.norm(P - Q, axis=1)
        assert np.median(err) < 0.0005 and err.max() < 0.003, (np.median(err), err.max())


def test_ground_truth_preserves_distances(seq):
    rng = np.random.default_rng(0)
    meta = read_metadata(seq.folder)
    d0 = seq.frame(0).depth.astype(np.float64)
    ys, xs = np.nonzero(d0 > 0)
    pick = rng.choice(len(xs), 3000, replace=False)
    pts = np.stack([xs[pick], ys[pick]], axis=1) + rng.uniform(-0.5, 0.5, (3000, 2))
    uv, _ = surface_coordinates(read_frame_truth(seq.folder, 0), seq.K, meta["spacing_m"], pts)
    for j in (3, 7):
        mapped, visible = correspondences(seq, 0, j, pts)
        assert visible.mean() > 0.7
        dj = seq.frame(j).depth.astype(np.float64)
        z0, ok0 = _bilinear(d0, pts)
        zj, okj = _bilinear(dj, np.where(visible[:, None], mapped, 0))
        ok = visible & ok0 & okj
        P0, Pj, uvk = _backproject(pts[ok], z0[ok], seq.K), _backproject(mapped[ok], zj[ok], seq.K), uv[ok]
        a, b = np.triu_indices(len(P0), 1)
        geo = np.linalg.norm(uvk[a] - uvk[b], axis=1)
        short = (geo > 0.015) & (geo < 0.03)
        a, b, geo = a[short], b[short], geo[short]
        assert len(a) > 200
        e0 = np.linalg.norm(P0[a] - P0[b], axis=1)
        ej = np.linalg.norm(Pj[a] - Pj[b], axis=1)
        rel = np.abs(ej - e0) / geo
        assert np.median(rel) < 0.015 and np.percentile(rel, 90) < 0.03, (np.median(rel), np.percentile(rel, 90))
        # Euclidean vs geodesic (uv) distance in frame j
        assert np.median(np.abs(ej - geo) / geo) < 0.03


def test_colour_agrees_at_corresponding_pixels(seq):
    rng = np.random.default_rng(1)
    g0 = cv2.cvtColor(seq.frame(0).color, cv2.COLOR_BGR2GRAY).astype(np.float64)
    gj = cv2.cvtColor(seq.frame(5).color, cv2.COLOR_BGR2GRAY).astype(np.float64)
    ys, xs = np.nonzero(seq.frame(0).depth > 0)
    pick = rng.choice(len(xs), 2000, replace=False)
    pts = np.stack([xs[pick], ys[pick]], axis=1).astype(np.float64)
    mapped, visible = correspondences(seq, 0, 5, pts)
    a = g0[ys[pick], xs[pick]][visible]
    b, _ = _bilinear(gj, mapped[visible])
    shifted, _ = _bilinear(gj, mapped[visible] + [6.0, 0.0])
    corr = np.corrcoef(a, b)[0, 1]
    assert corr > 0.85, corr
    assert corr > np.corrcoef(a, shifted)[0, 1] + 0.1


def test_landmarks_follow_ground_truth(seq):
    _, xy0, _ = seq.landmarks(0)
    for j in (2, 7):
        _, xyj, visj = seq.landmarks(j)
        mapped, visible = correspondences(seq, 0, j, xy0)
        assert np.array_equal(visible, visj)
        assert np.abs(mapped[visible] - xyj[visible]).max() < 0.006


def test_self_mapping_is_identity_and_background_is_not_visible(seq):
    pts = np.array([[160.3, 120.7], [0.0, 0.0], [-5.0, 3.0]])
    mapped, visible = correspondences(seq, 0, 0, pts)
    assert visible.tolist() == [True, False, False]
    assert np.allclose(mapped[0], pts[0], atol=1e-6)
    assert np.isnan(mapped[1:]).all()


def test_scale_and_rotate_scenarios(tmp_path):
    s = read_sequence(simulate_sequence(tmp_path / "s", "scale", 3, seed=2, width=160, height=120, progress=False))
    z0, z2 = (np.median(s.frame(i).depth[s.frame(i).depth > 0]) for i in (0, 2))
    assert 1.8 < z2 / z0 < 2.2
    r = read_sequence(simulate_sequence(tmp_path / "r", "rotate", 3, seed=2, width=160, height=120, progress=False))
    meta = read_metadata(r.folder)
    R = np.load(r.folder / "frame-002-gt.npz")["R"]
    assert np.isclose(np.degrees(np.arctan2(R[1, 0], R[0, 0])), 180.0, atol=1e-6) or np.isclose(
        abs(np.degrees(np.arctan2(R[1, 0], R[0, 0]))), 180.0)
    assert meta["scenario"] == "rotate"


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_same_seed_same_bytes_different_seed_differs(tmp_path):
    kw = dict(n_frames=3, width=160, height=120, progress=False)
    a = _files(simulate_sequence(tmp_path / "a", "deform", seed=7, **kw))
    b = _files(simulate_sequence(tmp_path / "b", "deform", seed=7, **kw))
    c = _files(simulate_sequence(tmp_path / "c", "deform", seed=8, **kw))
    assert a == b
    assert a.keys() == c.keys()
    assert a["frame-002-rgb.png"] != c["frame-002-rgb.png"]


def test_kinect_noise_makes_holes_but_keeps_ground_truth(tmp_path):
    s = read_sequence(simulate_sequence(tmp_path / "k", "deform", 2, seed=3, width=320, height=240,
                                        kinect_noise=True, progress=False))
    truth = read_frame_truth(s.folder, 1)
    on_cloth = truth.uv[:, :, 0] >= 0
    depth = s.frame(1).depth
    holes = on_cloth & (depth == 0)
    assert 0.005 < holes.sum() / on_cloth.sum() < 0.5
    assert not (depth[~on_cloth] > 0).any()


def test_bad_input_gives_clear_errors_and_writes_nothing(tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image")
    with pytest.raises(ValueError, match="texture"):
        simulate_sequence(tmp_path / "o1", texture=bad, n_frames=2, width=64, height=48, progress=False)
    with pytest.raises(ValueError, match="texture"):
        simulate_sequence(tmp_path / "o1", texture=tmp_path / "missing.jpg", n_frames=2, progress=False)
    with pytest.raises(ValueError, match="n_frames"):
        simulate_sequence(tmp_path / "o2", n_frames=0, progress=False)
    with pytest.raises(ValueError, match="scenario"):
        simulate_sequence(tmp_path / "o3", scenario="twist", n_frames=2, progress=False)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x.txt").write_text("keep")
    with pytest.raises(ValueError, match="exists"):
        simulate_sequence(tmp_path / "full", n_frames=2, width=64, height=48, progress=False)
    assert (tmp_path / "full" / "x.txt").read_text() == "keep"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.png", "full"]


@pytest.mark.parametrize("preset", ["mild", "hard"])
@pytest.mark.parametrize("shape", [(0, 10, 3), (10, 0, 3)])
def test_empty_texture_array_is_a_clear_error(shape, preset, tmp_path):
    # was a bare ZeroDivisionError (mild) or cv2.error (paper, hard) from deep in the scene setup
    with pytest.raises(ValueError, match="texture: the array is empty"):
        simulate_sequence(tmp_path / "o", n_frames=2, width=64, height=48, texture=np.zeros(shape, np.uint8),
                          preset=preset, progress=False)
    assert list(tmp_path.iterdir()) == []


def test_failure_midway_leaves_nothing_behind(tmp_path, monkeypatch):
    original = writer_mod.write_frame

    def failing(folder, name, frame, *unit):
        if frame.index == 2:
            raise OSError("disk full (simulated)")
        return original(folder, name, frame, *unit)

    monkeypatch.setattr(writer_mod, "write_frame", failing)
    with pytest.raises(OSError, match="nothing was written"):
        simulate_sequence(tmp_path / "out", n_frames=4, width=64, height=48, progress=False)
    assert list(tmp_path.iterdir()) == []


def test_no_ground_truth_on_real_data():
    from geofeat.io import demo_data_dir

    s = read_sequence(demo_data_dir())
    assert not has_ground_truth(s)
    with pytest.raises(ValueError, match="ground truth"):
        correspondences(s, 0, 0, np.zeros((1, 2)))


def test_command(tmp_path, capsys):
    import argparse

    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["simulate", str(tmp_path / "c"), "--frames", "2", "--width", "64", "--height", "48",
                              "--texture", "procedural", "--no-progress", "--contact-sheet", str(tmp_path / "sheet.png")])
    assert args.command == "simulate"
    assert main(["simulate", str(tmp_path / "c"), "--frames", "2", "--width", "64", "--height", "48",
                 "--texture", "procedural", "--no-progress", "--contact-sheet", str(tmp_path / "sheet.png")]) == 0
    assert has_ground_truth(read_sequence(tmp_path / "c"))
    assert cv2.imread(str(tmp_path / "sheet.png")) is not None
    with pytest.raises(SystemExit) as stop:  # a usage error naming the flag, not simulate_sequence's n_frames
        main(["simulate", str(tmp_path / "d"), "--frames", "0", "--no-progress"])
    assert stop.value.code == 2 and "argument --frames: expected a whole number >= 1" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()
    assert main(["simulate", str(tmp_path / "e"), "--texture-dir", str(packaged_texture_dir()), "--frames", "1",
                 "--width", "64", "--height", "48", "--no-progress"]) == 0
    assert read_metadata(tmp_path / "e")["texture"].endswith(".jpg")


def test_texture_loading():
    img = read_texture(TEXTURE)
    assert img.ndim == 3 and img.dtype == np.uint8
    proc = procedural_texture(np.random.default_rng(0), 64, 48)
    assert proc.shape == (48, 64, 3) and proc.std() > 10


def test_a_texture_word_that_is_no_file_names_the_generated_choices(tmp_path, monkeypatch):
    """`--texture Procedural` (or "fabrics") said only "file not found: Procedural": the choices it
    almost named were not mentioned. A path with a folder or a suffix is a file that is missing."""
    from geofeat.sim.textures import choose_texture

    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(0)
    for word in ("Procedural", "fabrics"):
        with pytest.raises(ValueError, match=rf"file not found: {word}; the generated textures are 'procedural', "
                                             r"'fabric' or 'fabric:KIND' \(lower case\)"):
            choose_texture(rng, texture=word)
    for path in ("cloth.jpg", str(tmp_path / "photos" / "cloth")):
        with pytest.raises(ValueError, match=r"file not found: [^;]*$"):
            choose_texture(rng, texture=path)


def test_a_16_bit_texture_keeps_its_contrast_or_is_warned_of(tmp_path):
    """OpenCV's plain colour read scaled a 16-bit file by 1/256: a texture of 8-bit values stored in 16
    bits came back black without a word (it would be rendered as a black cloth)."""
    import cv2

    img = read_texture(TEXTURE)
    cv2.imwrite(str(tmp_path / "full.png"), img.astype(np.uint16) * 257)  # the whole 16-bit range
    assert np.abs(read_texture(tmp_path / "full.png").astype(int) - img).max() <= 1
    cv2.imwrite(str(tmp_path / "low.png"), img.astype(np.uint16))  # 8-bit values in a 16-bit file
    with pytest.warns(UserWarning, match="low.png"):
        read_texture(tmp_path / "low.png")


def test_simulate_writes_the_depth_profile_it_rendered(tmp_path):
    """The folder's geofeat.json names the depth profile of what was rendered, and it agrees with
    the profile `auto` measures on the frames."""
    import json

    import geofeat

    for noise, profile in ((False, "clean"), (True, "kinect")):
        folder = simulate_sequence(tmp_path / profile, scenario="deform", n_frames=2, seed=3, width=320, height=240,
                                   kinect_noise=noise, progress=False)
        assert json.loads((folder / "geofeat.json").read_text()) == {"depth_scale": 0.0001, "depth_profile": profile}
        seq = geofeat.read_sequence(folder)
        assert seq.depth_profile == profile
        assert geofeat.depth_profile(seq.frame(seq.reference)) == profile


@pytest.mark.parametrize("change, message", [
    (dict(width=64.5), "width: expected a whole number"),  # ran, with the principal point a quarter pixel off
    (dict(width=100000), "width: expected 32 to 8192"), (dict(height=8), "height: expected 32 to 8192"),
    (dict(seed=-1), "seed: expected"),  # numpy's "expected non-negative integer"
    (dict(steps_per_frame=0), "steps_per_frame: expected"),  # every frame a copy of the reference
])
def test_size_seed_and_steps_are_checked(change, message, tmp_path):
    kwargs = dict(dict(n_frames=2, width=64, height=48, texture="procedural", progress=False), **change)
    with pytest.raises(ValueError, match=message):
        simulate_sequence(tmp_path / "out", **kwargs)
    assert list(tmp_path.iterdir()) == []


def test_a_refused_or_interrupted_move_into_place_leaves_no_partial_folder(tmp_path, monkeypatch):
    """replace_folder failing at the end of simulate_sequence (a clash, Ctrl-C) used to leave the
    hidden ".<name>.partial-<pid>" folder behind."""
    def refuse(tmp, out):
        raise KeyboardInterrupt

    monkeypatch.setattr(writer_mod, "_write", lambda folder, scene, progress, meta, **kw: (folder / "x.txt").write_text("x"))
    monkeypatch.setattr(writer_mod, "replace_folder", refuse)
    with pytest.raises(KeyboardInterrupt):
        simulate_sequence(tmp_path / "seq", n_frames=2, width=64, height=48, progress=False)
    assert list(tmp_path.iterdir()) == []


def test_help_names_every_texture_choice_and_the_default_scenario(capsys):
    """`--texture fabric[:KIND]` works and docs/cli.md offers it; --help listed only a file or 'procedural'."""
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "'fabric' or 'fabric:KIND'" in text and "plaid" in text
    assert "(default deform)" in text


@pytest.mark.parametrize("kw", [dict(scenario="scale", preset="paper", fov=119), dict(scenario="deform", preset="hard"),
                                dict(scenario="rotate", kinect_noise=True)])
def test_simulated_sequences_raise_no_depth_units_warning(tmp_path, kw):
    """The depth-units warning (a median depth outside 0.15-4.5 m) never fires on what `simulate`
    writes, the widest field of view (nearest cloth) included."""
    import warnings

    from geofeat.inputs import DepthUnitsWarning

    folder = simulate_sequence(tmp_path / "s", n_frames=2, width=64, height=48, progress=False, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DepthUnitsWarning)
        read_sequence(folder)


def test_simulate_warns_when_the_reference_has_few_landmarks(tmp_path):
    """At 33 x 47 pixels the cloth leaves no room for Harris corners 5 px inside its border: the
    landmark CSVs come out empty, and `simulate` says so instead of writing them without a word."""
    with pytest.warns(UserWarning, match="0 landmarks"):
        folder = simulate_sequence(tmp_path / "tiny", n_frames=2, width=33, height=47, progress=False)
    assert read_sequence(folder).landmarks(0)[0].size == 0
    import warnings

    with warnings.catch_warnings():  # a frame of the usual size has its landmarks, and no warning
        warnings.simplefilter("error", UserWarning)
        simulate_sequence(tmp_path / "usual", n_frames=2, width=320, height=240, progress=False)


def test_landmark_flags_read_back_as_the_ground_truth_visibility(tmp_path):
    """A landmark seen in the first pixel row or column (centre at 0, so -0.5 <= y < 0) was written
    valid 1 at e.g. y = -0.21 (paper, seed 3, frame 5), and read_landmarks dropped it as invisible
    (it took x, y >= 0 for visible): the csv read back disagreed with the ground truth."""
    out = simulate_sequence(tmp_path / "s", "deform", n_frames=6, seed=3, width=160, height=120, preset="paper",
                            progress=False)
    seq = read_sequence(out)
    _, xy0, vis0 = seq.landmarks(0)
    assert vis0.all()
    edge = 0
    for j in range(1, len(seq)):
        _, xy, visible = seq.landmarks(j)
        _, truth = seq.correspondences(0, j, xy0)
        np.testing.assert_array_equal(visible, truth)
        edge += int((visible & (xy < 0).any(axis=1)).sum())
    assert edge >= 1  # the case above is in this sequence


def test_read_frame_takes_the_depth_scale_from_geofeat_json(tmp_path):
    """read_frame read a simulated frame (0.1 mm PNGs, geofeat.json depth_scale 0.0001) in
    millimetres, without a warning: the cloth at 0.86 m came back at 8.6 m."""
    import geofeat

    out = simulate_sequence(tmp_path / "s", "deform", n_frames=1, seed=1, width=64, height=48, progress=False)
    seq = read_sequence(out)
    name = seq.names[0]
    frame = geofeat.read_frame(out / f"{name}-rgb.png", out / f"{name}-depth.png", out / "intrinsics.xml")
    np.testing.assert_array_equal(frame.depth, seq.frame(0).depth)
    assert 0.5 < np.median(frame.depth[frame.depth > 0]) < 1.5
    # an explicit depth_scale still wins
    mm = geofeat.read_frame(out / f"{name}-rgb.png", out / f"{name}-depth.png", out / "intrinsics.xml",
                            depth_scale=0.001)
    np.testing.assert_allclose(mm.depth, 10 * frame.depth, rtol=1e-6)


@pytest.mark.parametrize("size", [dict(width=32, height=640), dict(width=1000, height=100, fov=119)])
def test_sizes_whose_intrinsics_read_sequence_refuses_are_refused_before_simulating(size, tmp_path):
    """32 x 640 (f = 525 * 32 / 640 = 26 px) and 1000 x 100 at 119 deg (f = 29 px) were simulated and
    written, and read_sequence then refused the intrinsics.xml (focal length under 0.1x the larger side)."""
    with pytest.raises(ValueError, match="width, height, fov: .* read_sequence"):
        simulate_sequence(tmp_path / "out", n_frames=1, texture="procedural", progress=False, **size)
    assert list(tmp_path.iterdir()) == []
    # a merely elongated size still works and reads back
    simulate_sequence(tmp_path / "ok", n_frames=1, texture="procedural", progress=False, width=48, height=320)
    assert read_sequence(tmp_path / "ok").shape == (320, 48)


FAR = dict(n_frames=5, seed=1, width=40, height=160, preset="paper", fov=20.5, texture="procedural", progress=False)


def test_a_scene_deeper_than_16_bits_of_tenth_millimetres_is_written_in_millimetres(tmp_path, monkeypatch):
    """paper, scale, --fov 20.5, 40 x 160: the camera backs off to 8.8 m, past the 6.55 m that 16 bits of
    0.1 mm hold; simulate failed with "does not fit a 16-bit PNG" after the whole simulation, and no
    option could write that scene. Then it was simulated to the frame that passed 6.55 m, and all over
    again in millimetres without a word: `ClothScene.depth_bound`, known before simulating, chooses the unit."""
    runs = []
    real_write = writer_mod._write
    monkeypatch.setattr(writer_mod, "_write", lambda folder, *a, **kw: (runs.append(kw["depth_unit"]),
                                                                        real_write(folder, *a, **kw)))
    out = simulate_sequence(tmp_path / "far", "scale", **FAR)
    assert runs == [writer_mod.FAR_DEPTH_UNIT_M]  # one run
    seq = read_sequence(out)
    assert seq.depth_scale == writer_mod.FAR_DEPTH_UNIT_M
    depth = seq.frame(len(seq) - 1).depth
    z = read_frame_truth(seq.folder, len(seq) - 1).vertices[..., 2]
    on = depth > 0
    assert depth.max() > 65535 * writer_mod.DEPTH_UNIT_M
    assert z.min() - 0.0006 <= depth[on].min() and depth[on].max() <= z.max() + 0.0006


def test_the_depth_bound_holds_and_a_depth_past_it_is_simulated_again_with_a_warning(tmp_path, monkeypatch):
    """`ClothScene.depth_bound` is above every depth of a scene, noise included, and keeps 0.1 mm for
    scenes at a metre or two; a depth past it (noise beyond 6 sigma) still gives a sequence in millimetres,
    simulated again with a warning."""
    for preset, scenario in (("mild", "scale"), ("paper", "deform"), ("hard", "rotate"), ("hard", "scale")):
        scene = ClothScene(scenario, 6, np.random.default_rng(7), procedural_texture(np.random.default_rng(0)),
                           size=(48, 64), preset=preset, kinect_noise=True)
        bound = scene.depth_bound()
        assert bound < writer_mod.max_depth_m(writer_mod.DEPTH_UNIT_M)
        assert all(f.vertices[..., 2].max() < bound and f.depth.max() < bound for f in scene.frames())
    runs = []
    real_write = writer_mod._write
    monkeypatch.setattr(writer_mod, "_write", lambda folder, *a, **kw: (runs.append(kw["depth_unit"]),
                                                                        real_write(folder, *a, **kw)))
    monkeypatch.setattr(ClothScene, "depth_bound", lambda self: 1.0)
    with pytest.warns(UserWarning, match=r"\d+\.\d\d m does not fit .* farther than the scene could reach \(1\.00 m\): "
                                         "simulating it again in millimetres"):
        out = simulate_sequence(tmp_path / "again", "scale", **FAR)
    assert runs == [writer_mod.DEPTH_UNIT_M, writer_mod.FAR_DEPTH_UNIT_M]
    assert read_sequence(out).depth_scale == writer_mod.FAR_DEPTH_UNIT_M


def test_a_large_frame_gets_about_a_texel_per_pixel_of_the_cloth():
    """Textures were capped at 1024 texels: on a 4096 px wide frame a texel of a large photograph covered
    two pixels of the cloth (a blurred cloth). Now at least one texel per pixel of the cloth's closest view,
    within `MAX_TEXELS`; up to 1008 px of cloth (every preset at 640 x 480) the width is the capped one's."""
    from geofeat.sim.textures import MAX_TEXELS, texture_width

    photo = np.random.default_rng(0).integers(0, 256, (3000, 4000, 3), dtype=np.uint8)
    scene = ClothScene("deform", 1, np.random.default_rng(0), photo, size=(3072, 4096))
    cloth_px = scene.K[0, 0] * scene.config.width_m / scene.params.distance  # mild: a fixed camera
    assert cloth_px > 2000 and scene.texture.shape[1] >= cloth_px
    for aspect in (0.5, 4 / 3, 4.0):
        wide = texture_width(1e5, aspect)
        assert wide * round(wide / aspect) <= 1.001 * MAX_TEXELS
        for px in np.linspace(1, 1008, 50):
            assert texture_width(px, aspect) == int(min(1024, 1.5 * px + 16))


def test_kinect_noise_changes_only_the_depth_of_the_same_scene(tmp_path):
    # the noise draws shared the scene's generator: with --kinect-noise the same seed gave another cloth
    # motion (up to 2 cm per vertex by frame 2), other lights and other image noise
    kw = dict(n_frames=3, seed=3, width=80, height=60, texture="procedural", progress=False)
    clean = simulate_sequence(tmp_path / "clean", "deform", **kw)
    noisy = simulate_sequence(tmp_path / "noisy", "deform", kinect_noise=True, **kw)
    for i in range(3):
        a, b = read_frame_truth(clean, i), read_frame_truth(noisy, i)
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.uv, b.uv)
    a, b = _files(clean), _files(noisy)
    for name in ("frame-001-rgb.png", "frame-002-rgb.png", "frame-002.csv"):
        assert a[name] == b[name]
    da, db = (cv2.imread(str(f / "frame-002-depth.png"), cv2.IMREAD_UNCHANGED).astype(float) * 1e-4 for f in (clean, noisy))
    both = (da > 0) & (db > 0)
    assert (db[da > 0] == 0).any()  # holes
    assert 0 < np.abs(da - db)[both].mean() < 0.01  # millimetre noise on the same surface


def test_pins_sharing_a_particle_of_a_narrow_grid_do_not_collapse_the_cloth():
    """Four pins on a 3-column grid round to columns 0, 1, 1, 2: the two pins of column 1 (rest distance 0)
    made the feasibility scale 0 and drew every pin onto their centre, bunching the top edge into one point."""
    rng = np.random.default_rng(0)
    scene = ClothScene("deform", 3, rng, procedural_texture(np.random.default_rng(1), 64, 48), size=(48, 64),
                       cloth_config=ClothConfig(rows=20, cols=3))
    assert len(scene.pin_idx) == 4 and len(np.unique(scene.pin_idx)) == 3
    pins = scene._pins(200)
    assert np.ptp(pins[:, 0]) > 0.5 * np.ptp(scene.pin_rest[:, 0])


def test_recorded_difference_names_what_differs(seq, tmp_path):
    """`recorded_difference` compares a folder's recorded settings with the ones asked for."""
    from geofeat.sim.writer import SIMULATOR_REVISION, recorded_difference

    asked = dict(scenario="deform", n_frames=8, seed=1, texture=TEXTURE, width=320, height=240, preset="mild",
                 kinect_noise=False, fov=None, motion_blur=False, steps_per_frame=6)
    assert recorded_difference(seq.folder, **asked) is None
    found = recorded_difference(seq.folder, **{**asked, "seed": 2, "width": 640, "texture": "fabric"})
    assert "seed 1 (wanted 2)" in found and "width 320 (wanted 640)" in found
    assert "texture 'kodak_kodim23.jpg' (wanted 'fabric')" in found and "revision" not in found
    with pytest.raises(TypeError, match="unknown"):
        recorded_difference(seq.folder, frames=8)
    meta = (seq.folder / "groundtruth.json").read_text()
    assert f'"simulator_revision": {SIMULATOR_REVISION}' in meta
    (tmp_path / "groundtruth.json").write_text(meta.replace(f'"simulator_revision": {SIMULATOR_REVISION}',
                                                            f'"simulator_revision": {SIMULATOR_REVISION - 1}'))
    assert f"simulator revision {SIMULATOR_REVISION - 1}" in recorded_difference(tmp_path, **asked)
    assert "is missing" in recorded_difference(tmp_path / "nowhere")


def test_recorded_difference_tells_a_fabric_family_from_a_random_fabric(tmp_path):
    """`--texture fabric:plaid` was recorded in groundtruth.json as plain "fabric", so `recorded_difference`
    took the sequence for one simulated with a random fabric (another family, other random draws) and
    called it different from the very settings it was simulated with."""
    from geofeat.sim.writer import recorded_difference

    asked = dict(seed=3, n_frames=1, width=64, height=48)
    simulate_sequence(tmp_path / "plaid", texture="fabric:plaid", progress=False, **asked)
    assert recorded_difference(tmp_path / "plaid", texture="fabric:plaid", **asked) is None
    found = recorded_difference(tmp_path / "plaid", texture="fabric", **asked)
    assert found is not None and "texture 'fabric:plaid' (wanted 'fabric')" in found


def test_a_texture_with_transparent_pixels_is_warned_of(tmp_path):
    """The alpha channel of an RGBA texture was dropped without a word: a logo on a transparent background
    (stored as transparent black, as most tools write it) became a logo on a black cloth."""
    import warnings

    rgba = np.zeros((64, 64, 4), np.uint8)
    rgba[16:48, 16:48] = (0, 0, 255, 255)
    cv2.imwrite(str(tmp_path / "logo.png"), rgba)
    with pytest.warns(UserWarning, match=r"logo.png has transparent pixels \(75%\)"):
        image = read_texture(tmp_path / "logo.png")
    assert (image[0, 0] == 0).all() and (image[32, 32] == (0, 0, 255)).all()  # what the cloth shows
    rgba[..., 3] = 255  # opaque RGBA, grey and 16-bit files: no warning
    cv2.imwrite(str(tmp_path / "opaque.png"), rgba)
    cv2.imwrite(str(tmp_path / "grey.png"), np.full((16, 16), 90, np.uint8))
    cv2.imwrite(str(tmp_path / "deep.png"), np.full((16, 16, 4), 65535, np.uint16))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in ("opaque.png", "grey.png", "deep.png"):
            read_texture(tmp_path / name)
