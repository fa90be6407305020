"""Heat-method geodesics: operators, accuracy on analytic surfaces, agreement with the walk.

Frames are 320x240 with f = 525 px (a 1 m plane spans 0.61 x 0.46 m) and the default 0.5 mesh
scale, so one mesh pixel is 3.8 mm at 1 m and the 75 mm patch radius is about 20 mesh pixels.
"""


import numpy as np
import potpourri3d as pp3d
import pytest
import scipy.sparse as sp

import geofeat
import geofeat.geodesic.heat as heat
from geofeat.depth import DepthConfig
from geofeat.geodesic.heat import HeatGeodesics, heat_polar_patches
from surfaces import Sheet, sheet_texture

K_QVGA = np.array([[525.0, 0.0, 159.5], [0.0, 525.0, 119.5], [0.0, 0.0, 1.0]])
CLEAN = DepthConfig(fill="none", smooth_levels=0)  # analytic depth needs no smoothing
SHAPE = (240, 320)


@pytest.fixture(scope="module")
def texture():
    return sheet_texture(0, size_px=800, mm_per_px=1.0)


def sheet(texture, bend_radius=None):
    s = Sheet(bend_radius=bend_radius, K=K_QVGA.copy(), shape=SHAPE)
    frame = s.render(*texture)
    return s, frame, geofeat.build_mesh(frame, CLEAN)


def source_point(mesh, xy_mesh):
    """3D point of the mesh under mesh pixel (x, y) (linear in its face)."""
    _, _, _, w, corners, ok = heat._locate(np.asarray([xy_mesh], float), mesh.face_ok)
    assert ok[0]
    return (mesh.points[corners[0, :, 1], corners[0, :, 0]] * w[0][:, None]).sum(0)


def cylinder_geodesic(s: Sheet, P, p0):
    """Exact geodesic distance on the bent sheet's cylinder between points P (..., 3) and p0 (3,)."""
    zc = s.z0 + s.bend_radius
    th = np.arctan2(P[..., 0], zc - P[..., 2])
    th0 = np.arctan2(p0[0], zc - p0[2])
    return np.hypot(s.bend_radius * (th - th0), P[..., 1] - p0[1]), th - th0


def test_operators_are_the_cotan_laplacian(texture):
    _, _, mesh = sheet(texture, 0.2)
    H = HeatGeodesics(mesh)
    # the cotan Laplacian is the P1 stiffness matrix G^T A G, symmetric with zero row sums
    A = sp.diags(np.repeat(H.area, 3))
    assert abs(H.G.T @ A @ H.G - H.L).max() < 1e-12 * abs(H.L).max()
    assert abs(H.L - H.L.T).max() == 0
    assert np.abs(np.asarray(H.L.sum(axis=1))).max() < 1e-12
    assert abs(pp3d.cotan_laplacian(H.V, H.F) - H.L).max() < 1e-12
    np.testing.assert_allclose(H.M.sum(), H.area.sum())
    assert H.t == pytest.approx(H.mean_edge**2)


def test_matches_potpourri3d_heat_method(texture):
    """Same heat time, Neumann boundary, distance pinned to 0 at a vertex source: potpourri3d's
    independent implementation agrees to 0.18 mm (measured) over a 0.4 m range."""
    _, _, mesh = sheet(texture, 0.2)
    H = HeatGeodesics(mesh, boundary_mix=0.0, calibrate=False)
    Wm = mesh.points.shape[1]
    ours = H.distance(60 * Wm + 80)
    v = H.index[60, 80]
    ref = pp3d.MeshHeatMethodDistanceSolver(H.V, H.F, t_coef=1.0, use_robust=False).compute_distance(v)
    on = H.index >= 0
    assert np.isnan(ours[~on]).all()
    assert np.nanmax(np.abs(ours[on] - ref[H.index[on]])) < 0.5e-3


def test_plane_distance_is_euclidean(texture):
    """Fronto-parallel plane: measured relative error of the heat distance, 2-10 cm from a
    sub-pixel source: mean |error| 1.2 % (the heat method runs short: mean -0.9 %), max 3.6 %
    (anisotropy of the grid triangulation). Tolerances: 1.5 % mean, 4.5 % max."""
    _, _, mesh = sheet(texture)
    H = HeatGeodesics(mesh)
    src = (80.3, 60.6)
    D = H.distance(src)
    E = np.linalg.norm(mesh.points - source_point(mesh, src), axis=-1)
    near = (E > 0.02) & (E < 0.10)
    rel = np.abs(D[near] - E[near]) / E[near]
    assert rel.mean() < 0.015 and rel.max() < 0.045
    assert 0 <= np.nanmin(D) < 1.0 / 262.5  # nearest vertex 1.9 mm away, nothing negative
    # a sub-pixel shift of the source by half a mesh pixel moves far distances by half an edge
    # (1.9 mm; measured 1.5 to 1.8 mm; rounding the source would give 0 or 3.8 mm)
    D2 = H.distance((80.8, 60.6))
    right = near & (mesh.points[..., 0] - mesh.points[60, 80, 0] > 0.05) & (np.abs(mesh.points[..., 1]) < 0.01)
    shift = (D - D2)[right]
    assert right.sum() > 50 and np.abs(shift - 0.5 * 1.0 / 262.5).max() < 0.5e-3


def test_cylinder_distance_is_geodesic_not_chord(texture):
    """Cylinder of radius 0.1 m, source 0.6 rad off the line of sight; targets more than 1 rad
    around the axis from it. Measured mean relative error: heat 2.4 % (max 3.3 %), Euclidean
    chord 7.5 % (min 3.5 %)."""
    s, _, mesh = sheet(texture, 0.1)
    H = HeatGeodesics(mesh)
    src = mesh.image_to_mesh(s.project(np.array([-0.06]), np.array([0.0])))[0]
    D = H.distance(src)
    p0 = source_point(mesh, src)
    G, dth = cylinder_geodesic(s, mesh.points, p0)
    E = np.linalg.norm(mesh.points - p0, axis=-1)
    far = (dth > 1.0) & np.isfinite(D) & (np.abs(mesh.points[..., 1] - p0[1]) < 0.05)
    assert far.sum() > 100
    heat_err = np.abs(D[far] - G[far]) / G[far]
    chord_err = np.abs(E[far] - G[far]) / G[far]
    assert heat_err.mean() < 0.035
    assert heat_err.mean() < chord_err.mean() / 2.5


def test_patches_agree_with_walk_on_plane(texture):
    """Measured sample-coordinate disagreement with `geofeat.polar_patches`: mean 0.28 px,
    max 1.1 px (full-resolution image pixels)."""
    _, frame, mesh = sheet(texture)
    kps = np.array([[160.2, 120.7], [130.4, 100.3], [190.6, 140.1], [100.0, 120.0]])
    walk = geofeat.polar_patches(frame, kps, mesh=mesh)
    hp = heat_polar_patches(frame, kps, mesh=mesh)
    assert isinstance(hp, geofeat.PolarPatches)
    assert hp.values.shape == (4, 32, 32) and hp.coords.shape == (4, 32, 32, 2) and hp.points.shape == (4, 32, 32, 3)
    assert hp.valid.all() and (hp.rings_reached == 32).all()
    d = np.linalg.norm(walk.coords - hp.coords, axis=-1)
    assert d.mean() < 0.5 and d.max() < 1.5
    # ring radii on the plane: 3D distance from the keypoint = (i + 1) * radius / n_rings
    centre = np.stack([(kps[:, 0] - 159.5) / 525, (kps[:, 1] - 119.5) / 525, np.ones(4)], axis=1)
    r = np.linalg.norm(hp.points - centre[:, None, None], axis=-1)[:, 7:]
    expected = (np.arange(8, 33) * 0.075 / 32)[None, :, None]
    assert np.abs(r / expected - 1).mean() < 0.015
    # intensities come from the same image at nearly the same places
    assert np.corrcoef(walk.values.ravel(), hp.values.ravel())[0, 1] > 0.97


def test_patches_agree_with_walk_on_cylinder(texture):
    """Cylinder of radius 0.2 m. Measured disagreement with the walk: mean 0.38 px, 95th
    percentile 1.1 px, max 2.7 px (outer rings of oblique directions, where a geodesic helix
    is not a straight image line). GeoBit's image-plane angles are far worse (max 7.4 px)."""
    s, frame, mesh = sheet(texture, 0.2)
    kps = np.array([[160.2, 120.7], [130.4, 100.3], [190.6, 140.1], [100.0, 120.0]])
    walk = geofeat.polar_patches(frame, kps, mesh=mesh)
    hp = heat_polar_patches(frame, kps, mesh=mesh)
    assert walk.valid.all() and hp.valid.all()
    d = np.linalg.norm(walk.coords - hp.coords, axis=-1)
    assert d.mean() < 0.6 and np.percentile(d, 95) < 1.5 and d.max() < 3.5
    image = heat_polar_patches(frame, kps, mesh=mesh, angles="image")
    assert np.linalg.norm(walk.coords - image.coords, axis=-1).max() > 2 * d.max()
    # outer rings lie at the right geodesic distance (analytic), within 3 %
    p0 = source_point(mesh, mesh.image_to_mesh(kps[:1])[0])
    G, _ = cylinder_geodesic(s, hp.points[0, 7:].astype(np.float64), p0)
    expected = (np.arange(8, 33) * 0.075 / 32)[:, None]
    assert np.abs(G / expected - 1).max() < 0.03


def test_invalid_keypoints_and_leaving_the_mesh(texture):
    _, frame, _ = sheet(texture)
    depth = frame.depth.copy()
    depth[100:140, 200:260] = 0.0  # a big hole (kept by CLEAN: no filling)
    frame = geofeat.RGBDFrame(frame.image, depth, frame.K)
    mesh = geofeat.build_mesh(frame, CLEAN)
    kps = np.array([[230.0, 120.0], [0.2, 100.0], [160.2, 120.7], [185.0, 120.3]])
    walk = geofeat.polar_patches(frame, kps, mesh=mesh)
    hp = heat_polar_patches(frame, kps, mesh=mesh)
    # in the hole, on the image border: invalid, like the walk
    np.testing.assert_array_equal(hp.valid, [False, False, True, True])
    np.testing.assert_array_equal(hp.valid, walk.valid)
    assert np.isnan(hp.coords[~hp.valid]).all() and (hp.values[~hp.valid] == 0).all()
    # next to the hole: lines towards it stop early, like the walk's rays, and repeat their
    # last point on the mesh in the remaining rings
    reached = hp.rings_reached[3]
    assert reached.min() < 32 and reached.max() == 32
    assert np.abs(reached.astype(int) - walk.rings_reached[3]).max() <= 1
    a = int(np.argmin(reached))
    tail = hp.coords[3, reached[a]:, a]
    assert (tail == tail[0]).all() and tail[0, 0] < 200.5  # stops before the hole at x = 200
    assert np.isfinite(hp.points[3]).all()


def test_factorisation_is_reused(texture, monkeypatch):
    _, frame, mesh = sheet(texture, 0.2)
    calls = []
    real = heat.splu
    monkeypatch.setattr(heat, "splu", lambda *a, **k: calls.append(1) or real(*a, **k))
    H = HeatGeodesics(mesh)
    assert len(calls) == 3  # Neumann heat, Dirichlet heat, Poisson
    for src in [(80.3, 60.6), (60.2, 50.1), (100.7, 70.4)]:
        H.distance(src)
    kps = np.random.default_rng(0).uniform([60, 60], [260, 180], (20, 2))
    heat_polar_patches(frame, kps, solver=H)
    assert len(calls) == 3  # no new factorisation for 3 + 20 sources (timing: benchmarks/bench_heat.py)


def test_arguments(texture):
    _, frame, mesh = sheet(texture)
    with pytest.raises(ValueError, match="empty"):
        heat_polar_patches(frame, np.zeros((0, 2)), mesh=mesh)
    with pytest.raises(ValueError, match="radius"):
        heat_polar_patches(frame, [[100.0, 100.0]], radius=75.0, mesh=mesh)
    with pytest.raises(ValueError, match="angles"):
        heat_polar_patches(frame, [[100.0, 100.0]], mesh=mesh, angles="polar")
    with pytest.raises(ValueError, match="off the"):
        heat_polar_patches(frame, [[1000.0, 100.0]], mesh=mesh)
    with pytest.raises(ValueError, match="boundary_mix"):
        HeatGeodesics(mesh, boundary_mix=2.0)
    H = HeatGeodesics(mesh)
    assert np.isnan(H.distance((-5.0, 3.0))).all()
    # t is a time in m^2: potpourri3d's t_coef = 1.0 passed as t = 1.0 would silently smooth everything
    with pytest.warns(UserWarning, match="t_coef"):
        HeatGeodesics(mesh, t=1.0)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        HeatGeodesics(mesh, t=10 * H.mean_edge**2)  # a deliberate, plausible choice: no warning


@pytest.mark.parametrize("option, value, message", [
    ("calibrate", "no", r"calibrate: expected True or False, got 'no'"),  # truthy: it calibrated
    ("calibrate", 0, r"calibrate: expected True or False, got 0"),
    ("boundary_mix", "0.5", r"boundary_mix: expected a number in \[0, 1\], got '0.5'"),  # a raw TypeError
    ("boundary_mix", None, r"boundary_mix: expected a number in \[0, 1\], got None"),
    ("boundary_mix", True, r"boundary_mix: expected a number in \[0, 1\], got True"),
    ("boundary_mix", float("nan"), r"boundary_mix: expected a number in \[0, 1\], got nan"),
    ("t", "1e-5", r"t \(heat time, m\^2\): expected a positive number, got '1e-5'"),  # read as a number
    ("t", True, r"t \(heat time, m\^2\): expected a positive number, got True"),
])
def test_heat_options_of_the_wrong_kind_are_refused_by_name(option, value, message):
    """HeatGeodesics(calibrate="no") calibrated (a non-empty string is truthy); boundary_mix="0.5" or
    None failed with Python's TypeError, naming no argument."""
    from surfaces import plane_frame

    mesh = geofeat.build_mesh(plane_frame((48, 64)), CLEAN)
    with pytest.raises(ValueError, match=message):
        HeatGeodesics(mesh, **{option: value})
    solver = HeatGeodesics(mesh, boundary_mix=np.float32(0.25), calibrate=np.bool_(False))  # numpy's kinds are fine
    assert (solver.boundary_mix, solver.calibrate) == (0.25, False) and type(solver.calibrate) is bool


def test_a_mesh_of_another_frame_size_is_refused():
    from surfaces import plane_frame

    frame = plane_frame((120, 160))
    other = geofeat.build_mesh(frame.rotated90(1), DepthConfig(fill="none", smooth_levels=0))
    with pytest.raises(ValueError, match="mesh: built for a"):  # gave patches of the other frame's surface
        heat_polar_patches(frame, [[80.0, 60.0]], radius=0.02, mesh=other)
    with pytest.raises(ValueError, match="mesh: built for a"):
        heat_polar_patches(frame, [[80.0, 60.0]], radius=0.02, solver=HeatGeodesics(other))


def test_a_source_on_the_boundary_has_distances_with_dirichlet_heat_too():
    """With boundary_mix=1 (Dirichlet heat only) a source on the mesh border (or on a mesh with no
    interior vertex) put all its heat on boundary vertices, where the Dirichlet solution is 0: no
    flow, and the "distances" were the 1 cm calibration offset everywhere (max 0.010 m on a plane
    whose far corner is 0.32 m away). Such a source takes the Neumann solution."""
    from surfaces import plane_frame
    from geofeat.geodesic.mesh import mesh_from_points

    mesh = geofeat.build_mesh(plane_frame((120, 160)), CLEAN)
    src = (0.0, 30.0)  # a vertex on the left border
    p0 = mesh.points[30, 0]
    E = np.linalg.norm(mesh.points - p0, axis=-1)
    near = (E > 0.01) & (E < 0.1)
    for mix in (0.0, 0.5, 1.0):
        D = HeatGeodesics(mesh, boundary_mix=mix).distance(src)
        assert np.nanmax(D) > 0.3
        assert np.abs(D[near] / E[near] - 1).mean() < 0.03
    # a strip two vertices high: every vertex is on the boundary
    x = np.arange(40) / 262.5
    points = np.stack(np.broadcast_arrays(x[None, :], np.array([0.0, 1 / 262.5])[:, None], 1.0), axis=-1)
    strip = mesh_from_points(points, mesh.K, mesh.scale, (4, 80))
    D = HeatGeodesics(strip, boundary_mix=1.0).distance((10.2, 0.3))
    E = np.linalg.norm(points - np.array([10.2 / 262.5, 0.3 / 262.5, 1.0]), axis=-1)
    far = E > 0.02
    assert np.abs(D[far] / E[far] - 1).max() < 0.05


def test_a_mesh_and_a_solver_of_another_mesh_are_refused_and_vertex_indices_are_integers():
    """heat_polar_patches(mesh=m, solver=HeatGeodesics(other)) used the solver's mesh and ignored
    `mesh` (a mesh with no faces gave a valid patch); distance(3.7) was distance(3), the grid vertex."""
    from surfaces import plane_frame

    frame = plane_frame((120, 160))
    mesh = geofeat.build_mesh(frame, CLEAN)
    no_faces = geofeat.build_mesh(frame, CLEAN, max_edge_stretch=1.01)  # every edge "a discontinuity"
    H = HeatGeodesics(mesh)
    with pytest.raises(ValueError, match="solver.mesh"):
        heat_polar_patches(frame, [[80.0, 60.0]], radius=0.02, mesh=no_faces, solver=H)
    assert heat_polar_patches(frame, [[80.0, 60.0]], radius=0.02, mesh=mesh, solver=H).valid.all()
    for bad in (3.7, 3.0, True, np.float64(3.0)):
        with pytest.raises(ValueError, match="integer"):
            H.distance(bad)
    np.testing.assert_array_equal(H.distance(np.int64(3)), H.distance((3.0, 0.0)))


def test_sources_of_another_shape_or_not_finite_are_refused():
    """distances_vertices / distance_maps reshaped their sources to (-1, 2): two (x, y, z) points
    became three sources of shuffled coordinates, a flat [x0, y0, x1, y1] two, without a word; a NaN
    source failed as 'IndexError: index -9223372036854775808 is out of bounds'; no source at all as
    'cannot reshape array of size 0'."""
    from surfaces import plane_frame

    mesh = geofeat.build_mesh(plane_frame((60, 80)), CLEAN)
    H = HeatGeodesics(mesh)
    for bad in (np.array([[10.0, 10.0, 1.0], [20.0, 12.0, 1.0]]), [10.0, 10.0, 20.0, 12.0]):
        for solve in (H.distances_vertices, H.distance_maps):
            with pytest.raises(ValueError, match=r"sources: expected shape \(N, 2\)"):
                solve(bad)
    with pytest.raises(ValueError, match=r"sources: NaN or infinite coordinates in rows \[1\]"):
        H.distance_maps([[10.0, 10.0], [np.nan, 3.0]])
    assert H.distances_vertices(np.zeros((0, 2))).shape == (len(H.V), 0)
    assert H.distance_maps(np.zeros((0, 2))).shape == (0, *H.index.shape)
    np.testing.assert_array_equal(H.distance_maps((10.5, 12.0))[0], H.distance((10.5, 12.0)))


def test_a_heat_time_far_below_the_default_is_warned_of():
    """t = 1e-6 m^2 ("a small time is more accurate") on a mesh of 4 mm edges is 0.06 times the
    default: the distances came out about 9 % short without a word (the warning was for large t only)."""
    import warnings

    from surfaces import plane_frame

    mesh = geofeat.build_mesh(plane_frame((60, 80)), CLEAN)
    h2 = HeatGeodesics(mesh).mean_edge ** 2
    with pytest.warns(UserWarning, match=r"t: .* is 0\.05 times the default heat time.*distances come out short"):
        brief = HeatGeodesics(mesh, t=0.05 * h2)
    src, p0 = (20.0, 15.0), mesh.points[15, 20]
    E = np.linalg.norm(mesh.points - p0, axis=-1)
    far = E > 0.02
    short = np.median(brief.distance(src)[far] / E[far])
    assert short < 0.95, short  # what the warning is about
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        default = HeatGeodesics(mesh, t=h2).distance(src)  # the default itself, given: no warning
        HeatGeodesics(mesh, t=0.2 * h2)
    assert np.median(default[far] / E[far]) > 0.98


@pytest.mark.parametrize("step", ["1", None, 0.0, float("nan")])
def test_heat_polar_patches_refuses_a_step_that_is_no_positive_number(step):
    """step_px="1" failed inside np.isfinite with a bare TypeError."""
    frame = geofeat.read_demo_frame()
    with pytest.raises(ValueError, match=r"^step_px: "):
        heat_polar_patches(frame, np.array([[320.0, 240.0]]), step_px=step)
