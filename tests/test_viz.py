"""Pictures (`geofeat.viz`): edge inputs give a picture or a clear error."""

import numpy as np
import pytest

import geofeat
from geofeat.geodesic.polar import PolarPatches
from geofeat.viz import (CORRECT, MAX_MATCHES_WIDTH, UNJUDGED, WRONG, draw_geodesic_support, draw_matches, match_key,
                         patch_grid, ring_distances_mm)


def _no_patches() -> PolarPatches:
    return PolarPatches(np.zeros((0, 2)), np.zeros((0, 32, 32), np.float32), np.zeros((0, 32, 32, 2), np.float32),
                        np.zeros(0, bool), np.zeros((0, 32), np.int32), np.zeros((0, 32, 32, 3), np.float32), 0.075)


def test_pictures_of_no_keypoints_are_the_bare_frame():
    frame = geofeat.read_demo_frame()
    empty = _no_patches()
    assert (draw_geodesic_support(frame, empty) == frame.color).all()
    assert (patch_grid(empty) == 255).all()
    both = draw_matches(frame, frame, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64))
    assert both.shape == (frame.shape[0], 2 * frame.shape[1], 3)


@pytest.mark.parametrize("kwargs", [dict(columns=0), dict(zoom=0), dict(columns=-1), dict(columns=2.5)])
def test_patch_grid_refuses_meaningless_layouts(kwargs):
    # columns=0: ZeroDivisionError; zoom=0: an OpenCV assertion in resize; columns=-1: "negative dimensions"
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        patch_grid(_no_patches(), **kwargs)


def _flat_frame(bgr=(200, 60, 0), shape=(240, 320)) -> "geofeat.RGBDFrame":
    """A frame of one colour (no grey in it, so that a label's grey pixels stand out)."""
    H, W = shape
    image = np.zeros((H, W, 3), np.uint8)
    image[:] = bgr
    f = max(300.0, 0.5 * max(H, W))  # a plausible focal length for large frames too
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]])
    return geofeat.RGBDFrame(image, np.ones(shape, np.float32), K)


def _label_pixels(picture: np.ndarray, frame_bgr, rows: slice) -> np.ndarray:
    """(h, w) bool: pixels of picture[rows] that are not the frame's colour (a label's)."""
    return np.abs(picture[rows].astype(int) - np.array(frame_bgr)).max(-1) > 40


def test_a_title_sits_on_a_solid_box_so_that_it_reads_on_any_frame():
    """The title used to be drawn twice, a thick dark outline then thin white text; OpenCV 5 widens its
    glyphs with the thickness, so the two did not line up ("geobit: 660 correct" read as smudges, a
    ghost "t" after the text) and the frame showed between the letters."""
    frame = _flat_frame()
    picture = draw_matches(frame, frame, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64),
                           title="geobit: 660 correct")
    label = _label_pixels(picture, (200, 60, 0), slice(0, 24))
    ys, xs = np.nonzero(label)
    box = label[ys.min(): ys.max() + 1, xs.min(): xs.max() + 1]
    assert box.all()  # no frame pixel inside the title's box
    assert xs.max() - xs.min() > 100  # the whole title, not a dot


def test_correct_matches_are_drawn_over_wrong_ones_and_a_subset_says_so():
    frame = _flat_frame((90, 90, 90))
    k0 = np.array([[50.0, 120.0], [50.0, 120.0], [60.0, 200.0]])
    k1 = np.array([[100.0, 120.0], [100.0, 120.0], [110.0, 200.0]])
    # keypoint 0 correct and keypoint 1 wrong share one line: the wrong one used to cover it
    picture = draw_matches(frame, frame, k0, k1, np.array([0, 1, -1]), np.array([True, False, False]))
    assert tuple(picture[120, 50]) == CORRECT
    assert tuple(picture[120, 320 + 100]) == CORRECT  # the right frame's keypoint, at its own position
    assert match_key(2, 1, 2, judged=True) == "green: correct, red: wrong"
    assert match_key(1000, 700, 400, judged=True) == "green: correct, red: wrong; 400 of 1000 drawn"
    assert match_key(5, 0, 5, judged=False) == "blue: not judged (no ground truth)"
    assert match_key(0, 0, 0, judged=True) == "no matches"


def test_ring_distances_follow_the_radius():
    """`geofeat demo` printed "rings at 18/37/75 mm" whatever --radius was."""
    patches = _no_patches()
    np.testing.assert_allclose(ring_distances_mm(patches), [18.75, 37.5, 75.0])
    patches.radius = 0.05
    np.testing.assert_allclose(ring_distances_mm(patches, (15, 31, 40)), [25.0, 50.0])


def test_tracking_frames_are_labelled_at_a_legible_size_when_shrunk():
    """The label was drawn on the full frame and then halved with it: 6 px tall text in track.gif."""
    from geofeat.apps.tracking import GRID_SIDE, TrackResult, grid_frames

    colour = (200, 60, 0)
    frame = _flat_frame(colour, (480, 640))

    class Seq:
        def frame(self, name):
            return frame

    g = np.stack(np.meshgrid(np.linspace(200, 400, GRID_SIDE), np.linspace(150, 300, GRID_SIDE)), -1).reshape(-1, 2)
    result = TrackResult("s", "geopatch", (200, 150, 400, 300), ["a", "b"], g, np.stack([g, np.full_like(g, np.nan)]))
    pictures = grid_frames(Seq(), result, scale=0.5)
    assert [p.shape for p in pictures] == [(240, 320, 3)] * 2
    for p in pictures:
        band = p[:40, :, ::-1]  # RGB -> BGR
        white = (band.min(-1) > 180) & (np.ptp(band, axis=-1) < 12)
        rows = np.flatnonzero(white.any(axis=1))
        assert rows.max() - rows.min() + 1 >= 9


def test_matches_without_ground_truth_are_drawn_apart_from_wrong_ones_and_counted(tmp_path):
    """A match whose target keypoint has no ground truth (occluded, off the surface, outside the
    landmarks' hull) was drawn red as wrong; the protocol does not score it. Now blue, counted in the key."""
    from geofeat.groundtruth import GroundTruth, correct_matches, judged_matches
    from geofeat.io import read_sequence
    from test_bad_inputs import make_sequence

    frame = _flat_frame((90, 90, 90))
    k0 = np.array([[50.0, 60.0], [50.0, 120.0], [60.0, 200.0]])
    k1 = np.array([[100.0, 60.0], [100.0, 120.0], [110.0, 200.0]])
    picture = draw_matches(frame, frame, k0, k1, np.array([0, 1, 2]), np.array([True, False, False]),
                           judged=np.array([True, True, False]))
    assert tuple(picture[60, 50]) == CORRECT and tuple(picture[120, 50]) == WRONG
    assert tuple(picture[200, 60]) == UNJUDGED
    assert match_key(3, 1, 3, judged=True, n_unjudged=1) == \
        "green: correct, red: wrong, blue: 1 not judged (no ground truth)"
    assert match_key(3, 1, 3, judged=True, n_unjudged=2) == "green: correct, blue: 2 not judged (no ground truth)"
    # the landmarks' hull: a target keypoint outside it has no ground truth, and its match is not judged
    seq = read_sequence(make_sequence(tmp_path / "seq"))
    truth = GroundTruth(seq, None)
    inside, outside = [80.0, 60.0], [3.0, 3.0]
    tgt = np.array([inside, outside])
    ref = tgt - [3.0, 0.0]  # the target is the reference moved 3 px right
    matches0 = np.array([0, 1])
    assert judged_matches(truth, "frame-001", tgt, matches0).tolist() == [True, False]
    assert correct_matches(truth, "frame-001", ref, tgt, matches0).tolist() == [True, False]
    assert judged_matches(truth, "frame-001", tgt, np.array([-1, 0])).tolist() == [False, True]


def test_report_plots_leave_the_callers_matplotlib_backend_alone(tmp_path):
    """bench's curves, retrieval's Acc@K plot and train's loss plot switched matplotlib to "Agg"
    (matplotlib.use), so a notebook that ran a benchmark lost its inline plots. They now draw on a
    Figure made without pyplot; each writes a PNG."""
    import cv2
    import matplotlib

    from geofeat.apps.retrieval import _plot as plot_retrieval
    from geofeat.bench.report import plot_curves
    from geofeat.train.loop import _plot as plot_training

    before = matplotlib.get_backend()
    matplotlib.use("pdf")  # a backend none of them would pick
    try:
        plot_training({"epoch": [1, 2], "loss": [0.5, 0.4], "val_ms": [0.3, 0.4]}, tmp_path / "train.png")
        plot_retrieval({"geopatch": np.array([0.9, 0.8, 0.7]), "sift": np.array([0.8, 0.7, 0.6])},
                       tmp_path / "acc.png")
        rows = [{"sequence": "rotate-0", "descriptor": "geopatch", "detector": "geokey", "angle_deg": angle,
                 "scale": float("nan"), "ms": ms} for angle, ms in ((10.0, 0.6), (90.0, 0.5))]
        assert [p.name for p in plot_curves(rows, tmp_path)] == ["ms_vs_rotate.png"]
        assert matplotlib.get_backend() == "pdf"
    finally:
        matplotlib.use(before)
    for name in ("train.png", "acc.png", "ms_vs_rotate.png"):
        image = cv2.imread(str(tmp_path / name))
        assert image is not None and image.shape[0] > 100 and image.std() > 5


def test_a_caption_wider_than_a_small_picture_is_wrapped_not_cut_off():
    """On a pair of 160x120 frames the caption ran off the picture's right edge: "... 75 not" and the
    key's counts were lost. Every word is now on the picture, on the label's dark box (in a band above
    the frames, as small frames' captions are: `test_a_small_frames_caption_goes_above_the_picture_not_over_it`)."""
    from geofeat.viz import put_label

    frame = _flat_frame((200, 60, 0), (120, 160))
    title = "geopatch: 500 matches, 250 correct, 75 not judged (no ground truth)"
    picture = draw_matches(frame, frame, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64), title=title)
    # the caption's band spans more than one line's height (it was one ~22 px line, cut at x = 320)
    assert picture.shape[1:] == (320, 3) and picture.shape[0] - 120 > 30
    x0, y0, x1, y1 = put_label(np.zeros((120, 320, 3), np.uint8), title, (4, 4), 0.55)
    assert x1 <= 320 and y1 > 40
    wide = put_label(np.zeros((40, 2000, 3), np.uint8), title, (4, 4), 0.55)
    assert wide[3] < 30  # room for it: one line, as before


def test_large_frames_are_shrunk_with_their_keypoints_to_a_viewable_picture():
    """Two 4000x3000 frames made an 8000x3000 picture (35 MB of PNG) whose 1 px lines and 10 px
    caption vanished when viewed whole. It is now at most `max_width` wide, the keypoints drawn where
    the shrunk frames show them (pixel centres kept), in the legend's colours."""
    big = _flat_frame((90, 90, 90), (3000, 4000))
    small = _flat_frame((90, 90, 90), (1500, 2000))
    k0 = np.array([[1000.0, 500.0], [3000.0, 2500.0]])
    k1 = np.array([[1500.0, 1000.0], [999.5, 1299.5]])  # in the smaller right frame
    picture = draw_matches(big, small, k0, k1, np.array([0, 1]), np.array([True, False]))
    f = MAX_MATCHES_WIDTH / 6000
    w0, h0, w1, h1 = (int(round(n * f)) for n in (4000, 3000, 2000, 1500))
    assert picture.shape == (h0, w0 + w1, 3) and w0 + w1 <= MAX_MATCHES_WIDTH

    def at(x, y, w, h, W, H, dx=0):  # the pixel that shows frame pixel (x, y) of a W x H frame shrunk to w x h
        return tuple(picture[int(round((y + 0.5) * h / H - 0.5)), int(round((x + 0.5) * w / W - 0.5)) + dx])

    assert at(1000, 500, w0, h0, 4000, 3000) == CORRECT and at(3000, 2500, w0, h0, 4000, 3000) == WRONG
    assert at(1500, 1000, w1, h1, 2000, 1500, w0) == CORRECT and at(999.5, 1299.5, w1, h1, 2000, 1500, w0) == WRONG
    # max_width=None: drawn at their own size
    assert draw_matches(small, small, k1, k1, np.array([0, 1]), max_width=None).shape == (1500, 4000, 3)


def test_the_geodesic_support_of_a_huge_frame_is_shrunk_with_its_rings():
    """The demo's patch picture (`draw_geodesic_support`) of a 4096x3072 frame was drawn at full size,
    while match pictures cap their width at `MAX_MATCHES_WIDTH`. It is now shrunk to it too, each
    ring drawn where the shrunk frame shows it."""
    frame = _flat_frame((90, 90, 90), (3072, 4096))
    n, R, A = 1, 32, 64
    radii = 200 + 10 * np.arange(R, dtype=np.float32)[:, None]  # ring 31 at 510 frame pixels
    angles = np.linspace(0, 2 * np.pi, A, endpoint=False)[None, :]
    coords = np.stack([3000 + radii * np.cos(angles), 1500 + radii * np.sin(angles)], -1)[None].astype(np.float32)
    patches = PolarPatches(np.array([[3000.0, 1500.0]]), np.zeros((n, R, A), np.float32), coords, np.ones(n, bool),
                           np.full((n, A), R, np.int32), np.zeros((n, R, A, 3), np.float32), 0.075)
    picture = draw_geodesic_support(frame, patches)
    f = MAX_MATCHES_WIDTH / 4096
    assert picture.shape == (round(3072 * f), MAX_MATCHES_WIDTH, 3)
    outer = np.array([0, 255, 0])  # ring 31's colour, drawn around (3000, 1500) at 510 px, in the shrunk frame
    ys, xs = np.nonzero((np.abs(picture[:, 600:].astype(int) - outer).max(-1) < 60))  # right of the key
    xs = xs + 600
    assert len(xs) and abs((xs.max() + xs.min()) / 2 - 3000 * f) < 3 and abs((ys.max() + ys.min()) / 2 - 1500 * f) < 3
    assert (xs.max() - xs.min()) / 2 == pytest.approx(510 * f, abs=3)
    # max_width=None: drawn at the frame's own size
    assert draw_geodesic_support(frame, patches, max_width=None).shape == (3072, 4096, 3)


def test_the_ground_truth_overlay_of_a_huge_frame_is_shrunk_with_its_landmarks():
    """`geofeat groundtruth`'s <k>_overlay.png of 4096x3072 frames was 8192 pixels wide, while match
    pictures cap their width at `MAX_MATCHES_WIDTH`. Both halves are now shrunk to fit it, the
    landmarks drawn where the shrunk frame shows them."""
    from geofeat.groundtruth.pipeline import _overlay, _Warped
    frame = _flat_frame((90, 90, 90), (3072, 4096))
    ev = _Warped(mask=np.ones((3072, 4096), bool), ssim=np.zeros((3072, 4096), np.float32),
                 warped=np.full((3072, 4096), 0.5, np.float32))
    picture = _overlay(frame, ev, None, np.array([[3000.0, 2000.0]]), np.zeros((0, 2)))
    f = MAX_MATCHES_WIDTH / (2 * 4096)
    assert picture.shape == (round(3072 * f), MAX_MATCHES_WIDTH, 3)
    # the inlier's green circle (the key, in the same colour, is in the top-left corner)
    ys, xs = np.nonzero((picture[200:, : MAX_MATCHES_WIDTH // 2] == (0, 220, 0)).all(-1))
    ys = ys + 200
    assert len(xs) and abs((xs.max() + xs.min()) / 2 - 3000 * f) < 2 and abs((ys.max() + ys.min()) / 2 - 2000 * f) < 2


def test_invalid_keypoints_red_crosses_are_named_in_the_key():
    """The key named red only as the angle-0 ray, while a keypoint without a patch is a red cross:
    it read as a ray. The key now has a line for them when any is drawn (its dark box grows)."""
    frame = _flat_frame((200, 60, 0))
    n, R, A = 2, 32, 8
    coords = np.full((n, R, A, 2), np.nan, np.float32)
    radii = np.arange(1, R + 1, dtype=np.float32)[:, None]
    angles = np.linspace(0, 2 * np.pi, A, endpoint=False)[None, :]
    coords[0, ..., 0], coords[0, ..., 1] = 200 + radii * np.cos(angles), 150 + radii * np.sin(angles)

    def key_height(valid) -> int:
        patches = PolarPatches(np.array([[200.0, 150.0], [250.0, 200.0]]), np.zeros((n, R, A), np.float32), coords,
                               np.asarray(valid), np.zeros((n, A), np.int32), np.zeros((n, R, A, 3), np.float32), 0.075)
        picture = draw_geodesic_support(frame, patches)
        dark = (picture[:, :12] < 40).all(-1).any(axis=1)  # rows of the key's dark boxes, at its left edge
        return int(np.flatnonzero(dark).max())

    assert key_height([True, False]) > key_height([True, True]) + 10


def test_the_contact_sheet_says_what_its_dots_mean(tmp_path):
    """The contact sheet drew filled and hollow dots with no key: its only words were the frame names.
    Its first tile now carries a key, a dark box below its name that the other tiles lack."""
    from geofeat.sim import simulate_sequence
    from geofeat.sim.contact_sheet import contact_sheet

    folder = simulate_sequence(tmp_path / "s", scenario="rotate", n_frames=2, seed=5, width=64, height=48,
                               progress=False, texture="procedural")
    sheet = contact_sheet(folder, tmp_path / "sheet.png", n_tracks=0)
    assert sheet.shape == (480, 320, 3)  # two 320 x 240 tiles, one above the other
    first, second = sheet[:240], sheet[240:]

    def label_rows(tile) -> int:  # rows of the dark (30, 30, 30) label boxes at their left padding
        return int(np.count_nonzero((tile[:, 4:6] == 30).all(-1).all(axis=1)))

    assert label_rows(first) > label_rows(second) + 10


def test_retrieval_rows_name_their_whole_descriptor(tmp_path):
    """top6.png labelled each row with the descriptor's first 12 characters: two trained models,
    "geopatch=run1/x.pt" and "geopatch=run2/x.pt", gave rows with the same label."""
    import cv2
    from types import SimpleNamespace

    from geofeat.apps.retrieval import TOP6_HEADER_PX, _top6_picture

    cv2.imwrite(str(tmp_path / "f-rgb.png"), np.full((48, 64, 3), 128, np.uint8))
    db = SimpleNamespace(folders=[tmp_path] * 2, frames=["f", "f"], classes=["a", "a"])
    found = (np.array([0]), np.array([[1]]))
    _top6_picture(db, {"geopatch=run1/x.pt": found, "geopatch=run2/x.pt": found, "tfeat-sim": found},
                  tmp_path / "top6.png", queries_per=1)
    picture = cv2.imread(str(tmp_path / "top6.png"))
    labels = [picture[TOP6_HEADER_PX + 120 * k: TOP6_HEADER_PX + 120 * (k + 1), :110] for k in range(3)]
    assert not np.array_equal(labels[0], labels[1])
    assert (labels[2] < 128).any()  # a short name is still written


@pytest.mark.parametrize("shape", [(16, 64), (120, 40)])
def test_retrieval_thumbnails_keep_their_frames_aspect_ratio(tmp_path, shape):
    """top6.png squashed every frame to its 160 x 120 (4:3) cells: a 4:1 or a 1:3 frame was drawn
    4:3. Each is now letterboxed into its cell, its aspect ratio kept."""
    import cv2
    from types import SimpleNamespace

    from geofeat.apps.retrieval import TOP6_HEADER_PX, _top6_picture

    cv2.imwrite(str(tmp_path / "f-rgb.png"), np.full((*shape, 3), (90, 200, 200), np.uint8))
    db = SimpleNamespace(folders=[tmp_path] * 2, frames=["f", "f"], classes=["a", "a"])
    _top6_picture(db, {"sift": (np.array([0]), np.array([[1]]))}, tmp_path / "top6.png", queries_per=1)
    picture = cv2.imread(str(tmp_path / "top6.png"))
    for x0 in (110, 270):  # the query's cell and its first result's
        cell = picture[TOP6_HEADER_PX: TOP6_HEADER_PX + 120, x0: x0 + 160]
        ys, xs = np.nonzero((np.abs(cell.astype(int) - (90, 200, 200)).max(-1) < 10))
        width, height = xs.max() - xs.min() + 1, ys.max() - ys.min() + 1
        # the frame's own pixels (the cell's coloured border covers a few along the edges of the cell)
        assert width / height == pytest.approx(shape[1] / shape[0], rel=0.15), (x0, width, height)


@pytest.mark.parametrize("dtype", ["uint16", "float32", ">u2"])
def test_a_16_bit_or_float_colour_frame_is_drawn_in_colour(dtype):
    """RGBDFrame kept a colour copy for display of uint8 images only: a 16-bit or float BGR image was
    drawn grey by every picture (match, demo, track), though its colours were given."""
    from geofeat.viz import to_bgr

    bgr = np.zeros((240, 320, 3), np.uint8)
    bgr[:] = (200, 60, 0)
    image = (bgr.astype(np.uint16) * 257).astype(dtype) if dtype != "float32" else bgr.astype(np.float32) / 255
    K = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
    frame = geofeat.RGBDFrame(image, np.ones((240, 320), np.float32), K)
    np.testing.assert_array_equal(to_bgr(frame), bgr)
    # its gray image is read from the given image, as before
    np.testing.assert_allclose(frame.image, geofeat.RGBDFrame(bgr, frame.depth, K).image, atol=1 / 255)


def test_track_gif_frames_of_large_frames_are_at_most_max_gif_width():
    """track.gif's frames were the frames halved whatever their size: 4000x3000 frames made a GIF of
    2000x1500 frames. They are now at most `MAX_GIF_WIDTH` wide, the grid shrunk with the frame."""
    from geofeat.apps.tracking import GRID_SIDE, TrackResult, grid_frames

    MAX_GIF_WIDTH = 960  # geofeat.apps.tracking.MAX_GIF_WIDTH
    frame = _flat_frame((90, 90, 90), (3000, 4000))

    class Seq:
        def frame(self, name):
            return frame

    g = np.stack(np.meshgrid(np.linspace(1000, 3000, GRID_SIDE), np.linspace(500, 2500, GRID_SIDE)), -1).reshape(-1, 2)
    result = TrackResult("s", "geopatch", (1000, 500, 3000, 2500), ["a", "b"], g, np.stack([g, g]), skipped=["c"])
    result.frames.append("c")
    pictures = grid_frames(Seq(), result)
    f = MAX_GIF_WIDTH / 4000
    assert [p.shape for p in pictures] == [(int(round(3000 * f)), MAX_GIF_WIDTH, 3)] * 3
    green = pictures[1][..., 1].astype(int) - pictures[1][..., 0] > 40  # RGB: the tracked grid's green
    ys, xs = np.nonzero(green[40:])  # below the label
    assert abs(xs.min() - 1000 * f) < 3 and abs(xs.max() - 3000 * f) < 3 and abs(ys.min() + 40 - 500 * f) < 3


def test_a_small_frames_caption_goes_above_the_picture_not_over_it():
    """On 160x120 frames the wrapped caption (title and key) covered most of the top of the match
    picture. A caption that would cover more than `CAPTION_MAX_COVER` of it now sits in a band above
    the frames, which show whole; a large frame's caption stays on the picture as it was."""
    title = "geobit: 812 matches, 412 correct, 12 not judged (no ground truth)"
    frame = _flat_frame((200, 60, 0), (120, 160))
    picture = draw_matches(frame, frame, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64), title=title)
    band = picture.shape[0] - 120
    assert picture.shape[1] == 320 and band > 0
    assert (picture[band:] == (200, 60, 0)).all()  # every pixel of the frames shows
    assert (picture[:band] == 30).all(-1).mean() > 0.5 and (picture[:band] > 128).any()  # the caption, above
    # 640x480 frames: the caption on the frames, the picture their size, as before
    large = _flat_frame((200, 60, 0), (480, 640))
    picture = draw_matches(large, large, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64), title=title)
    assert picture.shape == (480, 1280, 3)
    covered = np.flatnonzero((picture != (200, 60, 0)).any(-1).any(axis=1))
    assert 0 < covered.max() <= 0.25 * 480  # geofeat.viz.CAPTION_MAX_COVER
