"""Geodesic polar patches: geometry on analytic surfaces, isometric invariance, real data, robustness."""

import subprocess
import warnings
import sys

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st, HealthCheck

import geofeat
from geofeat.depth import DepthConfig
from geofeat.io import demo_data_dir, read_landmarks
from surfaces import K_VGA, corresponding_points, plane_frame, sheet_pair

CLEAN = DepthConfig(fill="none", smooth_levels=0)  # noise-free synthetic depth needs no smoothing


def ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a.reshape(len(a), -1).astype(np.float64)
    b = b.reshape(len(b), -1).astype(np.float64)
    a = (a - a.mean(1, keepdims=True)) / a.std(1, keepdims=True)
    b = (b - b.mean(1, keepdims=True)) / b.std(1, keepdims=True)
    return (a * b).mean(1)


@pytest.mark.parametrize("mesh_scale", [1.0, 0.5])
def test_flat_plane_rings_and_angles(mesh_scale):
    frame = plane_frame()
    kps = np.array([[320.0, 240.0], [200.3, 150.7], [451.0, 333.2]])
    P = geofeat.polar_patches(frame, kps, depth_config=DepthConfig(mesh_scale=mesh_scale))
    assert P.valid.all()
    centre = np.stack([(kps[:, 0] - 319.5) / 525, (kps[:, 1] - 239.5) / 525, np.ones(3)], axis=1)
    offsets = P.points.astype(np.float64) - centre[:, None, None, :]
    dist = np.linalg.norm(offsets, axis=-1)  # (N, R, A)
    expected = (np.arange(1, 33) * 0.075 / 32)[None, :, None]
    np.testing.assert_allclose(dist, np.broadcast_to(expected, dist.shape), rtol=0.01)
    # angles: counter-clockwise as displayed (image y points down), column 0 along +x
    angles = np.degrees(np.arctan2(-offsets[..., 1], offsets[..., 0]))
    target = np.arange(32) * 360 / 32
    err = (angles - target[None, None, :] + 180) % 360 - 180
    assert np.abs(err).max() < 1.0
    # the projected sample coordinates agree with the 3D samples
    np.testing.assert_allclose(P.coords[0, 31, 0], [320 + 0.075 * 525, 240], atol=0.05)
    np.testing.assert_allclose(P.coords[0, 31, 8], [320, 240 - 0.075 * 525], atol=0.05)


@pytest.mark.parametrize("depth_config", [CLEAN, DepthConfig()], ids=["clean", "default"])
def test_isometric_bend_keeps_polar_patches(depth_config):
    flat_frame, bent_frame, flat, bent = sheet_pair(bend_radius=0.15)
    xy_flat, xy_bent = corresponding_points(flat, bent, n=100)
    A = geofeat.polar_patches(flat_frame, xy_flat, depth_config=depth_config)
    B = geofeat.polar_patches(bent_frame, xy_bent, depth_config=depth_config)
    assert A.valid.all() and B.valid.all()
    polar = ncc(A.values, B.values)
    assert np.median(polar) >= 0.95
    assert (polar >= 0.9).mean() >= 0.9

    def square(frame, xy, r=20):
        return np.stack([frame.image[int(round(y)) - r:int(round(y)) + r + 1, int(round(x)) - r:int(round(x)) + r + 1]
                         for x, y in xy])

    plain = ncc(square(flat_frame, xy_flat), square(bent_frame, xy_bent))
    assert np.median(plain) < np.median(polar) - 0.15


def _face_ids(mesh):
    ok = mesh.face_ok
    ids0 = np.cumsum(ok[:, :, 0].ravel()).reshape(ok.shape[:2]) - 1
    ids1 = ok[:, :, 0].sum() + np.cumsum(ok[:, :, 1].ravel()).reshape(ok.shape[:2]) - 1
    return ids0, ids1


def test_walk_agrees_with_potpourri3d_tracer():
    pp3d = pytest.importorskip("potpourri3d")
    H, W = 240, 320
    K = np.array([[262.5, 0, 159.5], [0, 262.5, 119.5], [0, 0, 1.0]])
    v, u = np.mgrid[0:H, 0:W]
    depth = (0.9 + 0.05 * np.sin(u / 25.0) * np.cos(v / 30.0) + 0.03 * np.sin(v / 17.0)).astype(np.float32)
    frame = geofeat.RGBDFrame(np.full((H, W), 0.5, np.float32), depth, K)
    cfg = DepthConfig(fill="none", smooth_levels=0, mesh_scale=1.0)
    mesh = geofeat.build_mesh(frame, cfg)
    V, F, _ = mesh.vertices_faces()
    tracer = pp3d.GeodesicTracer(V, F)
    ids0, _ = _face_ids(mesh)
    rng = np.random.default_rng(3)
    n_rings = 320  # fine rings: the first sample lies inside the start face and gives the start direction
    errors = []
    for _ in range(6):
        cx, cy = rng.integers(80, W - 80), rng.integers(80, H - 80)
        fx, fy = 0.3, 0.2  # inside face 0 of the cell
        P = geofeat.polar_patches(frame, np.array([[cx + fx, cy + fy]]), n_angles=8, n_rings=n_rings, mesh=mesh)
        assert P.valid[0]
        a, b, c = mesh.points[cy, cx], mesh.points[cy, cx + 1], mesh.points[cy + 1, cx]
        centre = a + fx * (b - a) + fy * (c - a)
        for k in range(8):
            first = P.points[0, 0, k].astype(np.float64)
            direction = (first - centre) / np.linalg.norm(first - centre) * 0.075
            # vertices_faces orders face 0 as (a, c, b)
            path = tracer.trace_geodesic_from_face(int(ids0[cy, cx]), np.array([1 - fx - fy, fy, fx]), direction)
            errors.append(np.linalg.norm(path[-1] - P.points[0, -1, k]))
    print(f"walk vs potpourri3d: end points differ by up to {max(errors) * 1000:.4f} mm")
    assert max(errors) < 1e-3, f"end points differ by up to {max(errors) * 1000:.2f} mm"


def test_kinect_frame_landmarks_valid_and_deterministic():
    frame = geofeat.read_demo_frame()
    _, xy, _ = read_landmarks(demo_data_dir() / "cloud_1.csv")
    assert len(xy) == 51
    A = geofeat.polar_patches(frame, xy)
    B = geofeat.polar_patches(frame, xy)
    assert A.valid.mean() >= 0.9
    np.testing.assert_array_equal(A.values, B.values)
    np.testing.assert_array_equal(A.coords, B.coords)
    # on the real frame the 75 mm radius is ~40 px at ~0.95 m
    radius_px = np.linalg.norm(A.coords[A.valid, -1] - A.keypoints[A.valid, None, :], axis=-1)
    assert 30 < np.median(radius_px) < 55


def test_invalid_keypoints_are_flagged_not_garbage():
    depth = np.full((120, 160), 1.0, np.float32)
    depth[:, :20] = 0  # missing band along the border
    K = np.array([[131.0, 0, 79.5], [0, 131.0, 59.5], [0, 0, 1.0]])
    frame = geofeat.RGBDFrame(np.random.default_rng(0).random((120, 160)).astype(np.float32), depth, K)
    P = geofeat.polar_patches(frame, np.array([[5.0, 60.0], [0.0, 0.0], [159.0, 119.0], [120.0, 60.0]]),
                              radius=0.02, depth_config=DepthConfig(fill="none", smooth_levels=0, mesh_scale=1.0))
    np.testing.assert_array_equal(P.valid, [False, False, False, True])
    assert np.isnan(P.coords[~P.valid]).all()
    assert (P.values[~P.valid] == 0).all()


def test_rays_stop_at_depth_discontinuities():
    """A step from the object (0.8 m) to the background (1.2 m): rays stay on the object."""
    depth = np.full((240, 320), 1.2, np.float32)
    depth[:, :160] = 0.8
    K = np.array([[262.5, 0, 159.5], [0, 262.5, 119.5], [0, 0, 1.0]])
    frame = geofeat.RGBDFrame(np.full((240, 320), 0.5, np.float32), depth, K)
    P = geofeat.polar_patches(frame, np.array([[150.0, 120.0]]), depth_config=DepthConfig(mesh_scale=1.0, smooth_levels=0))
    assert P.valid[0]
    assert np.nanmax(P.points[0, ..., 2]) < 0.81
    assert P.rings_reached[0].min() < 32  # the rays towards +x ended at the step


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(depth=np.ones((10, 10))), "depth"),
        (dict(depth=np.full((480, 640), np.nan)), "NaN"),
        (dict(depth=-np.ones((480, 640))), "negative"),
        (dict(depth=np.zeros((480, 640))), "every pixel"),
        (dict(depth=np.full((480, 640), 950.0)), "millimetres"),
        (dict(K=np.eye(2)), "K"),
        (dict(K=np.diag([-1.0, 525, 1])), "focal"),
        (dict(K=np.array([[0.82, 0, 0.5], [0, 1.09, 0.5], [0, 0, 1]])), "normalised intrinsics"),  # not pixels
        (dict(image=np.zeros((480, 640, 4))), "image"),
    ],
)
def test_bad_frames_raise_clear_errors(kwargs, match):
    args = dict(image=np.zeros((480, 640), np.float32), depth=np.ones((480, 640), np.float32), K=K_VGA)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        geofeat.RGBDFrame(**args)


def test_bad_keypoints_and_radius():
    frame = plane_frame((120, 160))
    with pytest.raises(ValueError, match="keypoints.*off"):
        geofeat.polar_patches(frame, np.array([[10.0, 10.0], [200.0, 10.0]]))
    with pytest.raises(ValueError, match="keypoints"):
        geofeat.polar_patches(frame, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="keypoints"):
        geofeat.polar_patches(frame, np.array([[np.nan, 1.0]]))
    for centimetres_or_millimetres in (7.5, 75.0):  # the radius is in metres, at most 2 m as for the commands
        with pytest.raises(ValueError, match="radius: .* not a plausible geodesic radius"):
            geofeat.polar_patches(frame, np.array([[10.0, 10.0]]), radius=centimetres_or_millimetres)
    with pytest.raises(ValueError, match="mesh"):
        geofeat.polar_patches(frame, np.array([[10.0, 10.0]]), mesh=geofeat.build_mesh(plane_frame((60, 80))))
    with pytest.raises(ValueError, match="keypoints: the keypoint set is empty"):
        geofeat.polar_patches(frame, np.zeros((0, 2)))


def _distance_to_mesh(mesh, points):
    """Distance (metres) of each (N, 3) point to the nearest existing face around its grid position
    (barycentric tolerance 1e-4: the points are stored as float32)."""
    K = mesh.K
    xm = K[0, 0] * points[:, 0] / points[:, 2] + K[0, 2]
    ym = K[1, 1] * points[:, 1] / points[:, 2] + K[1, 2]
    best = np.full(len(points), np.inf)
    Hc, Wc = mesh.face_ok.shape[:2]
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            x = np.clip(np.floor(xm).astype(int) + dx, 0, Wc - 1)
            y = np.clip(np.floor(ym).astype(int) + dy, 0, Hc - 1)
            P = mesh.points
            for t, corners in ((0, (P[y, x], P[y, x + 1], P[y + 1, x])), (1, (P[y + 1, x + 1], P[y, x + 1], P[y + 1, x]))):
                a, b, c = corners
                n = np.cross(b - a, c - a)
                n /= np.linalg.norm(n, axis=1, keepdims=True)
                off = np.einsum("ij,ij->i", points - a, n)
                q = points - off[:, None] * n
                # barycentric coordinates of q
                v0, v1, v2 = b - a, c - a, q - a
                d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
                d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
                den = d00 * d11 - d01 * d01
                bv = (d11 * d20 - d01 * d21) / den
                bw = (d00 * d21 - d01 * d20) / den
                inside = (bv >= -1e-4) & (bw >= -1e-4) & (bv + bw <= 1 + 1e-4) & mesh.face_ok[y, x, t]
                best = np.where(inside, np.minimum(best, np.abs(off)), best)
    return best


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n_holes=st.integers(0, 6), bumps=st.floats(0.0, 0.2))
def test_random_surfaces_never_crash_and_samples_lie_on_mesh(seed, n_holes, bumps):
    rng = np.random.default_rng(seed)
    H, W = 60, 80
    v, u = np.mgrid[0:H, 0:W]
    depth = 1.0 + bumps * np.sin(u / rng.uniform(3, 20) + rng.uniform(0, 6)) * np.cos(v / rng.uniform(3, 20))
    depth += rng.normal(0, 0.002, depth.shape)
    for _ in range(n_holes):
        y0, x0 = rng.integers(0, H), rng.integers(0, W)
        depth[y0:y0 + rng.integers(1, 25), x0:x0 + rng.integers(1, 25)] = 0
    if not (depth > 0).any():
        depth[0, 0] = 1.0
    K = np.array([[50.0, 0, 39.5], [0, 50.0, 29.5], [0, 0, 1.0]])
    frame = geofeat.RGBDFrame(rng.random((H, W)).astype(np.float32), depth.astype(np.float32), K)
    kps = rng.uniform([-0.5, -0.5], [W - 0.5, H - 0.5], size=(40, 2))
    cfg = DepthConfig(mesh_scale=rng.choice([0.5, 1.0]), smooth_levels=int(rng.integers(0, 2)))
    mesh = geofeat.build_mesh(frame, cfg)
    P = geofeat.polar_patches(frame, kps, radius=0.3, n_angles=16, n_rings=8, mesh=mesh)
    assert P.values.shape == (40, 8, 16) and np.isfinite(P.values).all()
    if P.valid.any():
        pts = P.points[P.valid].reshape(-1, 3).astype(np.float64)
        assert (_distance_to_mesh(mesh, pts) < 1e-5).all()
    # valid exactly when at least half of the directions reach the first ring
    np.testing.assert_array_equal(P.valid, (P.rings_reached >= 1).mean(axis=1) >= 0.5)
    assert np.isnan(P.coords[~P.valid]).all()


def test_full_hd_frame_2048_keypoints_under_2gb():
    code = """
import resource, numpy as np, geofeat
H, W = 1080, 1920
K = np.array([[1050.0, 0, 959.5], [0, 1050.0, 539.5], [0, 0, 1.0]])
v, u = np.mgrid[0:H, 0:W]
depth = (1.0 + 0.05 * np.sin(u / 80.0)).astype(np.float32)
frame = geofeat.RGBDFrame(np.random.default_rng(0).random((H, W)).astype(np.float32), depth, K)
kps = np.random.default_rng(1).uniform([100, 100], [W - 100, H - 100], size=(2048, 2))
P = geofeat.polar_patches(frame, kps)
assert P.valid.mean() > 0.99
# this process's own peak (VmHWM, kB): ru_maxrss would also count the parent's peak, which Linux
# carries across the vfork + exec of subprocess (an xdist worker's memory, not the walk's)
print(next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM:")))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    peak_kb = int(out.stdout.strip().splitlines()[-1])
    assert peak_kb < 2 * 1024 * 1024, f"peak RSS {peak_kb / 1024:.0f} MB"


def test_mesh_cached_on_frame_per_depth_config():
    from geofeat.geodesic.mesh import build_mesh, frame_mesh

    frame = geofeat.read_demo_frame()
    _, kps, visible = read_landmarks(demo_data_dir() / "cloud_1.csv")
    kps = kps[visible]
    first = frame_mesh(frame)
    assert frame_mesh(frame) is first  # a second call on the same frame reuses the mesh
    P = geofeat.polar_patches(frame, kps)
    assert frame_mesh(frame) is first
    # the cached mesh gives exactly the patches of a freshly built one
    Q = geofeat.polar_patches(frame, kps, mesh=build_mesh(frame))
    np.testing.assert_array_equal(P.values, Q.values)
    np.testing.assert_array_equal(P.coords, Q.coords)
    # another depth config has its own mesh; the first one stays cached
    clean = DepthConfig(smooth_levels=0, mesh_scale=1.0)
    other = frame_mesh(frame, clean)
    assert other is not first and other.points.shape[0] == 2 * first.points.shape[0]
    assert frame_mesh(frame) is first and frame_mesh(frame, clean) is other
    # editing the depth in place (a frame is read-only: only after turning that off) invalidates the cache
    frame.depth.flags.writeable = True
    frame.depth[200:260, 300:360] *= 1.1
    edited = frame_mesh(frame)
    assert edited is not first
    assert not np.allclose(edited.points, first.points, equal_nan=True)
    # a different frame object never sees another frame's mesh
    assert frame_mesh(geofeat.read_demo_frame()) is not edited


def test_edge_swap_table_matches_grid_layout():
    from geofeat.geodesic import walk

    np.testing.assert_array_equal(walk._SWAP, walk._swap_table())


def test_the_walk_order_changes_no_result():
    """`walk_polar` walks the keypoints in bands of mesh rows (`walk_order`, for the cache); any order
    gives the same samples, coordinates and rings reached, bit for bit, and an order that is not a
    permutation (which would leave a keypoint's samples unwritten) is refused."""
    from geofeat.geodesic.mesh import build_mesh
    from geofeat.geodesic.polar import walk_starts
    from geofeat.geodesic.walk import MAX_CROSSINGS, walk_order, walk_polar, walk_polar_in_order

    frame = geofeat.read_demo_frame()
    mesh = build_mesh(frame)
    rng = np.random.default_rng(3)
    xy = rng.uniform([0, 0], [frame.shape[1] - 1, frame.shape[0] - 1], size=(300, 2))  # some off the surface
    starts = walk_starts(mesh, xy)
    order = walk_order(starts)
    bands = np.floor(starts[order, 1] / 16)
    assert np.all(np.diff(bands) >= 0) and sorted(order) == list(range(300))
    args = (mesh.points, mesh.face_ok, mesh.normals, *mesh.walk_tables, starts, frame.K, 0.05, 16, 8, MAX_CROSSINGS)
    reference = walk_polar(*args)
    assert np.isnan(reference[0]).any() and np.isfinite(reference[0]).any()
    for permutation in (np.arange(300), rng.permutation(300), np.arange(300)[::-1].copy()):
        for got, want in zip(walk_polar_in_order(*args, permutation), reference):
            np.testing.assert_array_equal(got, want)
    for bad in (np.zeros(300, np.int64), np.arange(299), np.arange(1, 301)):
        with pytest.raises(ValueError, match="permutation"):
            walk_polar_in_order(*args, bad)


def test_extract_prefetches_the_mesh_with_identical_results():
    """`extract` builds the mesh in a background thread during detection: the descriptors equal
    those of the serial path (detect, then describe) on a fresh copy of the frame, bit for bit,
    and the mesh the thread built is the one cached on the frame."""
    import geofeat
    from geofeat.descriptors.geobit import GeoBit
    from geofeat.frame import RGBDFrame
    from geofeat.geodesic.mesh import _CACHE_ATTR
    from geofeat.keypoints import detect

    demo = geofeat.read_demo_frame()

    def fresh():
        return RGBDFrame(demo.color if demo.color is not None else demo.image, demo.depth.copy(), demo.K)

    frame = fresh()
    got = geofeat.extract(frame, n=150, detector="sift", descriptor="geobit")
    assert any(isinstance(v, tuple) and hasattr(v[1], "walk_tables") for v in getattr(frame, _CACHE_ATTR).values())
    serial = fresh()
    want = GeoBit().compute(serial, detect(serial, 150, detector="sift"))
    assert np.array_equal(got.keypoints, want.keypoints)
    assert np.array_equal(got.valid, want.valid)
    assert np.array_equal(got.descriptors, want.descriptors)
    # a descriptor without geodesic patches prefetches nothing
    plain = fresh()
    geofeat.extract(plain, n=50, detector="sift", descriptor="orb")
    assert not getattr(plain, _CACHE_ATTR, {})


def test_rotated90_takes_integer_quarter_turns_only():
    frame = plane_frame((120, 160))
    assert frame.rotated90(np.int64(-3)).shape == frame.rotated90(1).shape == (160, 120)
    for k in (1.5, 1.0, "1", None, True):  # 1.5 used to rotate by 270 degrees without a word
        with pytest.raises(TypeError, match="k: expected an integer"):
            frame.rotated90(k)



def test_rotated90_keeps_or_refuses_the_skew():
    """The skew K[0, 1] was dropped: the rotated frame had another camera. A half turn keeps it; a
    quarter turn would move it to K[1, 0], which a camera matrix here never has (and was ignored)."""
    K = K_VGA.copy()
    K[0, 1] = 2.0
    K[0, 2], K[1, 2] = 79.5, 59.5  # the principal point of a 160 x 120 image
    frame = geofeat.RGBDFrame(np.zeros((120, 160), np.uint8), np.ones((120, 160)), K)
    assert frame.rotated90(2).K[0, 1] == 2.0
    for k in (1, 3, -1):
        with pytest.raises(ValueError, match="K: rotated90 .* needs no skew"):
            frame.rotated90(k)
    K = K_VGA.copy()
    K[1, 0] = 2.0
    with pytest.raises(ValueError, match=r"K: expected \[\[fx, s, cx\], \[0, fy, cy\], \[0, 0, 1\]\], got K\[1, 0\] = 2"):
        geofeat.RGBDFrame(np.zeros((120, 160), np.uint8), np.ones((120, 160)), K)

def test_images_of_other_kinds_are_refused_by_name():
    depth = np.ones((120, 160), np.float32)
    with pytest.raises(TypeError, match="image: .*complex128"):  # was cast to its real part with a warning
        geofeat.RGBDFrame(np.zeros((120, 160), complex), depth, K_VGA)
    with pytest.raises(ValueError, match="image: empty"):  # was numpy's "zero-size array to reduction"
        geofeat.RGBDFrame(np.zeros((0, 0), np.float32), np.zeros((0, 0), np.float32), K_VGA)
    with pytest.raises(ValueError, match=r"image: int64 images must lie in \[0, 1\].*uint8"):  # not "float images"
        geofeat.RGBDFrame(np.full((120, 160), 200, np.int64), depth, K_VGA)


@pytest.mark.parametrize("kwargs, name", [
    (dict(n_angles=16.5), "n_angles"),  # gave 16 columns without a word
    (dict(n_rings=8.7), "n_rings"),
    (dict(n_angles=True), "n_angles"),
    (dict(radius="0.05"), "radius"),  # numpy's "ufunc 'isfinite' not supported"
    (dict(radius=None), "radius"),
    (dict(blur_px=float("nan")), "blur_px"),  # an OpenCV assertion
    (dict(blur_px=1e6), "blur_px"),  # ran out of memory
    (dict(blur_px=-1.0), "blur_px"),
])
def test_patch_sizes_are_integers_and_the_radius_a_number(kwargs, name):
    frame = plane_frame((120, 160))
    with pytest.raises(ValueError, match=f"^{name}: "):
        geofeat.polar_patches(frame, np.array([[80.0, 60.0]]), depth_config=CLEAN, **kwargs)


def test_numpy_scalars_are_patch_sizes_and_radii():
    frame = plane_frame((120, 160))
    p = geofeat.polar_patches(frame, np.array([[80.0, 60.0]]), radius=np.float32(0.02), n_angles=np.int64(8),
                              n_rings=4, depth_config=CLEAN)
    assert p.values.shape == (1, 4, 8) and p.valid.all()


@pytest.mark.parametrize("name", ["geobit", "geopatch"])
def test_descriptors_refuse_patches_of_other_keypoints(name):
    frame = plane_frame((120, 160))
    kp = np.array([[60.0, 50.0], [80.0, 60.0], [100.0, 70.0]])
    describer = geofeat.make_descriptor(name, radius=0.02, depth_config=CLEAN)
    patches = geofeat.polar_patches(frame, kp, radius=0.02, depth_config=CLEAN)
    assert np.array_equal(describer.compute(frame, kp, patches=patches).keypoints, kp)
    with pytest.raises(ValueError, match="patches: computed for other keypoints"):  # the same count, reversed
        describer.compute(frame, kp[::-1], patches=patches)
    with pytest.raises(TypeError, match="patches: expected PolarPatches"):
        describer.compute(frame, kp[:1], patches="x")


@pytest.mark.parametrize("name", ["geobit", "geopatch"])
def test_descriptors_refuse_patches_of_another_radius(name):
    """Patches of 0.03 m given to a descriptor of radius 0.02 m were described without a word (the
    descriptor's radius ignored)."""
    frame = plane_frame((120, 160))
    kp = np.array([[60.0, 50.0], [80.0, 60.0]])
    describer = geofeat.make_descriptor(name, radius=0.02, depth_config=CLEAN)
    with pytest.raises(ValueError, match="patches: computed with radius 0.03 m, but the descriptor's radius is 0.02"):
        describer.compute(frame, kp, patches=geofeat.polar_patches(frame, kp, radius=0.03, depth_config=CLEAN))
    same = geofeat.polar_patches(frame, kp, radius=np.float32(0.02), depth_config=CLEAN)  # float32: the same radius
    assert describer.compute(frame, kp, patches=same).valid.all()


def test_sample_bilinear_refuses_colour_and_integer_images():
    from geofeat.geodesic.polar import sample_bilinear

    coords = np.array([[1.0, 2.0], [3.0, 1.0]])
    gray = np.arange(20, dtype=np.float32).reshape(4, 5) / 20
    np.testing.assert_allclose(sample_bilinear(gray, coords), [gray[2, 1], gray[1, 3]])
    # a colour image used to give its first point's three channels as the two samples
    with pytest.raises(ValueError, match="image"):
        sample_bilinear(np.dstack([gray] * 3), coords)
    with pytest.raises(ValueError, match="image"):  # uint8: came back in 0..255, rounded
        sample_bilinear((gray * 255).astype(np.uint8), coords)


def test_frame_keeps_its_own_intrinsics():
    K = K_VGA.copy()
    frame = geofeat.RGBDFrame(np.full((480, 640), 0.5, np.float32), np.ones((480, 640), np.float32), K)
    K[0, 2] += 50.0  # the caller reuses its array (e.g. for the next camera): the frame must not move
    assert frame.K[0, 2] == K_VGA[0, 2]
    assert not np.shares_memory(frame.K, K)


@pytest.mark.parametrize("edit, match", [(np.nan, "NaN"), (-1.0, "negative"), ("mm", "millimetres")])
def test_depth_edited_in_place_is_checked_again_before_a_mesh_is_built(edit, match):
    frame = plane_frame()
    kp = np.array([[320.0, 240.0]])
    assert geofeat.polar_patches(frame, kp, depth_config=CLEAN).valid.all()
    frame.depth.flags.writeable = True  # a frame is read-only: edited in place only after turning that off
    if edit == "mm":
        frame.depth[:] *= 1000.0  # was silently a surface 1000 times too large: the rays left it
    else:
        frame.depth[100:120, 100:120] = edit
    with pytest.raises(ValueError, match=match):
        geofeat.polar_patches(frame, kp, depth_config=CLEAN)


def test_depth_nearer_than_a_camera_sees_is_warned_of():
    """Metres divided by 1000 again (a median of 1 mm) made a frame on which every patch left the surface:
    `extract` returned features that were all invalid, without a word. Close but plausible depth does not warn."""
    from geofeat.inputs import DepthUnitsWarning

    image = np.full((120, 160), 0.5, np.float32)
    with pytest.warns(DepthUnitsWarning, match=r"depth: median 0\.001 m is nearer than"):
        geofeat.RGBDFrame(image, np.full((120, 160), 0.001, np.float32), K_VGA / [[4], [4], [1]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        geofeat.RGBDFrame(image, np.full((120, 160), 0.06, np.float32), K_VGA / [[4], [4], [1]])


def test_rotated90_turns_the_frames_own_gray_image():
    """A frame with a colour image was rotated from that colour image: a frame from `with_image`
    (a filtered gray image, the colour kept for display) came back with the unfiltered gray image,
    so the 'same frame rolled' was another image, even for k = 0 or 4."""
    rng = np.random.default_rng(0)
    colour = (rng.random((60, 80, 3)) * 255).astype(np.uint8)
    K = np.array([[80.0, 0, 39.5], [0, 80.0, 29.5], [0, 0, 1]])
    frame = geofeat.RGBDFrame(colour, np.ones((60, 80), np.float32), K)
    filtered = frame.with_image(np.clip(frame.image * 0.5 + 0.2, 0, 1))
    for k in range(-1, 5):
        turned = filtered.rotated90(k)
        np.testing.assert_array_equal(turned.image, np.rot90(filtered.image, k))
        np.testing.assert_array_equal(turned.color, np.rot90(colour, k))
        assert turned.image.flags.c_contiguous and not np.shares_memory(turned.image, filtered.image)
        np.testing.assert_array_equal(frame.rotated90(k).image, np.rot90(frame.image, k))


def test_a_keypoint_on_the_last_pixel_column_or_row_keeps_half_its_patch_as_on_the_first():
    """The walk's start offset (+1.3e-6, +0.7e-6 mesh pixels, off vertices and edges) pushed a keypoint on
    the grid's last vertex column or row off the grid: no surface, invalid, while the mirror keypoint on
    the first column or row kept the half of its patch on the surface (17 of 32 directions)."""
    H, W = 120, 160
    K = np.array([[150.0, 0, (W - 1) / 2], [0, 150.0, (H - 1) / 2], [0, 0, 1]])
    image = np.random.default_rng(0).random((H, W)).astype(np.float32)
    frame = geofeat.RGBDFrame(image, np.full((H, W), 0.8, np.float32), K)  # a plane facing the camera
    kps = np.array([[0, 60], [W - 1, 60], [80, 0], [80, H - 1]], float)
    p = geofeat.polar_patches(frame, kps, depth_config="clean", radius=0.01)  # mesh at full resolution
    reaching = (p.rings_reached >= 1).sum(axis=1)
    assert p.valid.all() and reaching[0] == reaching[1] and reaching[2] == reaching[3] and reaching[0] >= 16


# ---------------------------------------------------------------- patches whose rays did not walk
@pytest.mark.parametrize("shape", [(1, 1), (1, 640), (640, 1)])
def test_a_frame_one_pixel_high_or_wide_has_no_surface_and_no_valid_patch(shape):
    """The depth smoothing's smallest mesh (2 x 2 vertices, one cell) stretched a single row of depth
    into a surface: on a 1 x 1 frame every ray walked all 32 rings on it and GeoBit called the patch
    valid; on a 1 x 640 frame with a short focal length the rays crossed the made-up strip to the first
    ring. One row or column of depth holds no surface: its mesh has no face, and no patch is valid,
    whatever the focal length, for the walk, the heat method and both geodesic descriptors."""
    from geofeat.geodesic.mesh import build_mesh

    H, W = shape
    xy = np.array([[(W - 1) / 2, (H - 1) / 2], [0.0, 0.0]])
    for focal in (0.1, 0.9, 20.0):  # times the longer side: the plausible range (`check_focal_lengths`)
        f = focal * max(H, W)
        K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]])
        frame = geofeat.RGBDFrame(np.full(shape, 0.5, np.float32), np.ones(shape, np.float32), K)
        for config in ("kinect", "clean"):
            assert not build_mesh(frame, config).face_ok.any()
            patches = geofeat.polar_patches(frame, xy, depth_config=config)
            assert not patches.valid.any() and not patches.rings_reached.any()
            assert not geofeat.heat_polar_patches(frame, xy, depth_config=config).valid.any()
        with pytest.warns(UserWarning, match="pixels high or wide"):
            assert not geofeat.GeoBit().compute(frame, xy).valid.any()


@pytest.mark.parametrize("name", ["geobit", "geopatch"])
def test_descriptors_refuse_patches_marked_valid_whose_rays_did_not_walk(name):
    """A descriptor took `patches.valid` as it came: patches marked valid whose rays reached no ring
    (no surface under them, or leaving it at once) were described. Validity is `patch_validity` of the
    rings reached, and a patch marked valid against it is refused, naming it."""
    frame = plane_frame((120, 160))
    xy = np.array([[60.0, 50.0], [80.0, 60.0]])
    describer = geofeat.make_descriptor(name, radius=0.02, depth_config=CLEAN)
    patches = geofeat.polar_patches(frame, xy, radius=0.02, depth_config=CLEAN)
    assert describer.compute(frame, xy, patches=patches).valid.all()
    patches.rings_reached[1, :20] = 0  # 20 of 32 directions leave the surface at once
    with pytest.raises(ValueError, match=r"patches: 1 marked valid \(e.g. #1\) whose rays reach the first ring"):
        describer.compute(frame, xy, patches=patches)
    patches.valid[1] = False  # marked invalid, as `patch_validity` says: described as invalid
    assert describer.compute(frame, xy, patches=patches).valid.tolist() == [True, False]


# ---------------------------------------------------------------- patches of other settings
@pytest.mark.parametrize("name", ["geobit", "geopatch"])
def test_descriptors_refuse_patches_of_another_blur_or_depth_config(name):
    """`PolarPatches` recorded their frame and radius, not the sampling blur or the depth config of the
    mesh their rays walked on: patches sampled with blur_px=2, or walked on a "kinect" mesh, were
    described by a descriptor set to blur 1 px on a "clean" mesh without a word (and so was a mesh of
    another depth config given as `mesh=`). Both settings are recorded and a mismatch is refused,
    naming both; the same settings however given (a profile name, an equal DepthConfig, "auto" and
    the profile it picks on the frame, a float32 blur) pass."""
    from geofeat.geodesic.mesh import build_mesh

    frame = plane_frame((120, 160))
    xy = np.array([[60.0, 50.0], [80.0, 60.0]])
    describer = geofeat.make_descriptor(name, radius=0.02, depth_config="clean")
    blurred = geofeat.polar_patches(frame, xy, radius=0.02, depth_config="clean", blur_px=2.0)
    assert blurred.blur_px == 2.0 and blurred.depth_config == geofeat.depth.PROFILES["clean"]
    with pytest.raises(ValueError, match="patches: sampled with blur_px=2, but the descriptor's blur_px is 1"):
        describer.compute(frame, xy, patches=blurred)
    with pytest.raises(ValueError, match="patches: walked on a mesh built with depth config 'kinect', but the "
                                         "descriptor's depth_config is 'clean'"):
        describer.compute(frame, xy, patches=geofeat.polar_patches(frame, xy, radius=0.02, depth_config="kinect"))
    with pytest.raises(ValueError, match="mesh: built with depth config 'kinect', but the descriptor's depth_config "
                                         "is 'clean'"):
        describer.compute(frame, xy, mesh=build_mesh(frame, "kinect"))
    same = geofeat.polar_patches(frame, xy, radius=0.02, depth_config=DepthConfig(smooth_levels=0, mesh_scale=1.0),
                                 blur_px=np.float32(1.0))
    assert describer.compute(frame, xy, patches=same) == describer.compute(frame, xy)
    assert describer.compute(frame, xy, mesh=build_mesh(frame, "clean")) == describer.compute(frame, xy)
    auto = geofeat.make_descriptor(name, radius=0.02)  # depth_config "auto": the profile it picks on the frame
    picked = geofeat.depth_profile(frame)
    own = geofeat.polar_patches(frame, xy, radius=0.02, depth_config=picked)
    assert auto.compute(frame, xy, patches=own) == auto.compute(frame, xy)
    other = "clean" if picked != "clean" else "kinect"
    with pytest.raises(ValueError, match=rf"depth_config is 'auto' \('{picked}' on this frame\)"):
        auto.compute(frame, xy, patches=geofeat.polar_patches(frame, xy, radius=0.02, depth_config=other))


def test_the_describer_shares_one_set_of_patches_of_its_own_settings():
    """`Describer` builds one set of polar patches for every geodesic descriptor; they are of the
    descriptors' own blur and depth config, so the check passes and the results equal each
    descriptor's own."""
    from geofeat.descriptors.describer import Describer

    frame = plane_frame((120, 160))
    keypoints = geofeat.as_keypoints(np.array([[60.0, 50.0], [80.0, 60.0]]))
    shared = Describer(("geobit", "geopatch", "orb"), 0.02, "clean")(frame, keypoints)
    for name in ("geobit", "geopatch"):
        own = geofeat.make_descriptor(name, radius=0.02, depth_config="clean").compute(frame, keypoints)
        assert shared[name][0] == own
