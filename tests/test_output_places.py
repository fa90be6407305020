"""Where results go: read-only folders, folders of sequences that hold a killed run's leftovers, and
folder names with spaces and non-ASCII letters."""

import os
import subprocess
import sys

import pytest

from geofeat.cli import main
from geofeat.io import find_sequences
from geofeat.outputs import check_out_dir, check_out_file, foreign_entries, output_folder, read_manifest
from geofeat.sim import writer as writer_mod
from geofeat.sim.writer import simulate_sequence


@pytest.fixture
def read_only(monkeypatch):
    """Make folders read-only (chmod 555); as root, whom the mode does not stop, `os.access` is made
    to answer as for another user, so the checks see what a user would."""
    folders = []

    def access(path, mode, *args, **kwargs):
        if mode & os.W_OK and any(os.path.samefile(path, f) for f in folders if os.path.exists(path)):
            return False
        return real_access(path, mode, *args, **kwargs)

    real_access = os.access
    monkeypatch.setattr(os, "access", access)

    def make(folder):
        folder.mkdir(parents=True, exist_ok=True)
        folder.chmod(0o555)
        folders.append(folder)
        return folder

    yield make
    for folder in folders:
        folder.chmod(0o755)


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_a_read_only_output_folder_is_refused_before_any_work(tmp_path, read_only, capsys):
    """A read-only --out (or the read-only folder an --out would be made in) failed only at the end,
    after all the work, naming a temporary file: "[Errno 13] Permission denied:
    '.../.geofeat-partial-1597-.geofeat-manifest.json'". Now one line naming the folder, first."""
    ro = read_only(tmp_path / "nur lesen ü")
    for check in (lambda: check_out_dir(ro), lambda: check_out_dir(ro / "neu" / "tief"),
                  lambda: check_out_file(ro / "w.pt"), lambda: check_out_file(ro / "neu" / "w.pt")):
        with pytest.raises(ValueError, match=r"--out: cannot write into .*nur lesen ü.*permission denied"):
            check()
    check_out_dir(tmp_path / "neu")  # a writable parent: fine
    assert main(["simulate", str(ro / "tücher 1"), "--frames", "2", "--width", "64", "--height", "48",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cannot write into" in err and "nur lesen ü" in err
    assert "partial" not in err and list(ro.iterdir()) == []


def test_an_existing_output_folder_under_a_read_only_parent_is_written(tmp_path, read_only):
    """`--out /scratch/me`, writable, under a read-only /scratch: the result folder was built in a
    sibling of --out, which cannot be made there, so every run failed at its end. Now it is built
    inside --out and leaves nothing behind."""
    scratch = tmp_path / "scratch"
    mine = scratch / "mein ordner"
    mine.mkdir(parents=True)
    (mine / "notes.txt").write_text("user")
    read_only(scratch)
    check_out_dir(mine, overwrite=True)
    for text in ("first", "second"):
        with output_folder(mine) as tmp:
            assert tmp.parent == mine
            (tmp / "sub").mkdir()
            (tmp / "sub" / "result.txt").write_text(text)
    assert (mine / "sub" / "result.txt").read_text() == "second" and (mine / "notes.txt").read_text() == "user"
    assert sorted(p.name for p in mine.iterdir()) == [".geofeat-manifest.json", "notes.txt", "sub"]
    assert read_manifest(mine) == ["sub/result.txt"] and list(scratch.iterdir()) == [mine]
    # what a killed run left inside is not taken for the user's files, and the next run removes it
    left = mine / f".geofeat-partial-{_dead_pid()}-mein ordner"
    (left / "sub").mkdir(parents=True)
    (left / "sub" / "result.txt").write_text("half")
    assert foreign_entries(mine) == ["notes.txt"]
    with output_folder(mine) as tmp:
        (tmp / "result.txt").write_text("third")
    assert not left.exists()


@pytest.mark.filterwarnings("ignore:.*landmarks")
def test_a_killed_simulate_leaves_nothing_that_is_read_as_a_sequence(tmp_path, monkeypatch):
    """`simulate` built the sequence in ".<name>.partial-<pid>", which a SIGKILL left for good, and
    a folder of sequences then read it as a sequence: half its frames, and without its geofeat.json
    the depth scale 10 times too large (bench scored it, train trained on it). Now it is geofeat's
    temporary folder, which `find_sequences` passes over and the next run removes."""
    data = tmp_path / "daten ü"
    simulate_sequence(data / "tücher 1", n_frames=2, width=64, height=48, texture="procedural", progress=False)
    killed = data / f".geofeat-partial-{_dead_pid()}-tücher 2"  # as a SIGKILL while writing leaves it
    killed.mkdir()
    for name in ("frame-000-master-rgb.png", "frame-000-master-depth.png", "intrinsics.xml"):
        (killed / name).write_bytes((data / "tücher 1" / name).read_bytes())
    old_style = data / ".tücher 3.partial-12345"  # an earlier geofeat's
    old_style.mkdir()
    (old_style / "frame-000-master-rgb.png").write_bytes(b"")
    assert find_sequences([data]) == [data / "tücher 1"]
    built = []
    real_write = writer_mod._write
    monkeypatch.setattr(writer_mod, "_write", lambda folder, *a, **kw: (built.append(folder), real_write(folder, *a, **kw)))
    simulate_sequence(data / "tücher 2", n_frames=2, width=64, height=48, texture="procedural", progress=False)
    assert built[0].name.startswith(".geofeat-partial-") and not killed.exists()
    assert find_sequences([data]) == [data / "tücher 1", data / "tücher 2"]


def test_simulate_warnings_name_the_folder_given_not_a_temporary_one(tmp_path):
    """The few-landmarks warning named ".<name>.partial-<pid>", a folder the user never sees."""
    out = tmp_path / "tücher klein"
    with pytest.warns(UserWarning, match="landmarks") as caught:
        simulate_sequence(out, n_frames=2, width=33, height=47, progress=False)
    assert str(caught[0].message).startswith(f"{out}: ")


def test_result_files_are_utf8_whatever_the_locale(tmp_path):
    """bench appends its rows to results.csv as UTF-8 but read the file back (resuming, repairing,
    the tables) in the locale's encoding: on Windows (cp1252) "tücher 1" came back as "tÃ¼cher 1",
    so a rerun took no finished sequence for done and scored it again; in an ASCII locale it stopped
    with UnicodeDecodeError. Now every text result is written and read as UTF-8. The locale here is
    ASCII (Python's own UTF-8 defaults turned off), the one a test can choose on any Linux."""
    script = (
        "import sys\nfrom pathlib import Path\n"
        "from geofeat.bench.runner import COLUMNS, _append_rows, _finished, repair_results\n"
        "from geofeat.bench.report import read_results\n"
        "path = Path(sys.argv[1])\n"
        "path.write_bytes((','.join(COLUMNS) + '\\n').encode())\n"
        "row = {**dict.fromkeys(COLUMNS, '1'), 'sequence': 't\\u00fccher 1', 'descriptor': 'sift'}\n"
        "_append_rows(path, [row])\n"
        "assert repair_results(path) == 0\n"
        "assert _finished(path) == {('t\\u00fccher 1', 'sift')}, _finished(path)\n"
        "assert read_results(path)[0]['sequence'] == 't\\u00fccher 1'\n"
    )
    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONCOERCECLOCALE": "0", "PYTHONUTF8": "0",
           "PYTHONPATH": os.pathsep.join(sys.path)}
    done = subprocess.run([sys.executable, "-X", "utf8=0", "-c", script, str(tmp_path / "results.csv")], env=env,
                          capture_output=True, text=True, encoding="utf-8")
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "results.csv").read_bytes().decode("utf-8").splitlines()[1].startswith("tücher 1,")


def _strict_json(path):
    """The file read as JSON proper: NaN and Infinity, which Python writes and reads but JSON has not, refused."""
    import json

    def refuse(token):
        raise ValueError(f"{path}: {token} is not JSON")

    return json.loads(path.read_text(encoding="utf-8"), parse_constant=refuse)


def test_json_reports_are_json_without_nan(tmp_path):
    """train's history (val_ms of a run without --val) and groundtruth's report.json (the figures of a
    failed frame) held the bare token NaN, so jq, JavaScript and other strict readers refused them.
    Now such a figure is null."""
    from types import SimpleNamespace

    import numpy as np

    from geofeat.descriptors.geopatch import GeoPatchConfig
    from geofeat.groundtruth.pipeline import FrameReport, GroundTruthConfig, _write_report
    from geofeat.train.dataset import PatchSet
    from geofeat.train.loop import TrainConfig, train

    rng = np.random.default_rng(0)
    patches = rng.integers(0, 256, (20, 32, 32)).astype(np.uint8)
    data = PatchSet(np.concatenate([patches, patches]), np.concatenate([np.arange(20), np.arange(20)]))
    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=8, net=GeoPatchConfig(channels=(4, 8, 8), dim=16))
    train(data, tmp_path / "w ü.pt", config, progress=False, device="cpu")
    history = _strict_json(tmp_path / "w ü.pt.json")
    assert history["val_ms"] == [None] and isinstance(history["loss"][0], float)

    seq = SimpleNamespace(folder=tmp_path / "tücher 1", reference="frame-000-master", depth_scale=0.001)
    seq.folder.mkdir()  # report.json records the digest of its files
    failed = FrameReport("frame-001", status="failed", reason="too few landmarks", ssim_before=np.float32("nan"))
    _write_report(tmp_path, seq, GroundTruthConfig(), [FrameReport("frame-002", ssim_before=0.5), failed])
    frames = _strict_json(tmp_path / "report.json")["frames"]
    assert frames[0]["ssim_before"] == 0.5 and frames[1]["ssim_before"] is None and frames[1]["status"] == "failed"
    assert _strict_json(tmp_path / "report.json")["sequence"].endswith("tücher 1")


def test_an_output_folder_that_is_a_dangling_link_is_refused_before_any_work(tmp_path):
    """A symbolic link to a folder not made yet passed the check, and the finished result, built in a
    temporary folder, was lost at the end: a folder cannot be renamed over a link (NotADirectoryError)."""
    out = tmp_path / "out"
    out.symlink_to(tmp_path / "not-made-yet")
    with pytest.raises(ValueError, match="out: .*out is a symbolic link to .*not-made-yet, which does not exist"):
        check_out_dir(out, what="out")
    (tmp_path / "not-made-yet").mkdir()
    check_out_dir(out)
    with output_folder(out) as tmp:
        (tmp / "a.txt").write_text("result")
    assert (tmp_path / "not-made-yet" / "a.txt").read_text() == "result"


HOLD_OUTPUT = """
import sys
from geofeat.outputs import check_out_dir
check_out_dir(sys.argv[1], overwrite=True, writes="sequence")  # as `simulate` claims its OUT_DIR
print("claimed", flush=True)
sys.stdin.read()  # hold the claim until the test closes stdin or kills this process
"""


def _holding(folder):
    """A second process that has claimed `folder` as its output (as a running command has)."""
    child = subprocess.Popen([sys.executable, "-c", HOLD_OUTPUT, str(folder)], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    assert child.stdout.readline().strip() == "claimed"
    return child


def test_a_second_run_into_the_same_output_is_refused_while_the_first_runs(tmp_path, capsys):
    """Two runs writing one new --out at once each built their result in a temporary folder, and the
    second to finish replaced the first's files with no word. Now the second stops at once, naming the
    first; a path that leads to the same folder through a link is the same output; a killed run (no
    clean-up) does not block the next one."""
    from geofeat.outputs import release_outputs

    out = tmp_path / "runs" / "shared"
    child = _holding(out)
    try:
        with pytest.raises(ValueError, match=rf"--out: .*shared is being written by another geofeat run \(process "
                                             rf"{child.pid}"):
            check_out_dir(out)
        (tmp_path / "link").symlink_to(tmp_path / "runs")
        with pytest.raises(ValueError, match="another geofeat run"):
            check_out_dir(tmp_path / "link" / "shared")
        check_out_dir(tmp_path / "runs" / "other")  # another folder: free
        assert main(["simulate", str(out), "--frames", "2", "--width", "64", "--height", "48", "--no-progress"]) == 2
        assert f"is being written by another geofeat run (process {child.pid}" in capsys.readouterr().err
        assert not out.exists()  # nothing was written
    finally:
        child.kill()
        child.wait()
        child.stdout.close()
        child.stdin.close()
    check_out_dir(out)  # the killed holder's lock went with it
    check_out_dir(out)  # claiming again in the same run is fine
    release_outputs()
    child = _holding(out)  # released: another process may take it
    child.stdin.close()
    child.wait()
    child.stdout.close()


def test_the_command_line_releases_its_outputs_when_a_command_ends(tmp_path):
    """After a command returns, its output is free for the next run, in another process too."""
    out = tmp_path / "sim"
    assert main(["simulate", str(out), "--frames", "2", "--width", "64", "--height", "48", "--no-progress"]) == 0
    child = _holding(out)
    child.stdin.close()
    child.wait()
    child.stdout.close()
    assert child.returncode == 0


def test_ctrl_c_while_extract_renames_its_files_waits_for_the_last(tmp_path, monkeypatch):
    """`extract --out DIR/f.npz` writes one file per frame, then renames them into place. Ctrl-C in
    that loop left this run's files for the first frames beside an earlier run's for the others,
    which `bench --features` then scored as one method. Now the signal waits until every file is in."""
    import signal

    from geofeat.features import load_features

    seq = tmp_path / "seq"
    assert main(["simulate", str(seq), "--frames", "3", "--width", "160", "--height", "120", "--no-progress"]) == 0
    out = tmp_path / "f.npz"
    assert main(["extract", str(seq), "--descriptor", "sift", "--keypoints", "40", "--out", str(out)]) == 0
    names = sorted(p.name for p in tmp_path.glob("f-*.npz"))
    assert len(names) == 3
    real_replace, calls = os.replace, []

    def replace(src, dst, *args, **kwargs):
        if os.path.basename(str(dst)).startswith("f-"):
            calls.append(dst)
            if len(calls) == 2:  # Ctrl-C after the first frame's file is in
                signal.raise_signal(signal.SIGINT)  # to this thread
        return real_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", replace)
    # Ctrl-C must interrupt this process: one started in the background by a shell without job control
    # (`./.ci/run &`) inherits SIGINT ignored, and the run then rightly goes on and returns 0
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        status = main(["extract", str(seq), "--descriptor", "sift", "--keypoints", "12", "--out", str(out),
                       "--overwrite"])
    finally:
        signal.signal(signal.SIGINT, before)
    assert status == 130
    assert len(calls) == 3
    counts = [len(load_features(tmp_path / name)) for name in names]
    assert max(counts) <= 12, counts  # every frame's file is the second run's
