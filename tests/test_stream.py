"""geofeat in a long-running process fed a stream of frames (a robot's node): memory released with
each frame, calls from several threads, no lasting change to the process's settings, bad frames and
Ctrl-C in the middle of the stream."""

import gc
import signal
import threading
import time
import weakref

import numpy as np
import pytest

import geofeat
import geofeat.geodesic.mesh as mesh_module
import geofeat.pipeline as pipeline
from geofeat.geodesic.mesh import _CACHE_ATTR

N = 64  # keypoints: small, the properties do not depend on it


@pytest.fixture(scope="module")
def demo():
    return geofeat.read_demo_frame()


def fresh(demo, flip=False):
    """A new frame of the demo's data (nothing cached on it), mirrored with `flip`."""
    color, depth = demo.color, demo.depth
    if flip:
        color, depth = color[:, ::-1], depth[:, ::-1]
    return geofeat.RGBDFrame(np.ascontiguousarray(color), np.ascontiguousarray(depth), demo.K)


def same(a, b):
    return (np.array_equal(a.keypoints, b.keypoints) and np.array_equal(a.valid, b.valid)
            and np.array_equal(a.descriptors, b.descriptors))


def mesh_threads():
    return [t for t in threading.enumerate() if t.name == "geofeat-mesh"]


def test_a_dropped_frame_frees_its_mesh(demo):
    """The meshes are cached on the frame, not in the module: once the caller drops the frame,
    the frame and its mesh are freed (by reference counting: no cycle keeps them)."""
    frame = fresh(demo)
    geofeat.extract(frame, n=N)
    meshes = [v[1] for v in getattr(frame, _CACHE_ATTR).values() if hasattr(v[1], "walk_tables")]
    assert meshes and "walk_tables" in meshes[0].__dict__  # built by the prefetch thread, with its tables
    refs = [weakref.ref(frame)] + [weakref.ref(m) for m in meshes]
    del frame, meshes
    assert all(r() is None for r in refs)
    gc.collect()
    assert all(r() is None for r in refs)


def test_extract_from_several_threads_equals_one_thread(demo):
    """Three callback threads at once, two of them on the same frame object: each result equals
    the one-thread result bit for bit, and no prefetch thread is left."""
    want = {False: geofeat.extract(fresh(demo), n=N), True: geofeat.extract(fresh(demo, flip=True), n=N)}
    shared = fresh(demo)
    jobs = [(shared, False), (fresh(demo, flip=True), True), (shared, False)]
    got = [None] * len(jobs)
    barrier = threading.Barrier(len(jobs))

    def run(i):
        barrier.wait()
        got[i] = geofeat.extract(jobs[i][0], n=N)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(jobs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(same(g, want[flip]) for g, (_, flip) in zip(got, jobs))
    assert not mesh_threads()


def test_one_openvino_geopatch_serves_several_threads():
    """One GeoPatch shared by callbacks in several threads: the OpenVINO backends ran every call on
    the instance's one inference request, and overlapping calls failed ("Infer Request is busy")."""
    pytest.importorskip("openvino")
    from geofeat.descriptors.geopatch import GeoPatch

    patches = np.random.default_rng(0).random((3, 40, 32, 32)).astype(np.float32)
    for backend in ("openvino-int8", "openvino-bf16"):
        net = GeoPatch(backend=backend, threads=2)
        want = [net.describe(p) for p in patches]
        errors, barrier = [], threading.Barrier(3)

        def run(i):
            barrier.wait()
            try:
                for _ in range(30):  # batches of 40 <= batch_size: one request each
                    if not np.array_equal(net.describe(patches[i]), want[i]):
                        errors.append(f"thread {i}: other descriptors")
            except Exception as error:  # noqa: BLE001 - collected, asserted below
                errors.append(f"thread {i}: {error!r}")

        threads = [threading.Thread(target=run, args=(i,)) for i in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert not errors, (backend, errors[:3])


def _overlap(first, second, first_net, second_net):
    """Run `first()` and `second()` in two threads so that their calls overlap, `second` starting
    while `first` is inside its network's forward pass (`first_net`) and finishing after `first`
    (its network, `second_net`, waits for it): the order in which a restore of the other's value
    shows."""
    first_inside, second_inside, first_done = threading.Event(), threading.Event(), threading.Event()

    def hold(net, inside, wait_for):
        forward = net.forward

        def held(x):
            inside.set()
            assert wait_for.wait(10)
            return forward(x)

        net.forward = held

    hold(first_net, first_inside, second_inside)
    hold(second_net, second_inside, first_done)

    def run_first():
        first()
        first_done.set()

    a, b = threading.Thread(target=run_first), threading.Thread(target=second)
    a.start()
    assert first_inside.wait(10)
    b.start()
    a.join()
    b.join()


def test_overlapping_describe_calls_restore_the_callers_torch_threads():
    """GeoPatch(threads=1) sets torch's thread count for its call (the calling thread's, and the
    process's, which threads take when they first run torch). A call of another GeoPatch that
    started meanwhile saved that 1 and put it back after the first had restored the caller's
    value: threads started afterwards ran torch on 1 thread for good."""
    torch = pytest.importorskip("torch")
    from geofeat.descriptors.geopatch import GeoPatch

    one = GeoPatch(device="cpu", backend="torch", threads=1)
    free = GeoPatch(device="cpu", backend="torch")  # leaves torch's threads as they are
    patches = np.random.default_rng(1).random((4, 32, 32)).astype(np.float32)
    caller = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        _overlap(lambda: one.describe(patches), lambda: free.describe(patches), one.net, free.net)
        assert torch.get_num_threads() == 3
        seen = []  # the process's count, taken by a thread started now
        later = threading.Thread(target=lambda: seen.append(torch.get_num_threads()))
        later.start()
        later.join()
        assert seen == [3]
    finally:
        torch.set_num_threads(caller)


def test_overlapping_gpu_path_calls_restore_the_callers_tf32_switches():
    """`describe_tensor` turns TF32 off for its call (torch's switches are the process's); two
    overlapping calls left it off for good, the second having saved the first's value."""
    torch = pytest.importorskip("torch")
    from geofeat.descriptors.geopatch import GeoPatch

    a, b = GeoPatch(device="cpu", backend="torch"), GeoPatch(device="cpu", backend="torch")
    values = torch.rand(4, 32, 32)
    flags = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = True
    try:
        _overlap(lambda: a.describe_tensor(values), lambda: b.describe_tensor(values), a.net, b.net)
        assert (torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32) == (True, True)
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = flags


def test_making_torch_descriptors_leaves_the_callers_torch_random_numbers_alone():
    """Loading GeoPatch (torch backend) or tfeat-sim weights built a network with random initial
    weights first, drawing from torch's global generator: a host that had seeded torch got other
    random numbers afterwards."""
    torch = pytest.importorskip("torch")
    torch.manual_seed(7)
    want = torch.rand(4)
    for name, options in (("geopatch", {"backend": "torch", "device": "cpu"}), ("tfeat-sim", {})):
        torch.manual_seed(7)
        geofeat.make_descriptor(name, **options)
        assert torch.equal(torch.rand(4), want), name


def test_a_bad_frame_in_the_stream_leaves_the_next_ones_unchanged(demo):
    """A frame that fails (depth edited to NaN after the frame was made: the prefetch thread fails
    on it, and so does the description) or that has nothing to describe raises a ValueError saying
    why; the good frames before and after give the same features, and no thread is left."""
    want = geofeat.extract(fresh(demo), n=N)
    broken = fresh(demo)
    broken.depth.flags.writeable = True  # a frame is read-only: edited in place only after turning that off
    broken.depth[::3, ::3] = np.nan
    with pytest.raises(ValueError, match="depth: contains NaN"):
        geofeat.extract(broken, n=N)
    blank = geofeat.RGBDFrame(np.full_like(demo.color, 128), demo.depth, demo.K)
    with pytest.raises(ValueError, match="no keypoints detected"):
        geofeat.extract(blank, n=N)
    assert same(geofeat.extract(fresh(demo), n=N), want)
    assert not mesh_threads()


def test_ctrl_c_in_the_detector_leaves_no_prefetch_thread(demo, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(pipeline, "detect", interrupted)
    with pytest.raises(KeyboardInterrupt):
        geofeat.extract(fresh(demo), n=N)
    assert not mesh_threads()


def test_ctrl_c_while_waiting_for_the_mesh_leaves_no_prefetch_thread(demo, monkeypatch):
    """SIGINT while `extract` waits for the prefetch thread's mesh (detection done): the interrupt
    used to leave at once, the thread still building; now it waits for the thread first."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals reach the main thread only")
    keypoints = geofeat.detect(fresh(demo), N)
    detected, release, built = threading.Event(), threading.Event(), threading.Event()
    build = mesh_module.frame_mesh

    def slow_mesh(*args, **kwargs):
        assert release.wait(10)  # released by the SIGINT handler
        time.sleep(0.5)  # a window: old code returned with this thread still building
        try:
            return build(*args, **kwargs)
        finally:
            built.set()

    def quick_detect(*args, **kwargs):
        detected.set()
        return keypoints

    def on_sigint(signum, frame):
        release.set()
        raise KeyboardInterrupt

    def send_sigint():
        assert detected.wait(10)
        time.sleep(0.2)  # extract is waiting for the mesh by then (detection returns at once)
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)

    monkeypatch.setattr(mesh_module, "frame_mesh", slow_mesh)
    monkeypatch.setattr(pipeline, "detect", quick_detect)
    before = signal.signal(signal.SIGINT, on_sigint)
    sender = threading.Thread(target=send_sigint)
    try:
        sender.start()
        with pytest.raises(KeyboardInterrupt):
            geofeat.extract(fresh(demo), n=N)
        # the thread's work is done when the interrupt arrives (on Python < 3.13 the thread itself is
        # not a witness: an interrupted join marks it as ended while it runs on)
        assert built.is_set()
    finally:
        sender.join()
        signal.signal(signal.SIGINT, before)
        release.set()
