"""Commands never write among their inputs nor mix them up: an --out inside an input folder is
refused by every command, `retrieval` refuses a sequence copied under two folder names, and
`extract` refuses to add one sequence's per-frame features to another's. Nor do they replace data
or results that are not theirs: another sequence or ground truth, `match`'s features, a results.csv
copied in, the --texture photograph; `bench` refuses to average an earlier run's other sequences in."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from geofeat.cli import main
from geofeat.io import write_frame, write_intrinsics, write_landmarks
from geofeat.outputs import check_out_dir

W, H = 160, 120
K = np.array([[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]])


def make_sequence(folder: Path, seed: int = 0, names=("frame-000-master", "frame-001")) -> Path:
    """A sequence of `names` in the public layout: a blurred-noise texture of `seed` (so that two
    seeds give two different sequences) shifted 3 px per frame, depth 1 m, landmark csvs."""
    folder.mkdir(parents=True, exist_ok=True)
    write_intrinsics(folder / "intrinsics.xml", K)
    rng = np.random.default_rng(seed)
    texture = sum(cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), s) * s for s in (1.5, 4))
    texture = cv2.normalize(texture, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    gx, gy = np.meshgrid(np.linspace(20, W - 30, 5), np.linspace(20, H - 20, 4))
    landmarks = np.stack([gx.ravel(), gy.ravel()], 1)
    for i, name in enumerate(names):
        image = cv2.cvtColor(np.roll(texture, 3 * i, axis=1), cv2.COLOR_GRAY2BGR)
        write_frame(folder, name, image, np.full((H, W), 1.0))
        write_landmarks(folder / f"{name}.csv", np.arange(len(landmarks)), landmarks + [3 * i, 0],
                        np.ones(len(landmarks), bool))
    return folder


def _listing(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# ---------------------------------------------------------------- an --out inside an input folder
#: Each command with an --out (or OUT_DIR) inside one of its input folders that holds images itself:
#: {seq} a sequence folder (in {data}, beside {other}), {tex} a folder of texture images.
INSIDE = {
    "match": (["match", "{seq}", "--descriptor", "orb", "--out", "{seq}/matches"], "{seq}"),
    "extract-h5": (["extract", "{seq}", "--descriptor", "orb", "--out", "{seq}/features.h5"], "{seq}"),
    "extract-folder": (["extract", "{seq}", "--descriptor", "orb", "--out", "{seq}/features"], "{seq}"),
    "bench-sequence": (["bench", "{seq}", "--descriptors", "orb", "--out", "{seq}/bench"], "{seq}"),
    "bench-dataset": (["bench", "{data}", "--descriptors", "orb", "--out", "{seq}/bench"], "{seq}"),
    "track-dataset": (["track", "{data}", "--descriptors", "orb", "--out", "{seq}/track"], "{seq}"),
    "retrieval-dataset": (["retrieval", "{data}", "--descriptors", "orb", "--out", "{other}/r"], "{other}"),
    "groundtruth-sequence": (["groundtruth", "{seq}", "--no-refine", "--out", "{seq}/gt"], "{seq}"),
    "groundtruth-dataset": (["groundtruth", "{data}", "--no-refine", "--out", "{seq}/gt"], "{seq}"),
    "simulate": (["simulate", "{tex}/sim", "--texture-dir", "{tex}", "--frames", "1", "--width", "64",
                  "--height", "48", "--no-progress"], "{tex}"),
    "train": (["train", "--data", "{seq}", "--out", "{seq}/w.pt"], "{seq}"),
    "train-sequence-of-data": (["train", "--data", "{data}", "--out", "{seq}/frame-001-rgb.png"], "{seq}"),
    "train-detector-sequence-of-data": (["train-detector", "--data", "{data}", "--val", "{data}", "--out",
                                         "{other}/frame-001-depth.png"], "{other}"),
    "train-detector": (["train-detector", "--data", "{seq}", "--val", "{other}", "--out", "{other}/gk.npz"],
                       "{other}"),
}


@pytest.mark.parametrize("overwrite", [False, True], ids=["", "overwrite"])
@pytest.mark.parametrize("case", list(INSIDE))
def test_an_out_inside_an_input_folder_is_refused_before_any_work(tmp_path, capsys, case, overwrite):
    """An --out inside (not only equal to) a sequence folder or --texture-dir was written: the results
    among the user's frames, where the next run over that folder reads them as inputs. Now one line
    naming both paths, with or without --overwrite, and every input folder as it was."""
    data = tmp_path / "data"
    seq = make_sequence(data / "seq")
    other = make_sequence(data / "other", seed=1)
    tex = tmp_path / "tex"
    tex.mkdir()
    cv2.imwrite(str(tex / "cloth.png"), np.full((32, 32, 3), 128, np.uint8))
    places = {"seq": seq, "data": data, "other": other, "tex": tex}
    before = _listing(tmp_path)
    command, outer = INSIDE[case]
    argv = [a.format(**places) for a in command] + ["--overwrite"] * overwrite
    out = Path(argv[argv.index("--out") + 1] if "--out" in argv else argv[1])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert f"{out} lies inside the input folder {outer.format(**places)}" in err
    assert _listing(tmp_path) == before  # an --out naming one of the frames is left as it was
    assert not out.exists() or str(out.relative_to(tmp_path)) in before


def test_check_out_dir_refuses_a_folder_inside_an_input_also_through_a_link(tmp_path):
    seq = make_sequence(tmp_path / "seq")
    (tmp_path / "link").symlink_to(seq)
    for out in (seq / "out", seq / "a" / "b", tmp_path / "link" / "out"):
        with pytest.raises(ValueError, match=f"lies inside the input folder {seq}"):
            check_out_dir(out, overwrite=True, inputs=[None, seq])
    assert check_out_dir(tmp_path / "out", inputs=[seq]) == tmp_path / "out"  # beside it: fine


def test_a_results_folder_beside_the_sequences_of_a_dataset_folder_is_fine(tmp_path):
    """A folder of sequences holds no frames itself, and the commands look for sequences only in
    sub-folders that hold frames: results beside them (`cd data; geofeat bench . --out results`, the
    way COLMAP keeps sparse/ beside images/) are not read as inputs, and are written."""
    data = tmp_path / "data"
    seq = make_sequence(data / "seq")
    assert check_out_dir(data / "results", inputs=[data, seq]) == data / "results"
    cv2.imwrite(str(data / "sheet.png"), np.zeros((8, 8), np.uint8))  # a contact sheet beside the sequences
    assert check_out_dir(data / "results", inputs=[data, seq]) == data / "results"
    for inputs in ([data, seq], [data]):  # a sequence of the folder given is an input folder too
        with pytest.raises(ValueError, match=f"lies inside the input folder {seq}"):
            check_out_dir(data / "seq" / "results", inputs=inputs)
    with pytest.raises(ValueError, match=f"is the input folder {seq}"):
        check_out_dir(seq, overwrite=True, inputs=[data])


def test_a_results_folder_in_a_dataset_folder_is_written_again_though_it_holds_its_plots(tmp_path, capsys):
    """A results folder beside the sequences holds the images geofeat wrote there (bench's
    ms_vs_<scenario>.png plots) but no frames: no command reads it as a sequence. Its images made it
    an "input folder", so the rerun (resumed, or with --overwrite) of the same command was refused:
    "--out: data/bench is the input folder data/bench"; a folder below it as well."""
    from geofeat.outputs import add_to_manifest

    data = tmp_path / "data"
    seq = make_sequence(data / "seq")
    bench = ["bench", str(data), "--descriptors", "orb", "--keypoints", "64", "--workers", "1", "--out"]
    assert main([*bench, str(data / "bench")]) == 0
    cv2.imwrite(str(data / "bench" / "ms_vs_rotate.png"), np.zeros((8, 8), np.uint8))  # as bench plots it
    add_to_manifest(data / "bench", ["ms_vs_rotate.png"])
    capsys.readouterr()
    assert main([*bench, str(data / "bench")]) == 0, capsys.readouterr().err  # resumed
    assert main([*bench, str(data / "bench"), "--overwrite"]) == 0, capsys.readouterr().err
    assert check_out_dir(data / "bench" / "sub", inputs=[data, seq]) == data / "bench" / "sub"
    with pytest.raises(ValueError, match=f"is the input folder {seq}"):  # a sequence still is one
        check_out_dir(seq, overwrite=True, inputs=[data])


# ---------------------------------------------------------------- retrieval: one sequence under two names
@pytest.mark.parametrize("own", [False, True], ids=["", "include-own-sequence"])
def test_retrieval_refuses_a_sequence_copied_under_another_folder_name(tmp_path, capsys, monkeypatch, own):
    """The query's own sequence is left out of its results by name, so a byte copy of it under
    another folder name (a dataset given twice, two datasets sharing a sequence) was found as its
    own frame, counted correct, and Acc@K rose unsaid. Now one line naming both folders, before any
    frame is described."""
    import geofeat.apps.retrieval as retrieval

    make_sequence(tmp_path / "a" / "cloth", seed=0)
    make_sequence(tmp_path / "a" / "paper", seed=1)
    shutil.copytree(tmp_path / "a" / "cloth", tmp_path / "b" / "cloth_again")  # another dataset shares it
    make_sequence(tmp_path / "b" / "towel", seed=2)
    classes = tmp_path / "classes.csv"  # the copy is a class mate of its original: a correct result
    classes.write_text("sequence,class\ncloth,cloth\ncloth_again,cloth\npaper,paper\ntowel,paper\n")

    def described(*args, **kwargs):
        raise AssertionError("frames were described before the copy was reported")

    monkeypatch.setattr(retrieval, "describe_datasets", described)
    argv = ["retrieval", str(tmp_path / "a"), str(tmp_path / "b"), "--descriptors", "orb", "--classes", str(classes),
            "--out", str(tmp_path / "r")] + ["--include-own-sequence"] * own
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert f"{tmp_path / 'a' / 'cloth'} and {tmp_path / 'b' / 'cloth_again'} hold the same reference frame" in err
    assert not (tmp_path / "r").exists()


def test_retrieval_sequences_that_differ_are_not_taken_for_copies(tmp_path):
    from geofeat.apps.retrieval import refuse_copied_sequences

    folders = [make_sequence(tmp_path / f"s{seed}", seed=seed) for seed in range(3)]
    refuse_copied_sequences(folders)  # no error
    # the same frames under other frame names are still a copy
    make_sequence(tmp_path / "renamed", seed=1, names=("frame-100-master", "frame-101"))
    with pytest.raises(ValueError, match=f"{tmp_path / 's1'} and {tmp_path / 'renamed'}"):
        refuse_copied_sequences([*folders, tmp_path / "renamed"])


# ---------------------------------------------------------------- extract: one sequence per .npz prefix
def _extract(seq: Path, out: Path, *extra: str) -> int:
    return main(["extract", str(seq), "--descriptor", "orb", "--keypoints", "100", "--out", str(out), *extra])


def _prefix_files(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.parent.glob(f"{out.stem}-*.npz"))}


@pytest.mark.parametrize("frames", ["same frame names", "other frame names"])
def test_extract_refuses_to_add_another_sequences_features_to_an_npz_prefix(tmp_path, capsys, frames):
    """`--out DIR/f.npz` writes f-<frame>.npz; a second sequence extracted there was added beside the
    first's (other frame names), or refused as "exists" with no word of whose features those are.
    Now one line naming both sequences, and the first's files untouched."""
    first = make_sequence(tmp_path / "first", seed=0)
    names = ("frame-000-master", "frame-001") if frames == "same frame names" else ("img-00-ref", "img-01")
    second = make_sequence(tmp_path / "second", seed=1, names=names)
    out = tmp_path / "features" / "f.npz"
    assert _extract(first, out) == 0
    kept = _prefix_files(out)
    capsys.readouterr()
    assert _extract(second, out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert f"features of {first.resolve()}, not of {second.resolve()}" in err and "--overwrite" in err
    assert _prefix_files(out) == kept


def test_extract_overwrite_with_another_sequence_leaves_none_of_the_first_ones_features(tmp_path, capsys):
    """--overwrite replaced the second sequence's frames' files and left the first's other frames
    (f-frame-002.npz) beside them: `bench --features` read one sequence's features for another. Now
    the earlier run's files that this run does not write are removed, named, and the record names
    the second sequence."""
    first = make_sequence(tmp_path / "first", seed=0, names=("frame-000-master", "frame-001", "frame-002"))
    second = make_sequence(tmp_path / "second", seed=1)
    out = tmp_path / "features" / "f.npz"
    assert _extract(first, out) == 0
    assert _extract(second, out, "--overwrite") == 0
    assert sorted(_prefix_files(out)) == ["f-frame-000-master.npz", "f-frame-001.npz"]
    assert "f-frame-002.npz" in capsys.readouterr().err
    record = json.loads((out.parent / "f.source.json").read_text())
    assert record["sequence"] == str(second.resolve())
    assert record["files"] == ["f-frame-000-master.npz", "f-frame-001.npz"]


def test_extract_reruns_the_same_sequence_into_its_npz_prefix(tmp_path, capsys):
    """The same sequence again is no other sequence: --overwrite replaces its files as before, and
    without it the files that exist are refused as before ("exists"), not as another's."""
    seq = make_sequence(tmp_path / "seq", seed=0, names=("frame-000-master", "frame-001", "frame-002"))
    out = tmp_path / "features" / "f.npz"
    assert _extract(seq, out) == 0
    assert _extract(seq, out, "--overwrite") == 0
    assert len(_prefix_files(out)) == 3
    capsys.readouterr()
    assert _extract(seq, out) == 2
    assert "f-frame-000-master.npz exists; pass --overwrite" in capsys.readouterr().err
    record = json.loads((out.parent / "f.source.json").read_text())
    assert record["sequence"] == str(seq.resolve()) and len(record["files"]) == 3
    moved = seq.rename(tmp_path / "moved")  # the same sequence under another folder: its files, not another's
    assert _extract(moved, out) == 2
    assert "f-frame-000-master.npz exists; pass --overwrite" in capsys.readouterr().err


def test_simulate_refuses_a_contact_sheet_inside_its_texture_folder_and_names_a_texture_folder(tmp_path, capsys):
    """`simulate --texture-dir T --contact-sheet T/sheet.png` wrote the sheet among the textures, where the
    next simulation could draw it as a cloth; `--texture FOLDER` said "file not found" for a folder that exists."""
    tex = tmp_path / "tex"
    tex.mkdir()
    cv2.imwrite(str(tex / "cloth.png"), np.full((32, 32, 3), 128, np.uint8))
    small = ["--frames", "1", "--width", "64", "--height", "48", "--no-progress"]
    assert main(["simulate", str(tmp_path / "s"), "--texture-dir", str(tex), "--contact-sheet", str(tex / "sheet.png"),
                 *small]) == 2
    assert f"--contact-sheet: {tex / 'sheet.png'} lies inside the input folder {tex}" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tex"] and sorted(p.name for p in tex.iterdir()) == ["cloth.png"]
    assert main(["simulate", str(tmp_path / "s"), "--texture", str(tex), *small]) == 2
    assert f"texture: {tex} is a folder, not an image file" in capsys.readouterr().err


def test_simulate_texture_folder_passes_over_macos_dot_files_and_names_a_bad_file_as_the_folders(tmp_path, capsys):
    """A texture folder copied from a Mac holds a `._cloth.png` beside each photo (AppleDouble metadata, no
    image): every seed that drew one failed with "texture: cannot decode image", naming --texture, which was
    not given. Hidden files are no textures; a file of the folder that cannot be read is named as the folder's."""
    from geofeat.sim.textures import choose_texture, list_textures

    tex = tmp_path / "tex"
    tex.mkdir()
    cv2.imwrite(str(tex / "cloth.png"), np.full((32, 32, 3), 128, np.uint8))
    (tex / "._cloth.png").write_bytes(b"\x00\x05\x16\x07 AppleDouble")
    assert list_textures(tex) == [tex / "cloth.png"]
    for seed in range(8):  # every seed draws the photo
        image, name = choose_texture(np.random.default_rng(seed), texture_dir=tex)
        assert name == "cloth.png" and image.shape == (32, 32, 3)
    (tex / "notes.png").write_text("not an image")
    small = ["--frames", "1", "--width", "64", "--height", "48", "--no-progress"]
    seed = next(s for s in range(20) if list_textures(tex)[int(np.random.default_rng(s).integers(2))].name == "notes.png")
    assert main(["simulate", str(tmp_path / "s"), "--texture-dir", str(tex), "--seed", str(seed), *small]) == 2
    err = capsys.readouterr().err
    assert f"texture_dir: notes.png, the file this seed draws from {tex}, is no usable texture" in err
    assert "remove it from the folder" in err and not (tmp_path / "s").exists()


# ---------------------------------------------------------------- whose files an output may replace
def _simulated_like(folder: Path, seed: int = 1) -> Path:
    """A sequence whose files are all in its manifest, as `geofeat simulate` leaves one."""
    from geofeat.outputs import write_manifest

    make_sequence(folder, seed=seed)
    write_manifest(folder, [p.name for p in folder.iterdir()])
    return folder


#: Each command with --overwrite and an output folder that is another sequence, no input of the run:
#: {seq} the input sequence, {sim} a folder holding a sequence named like it (`groundtruth` writes
#: {sim}/seq), {gt} a folder of TPS ground truth (`groundtruth`'s), all files in their manifests.
REPLACED = {
    "match": (["match", "{seq}", "--descriptor", "orb", "--keypoints", "64", "--out", "{sim}/seq"], "{sim}/seq",
              "a sequence's frames"),
    "track": (["track", "{seq}", "--descriptors", "orb", "--keypoints", "64", "--refine", "none", "--out", "{sim}/seq"],
              "{sim}/seq", "a sequence's frames"),
    "bench": (["bench", "{seq}", "--descriptors", "orb", "--keypoints", "64", "--out", "{sim}/seq"], "{sim}/seq",
              "a sequence's frames"),
    "groundtruth": (["groundtruth", "{seq}", "--no-refine", "--out", "{sim}"], "{sim}/seq", "a sequence's frames"),
    "simulate": (["simulate", "{gt}", "--frames", "1", "--width", "64", "--height", "48", "--no-progress"], "{gt}",
                 "ground truth (TPS files)"),
}


@pytest.mark.parametrize("case", list(REPLACED))
def test_overwrite_never_replaces_a_sequence_or_ground_truth_with_another_commands_output(tmp_path, capsys, case):
    """The input sequence was protected, another one was not: `match seq --out other_seq --overwrite` (as
    the "exists and is not empty; pass --overwrite" error advised) deleted every frame of a simulated
    sequence, whose files geofeat wrote, and left the matches; `simulate gt --overwrite` deleted
    `groundtruth`'s TPS files. Now one line naming what the folder holds, and nothing changed."""
    seq = make_sequence(tmp_path / "data" / "seq")
    sim = tmp_path / "sim"
    _simulated_like(sim / "seq")
    gt = tmp_path / "gt"
    gt.mkdir()
    np.save(gt / "frame-001_theta.npy", np.zeros((3, 2)))
    cv2.imwrite(str(gt / "frame-000-master_objmask.png"), np.full((8, 8), 255, np.uint8))
    from geofeat.outputs import write_manifest

    write_manifest(gt, ["frame-001_theta.npy", "frame-000-master_objmask.png"])
    places = {"seq": seq, "sim": sim, "gt": gt}
    before = _listing(tmp_path)
    command, held, what = REPLACED[case]
    assert main([a.format(**places) for a in command] + ["--overwrite"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert f"{held.format(**places)} holds {what}" in err
    assert _listing(tmp_path) == before


def test_track_refuses_results_inside_an_input_sequence_under_the_folder_above_it(tmp_path, capsys):
    """`track data/seq --out data` writes OUT/<sequence>/<descriptor>/: data/seq/orb/track.gif, among the
    input's frames (the folder above a sequence is no input, so it was not refused)."""
    seq = make_sequence(tmp_path / "data" / "seq")
    before = _listing(tmp_path)
    argv = ["track", str(seq), "--descriptors", "orb", "--keypoints", "64", "--refine", "none", "--out",
            str(tmp_path / "data"), "--overwrite"]
    assert main(argv) == 2
    assert f"{seq / 'orb'} lies inside the input folder {seq}" in capsys.readouterr().err
    assert _listing(tmp_path) == before


def test_bench_overwrite_never_replaces_a_results_csv_geofeat_did_not_write(tmp_path, capsys):
    """A results.csv copied into a folder (bench's header, no manifest listing it) was refused on a rerun
    ("other settings ... use --overwrite"), and --overwrite then replaced it with the new run's."""
    from geofeat.bench.runner import COLUMNS

    seq = make_sequence(tmp_path / "seq")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "results.csv").write_text(",".join(COLUMNS) + "\n" + ",".join(["x"] * len(COLUMNS)) + "\n")
    before = _listing(mine)
    assert main(["bench", str(seq), "--descriptors", "orb", "--keypoints", "64", "--out", str(mine), "--overwrite"]) == 2
    assert "holds results.csv, which geofeat did not write" in capsys.readouterr().err
    assert _listing(mine) == before


def test_bench_resume_refuses_results_of_sequences_not_given(tmp_path, capsys):
    """`bench a --out b` then `bench other --out b` skipped nothing and wrote table.md over both: the earlier
    run's sequence averaged in unsaid (its files unchecked, its scenario group lost)."""
    seq = make_sequence(tmp_path / "a" / "seq")
    other = make_sequence(tmp_path / "o" / "other", seed=1)
    bench = ["bench", "--descriptors", "orb", "--keypoints", "64", "--out", str(tmp_path / "b")]
    assert main([bench[0], str(seq), *bench[1:]]) == 0
    before = _listing(tmp_path / "b")
    capsys.readouterr()
    assert main([bench[0], str(other), *bench[1:]]) == 2
    err = capsys.readouterr().err
    assert f"holds results of seq (from {seq.resolve()}), not among the datasets given" in err
    assert _listing(tmp_path / "b") == before
    assert main([bench[0], str(seq), str(other), *bench[1:]]) == 0  # both: seq resumed, other added


def test_match_refuses_a_file_it_would_replace_before_any_pair_is_matched(tmp_path, capsys, monkeypatch):
    """An `extract` features file in the --out folder (features-orb.h5, which match writes too) was found
    only when the results were moved into place, after every pair was matched; and the error called it
    a file "geofeat did not write" (extract recorded nothing): it names the command that wrote it."""
    import geofeat.matching

    seq = make_sequence(tmp_path / "seq")
    out = tmp_path / "out"
    assert main(["extract", str(seq), "--descriptor", "orb", "--keypoints", "64", "--out", str(out)]) == 0
    matched = []
    monkeypatch.setattr(geofeat.matching, "match", lambda *a, **k: matched.append(a))
    capsys.readouterr()
    assert main(["match", str(seq), "--descriptor", "orb", "--keypoints", "64", "--out", str(out), "--overwrite"]) == 2
    assert ("holds features-orb.h5 (written by `geofeat extract`), which is not among the results geofeat wrote "
            "there; --overwrite never replaces those") in capsys.readouterr().err
    assert matched == []


def test_extract_never_replaces_the_features_of_a_match_folder(tmp_path, capsys):
    """`extract --out DIR` writes DIR/features-<descriptor>.h5, the name of the features `match` writes
    beside the matches that index them: --overwrite replaced them with other keypoints unsaid."""
    seq = make_sequence(tmp_path / "seq")
    out = tmp_path / "out"
    assert main(["match", str(seq), "--descriptor", "orb", "--keypoints", "64", "--out", str(out)]) == 0
    before = _listing(out)
    capsys.readouterr()
    assert main(["extract", str(seq), "--descriptor", "orb", "--keypoints", "32", "--out", str(out), "--overwrite"]) == 2
    assert f"{out / 'features-orb.h5'} belongs to the results in {out}" in capsys.readouterr().err
    assert _listing(out) == before


def test_simulate_refuses_a_contact_sheet_that_is_its_texture(tmp_path, capsys):
    """`--contact-sheet` naming the --texture photograph was refused as "exists; pass --overwrite", and
    with --overwrite the sheet replaced the user's photograph."""
    photo = tmp_path / "photo.png"
    cv2.imwrite(str(photo), np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8))
    kept = photo.read_bytes()
    argv = ["simulate", str(tmp_path / "s"), "--texture", str(photo), "--contact-sheet", str(tmp_path / "." / "photo.png"),
            "--overwrite", "--frames", "1", "--width", "64", "--height", "48", "--no-progress"]
    assert main(argv) == 2
    assert "is the --texture image" in capsys.readouterr().err
    assert photo.read_bytes() == kept and not (tmp_path / "s").exists()


# ---------------------------------------------------------------- only what the command wrote, never two runs
def test_train_overwrite_never_removes_a_file_beside_the_weights_that_train_did_not_write(tmp_path):
    """`train --out model --overwrite` removed model.json and model.png beside the weights (the files an
    earlier run writes there) without asking whether `train` wrote them: a user's own model.json went."""
    from geofeat.descriptors.geopatch import GeoPatchConfig
    from geofeat.train.dataset import PatchSet
    from geofeat.train.loop import TrainConfig, train

    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (40, 32, 32)).astype(np.uint8)
    data = PatchSet(np.concatenate([base, 255 - base]), np.concatenate([np.arange(40), np.arange(40)]))
    config = TrainConfig(epochs=1, steps_per_epoch=1, batch_size=8, net=GeoPatchConfig(channels=(4, 8, 8), dim=16))
    (tmp_path / "model.json").write_text('{"mine": true}')
    with pytest.raises(ValueError, match=r"model\.json exists, and `geofeat train` did not write it"):
        train(data, tmp_path / "model", config, progress=False, device="cpu", overwrite=True)
    assert (tmp_path / "model.json").read_text() == '{"mine": true}'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.json"]
    train(data, tmp_path / "weights", config, progress=False, device="cpu")  # its own files it replaces
    (tmp_path / "weights.png").write_bytes(b"an earlier run's plot")
    train(data, tmp_path / "weights", config, progress=False, device="cpu", overwrite=True)
    assert (tmp_path / "weights.png").read_bytes()[:4] == b"\x89PNG"


def test_an_interrupted_demo_rerun_leaves_the_earlier_pictures_unmixed(tmp_path, monkeypatch):
    """`geofeat demo` wrote its pictures one by one into --out: a rerun with another --angle stopped
    before its last picture left the new rolled pair beside the earlier run's other pictures."""
    from geofeat.cli import demo

    out = tmp_path / "demo"
    monkeypatch.setattr(demo, "_demo_deformed_pair", lambda *a: None)  # the simulated pair: not needed here
    assert main(["demo", "--out", str(out), "--keypoints", "100"]) == 0
    before = _listing(out)
    assert sorted(before) == [".geofeat-manifest.json", "polar_patches.png", "rolled_pair_matches.png"]

    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(demo, "_demo_deformed_pair", interrupted)
    assert main(["demo", "--out", str(out), "--keypoints", "100", "--angle", "30"]) == 130
    assert _listing(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo"]  # no temporary folder left


def test_bench_resume_never_leaves_a_timing_table_without_the_descriptors_of_its_results(tmp_path, capsys,
                                                                                          monkeypatch):
    """A resumed bench without --timing kept the earlier timing.md, which lacked the descriptors added
    since; with --timing it timed only the descriptors named this time, not those results.csv holds."""
    import geofeat.bench.timing

    timed = []
    monkeypatch.setattr(geofeat.bench.timing, "timing_table",
                        lambda frame, descriptors, *a, **k: timed.append(descriptors) or f"timed {descriptors}\n")
    seq, other = make_sequence(tmp_path / "seq"), make_sequence(tmp_path / "other", seed=1)
    out = tmp_path / "b"
    bench = ["bench", "--keypoints", "64", "--out", str(out)]
    assert main([*bench, str(seq), "--descriptors", "orb", "--timing"]) == 0
    assert (out / "timing.md").is_file()
    assert main([*bench, str(seq), "--descriptors", "orb,sift"]) == 0  # sift's rows added
    assert not (out / "timing.md").exists() and "timing.md" not in json.loads((out / ".geofeat-manifest.json")
                                                                               .read_text())["files"]
    assert main([*bench, str(seq), "--descriptors", "orb"]) == 0  # nothing added: nothing to remove or time
    assert main([*bench, str(seq), str(other), "--descriptors", "orb", "--timing"]) == 0
    assert timed[-1] == ("orb", "sift") and (out / "timing.md").read_text() == "timed ('orb', 'sift')\n"


def test_bench_resume_never_appends_to_a_results_csv_geofeat_did_not_write(tmp_path, capsys):
    """A results.csv and config.json copied into a folder (no manifest listing them) were resumed: the
    new rows were appended to the copy, and the copy then listed as geofeat's."""
    seq, other = make_sequence(tmp_path / "seq"), make_sequence(tmp_path / "other", seed=1)
    bench = ["bench", "--descriptors", "orb", "--keypoints", "64", "--out"]
    assert main([*bench, str(tmp_path / "b"), str(seq)]) == 0
    mine = tmp_path / "mine"
    mine.mkdir()
    for name in ("results.csv", "config.json"):
        shutil.copy(tmp_path / "b" / name, mine / name)
    before = _listing(mine)
    capsys.readouterr()
    assert main([*bench, str(mine), str(seq), str(other)]) == 2
    assert "holds results.csv, config.json, which geofeat did not write" in capsys.readouterr().err
    assert _listing(mine) == before


def test_bench_never_appends_rows_through_a_symbolic_link(tmp_path, capsys, monkeypatch):
    """`append_line_durably` followed a results.csv that is a symbolic link, appending the rows to the
    file it points to; a resumed bench with such a results.csv (listed as its own) did so."""
    import geofeat.bench.runner as runner
    from geofeat.outputs import append_line_durably

    elsewhere = tmp_path / "elsewhere.csv"
    elsewhere.write_text("a user's table\n")
    (tmp_path / "link.csv").symlink_to(elsewhere)
    with pytest.raises(ValueError, match=r"link\.csv is a symbolic link .*elsewhere\.csv"):
        append_line_durably(tmp_path / "link.csv", "x,y\n")
    assert elsewhere.read_text() == "a user's table\n"

    seq, other = make_sequence(tmp_path / "seq"), make_sequence(tmp_path / "other", seed=1)
    out = tmp_path / "b"
    bench = ["bench", "--descriptors", "orb", "--keypoints", "64", "--out", str(out)]
    assert main([*bench, str(seq)]) == 0
    shutil.move(out / "results.csv", elsewhere)
    (out / "results.csv").symlink_to(elsewhere)
    before = elsewhere.read_text()
    monkeypatch.setattr(runner, "_run_all", lambda *a: pytest.fail("a sequence was evaluated"))
    capsys.readouterr()
    assert main([*bench, str(seq), str(other)]) == 2
    assert f"--out: {out / 'results.csv'} is a symbolic link" in capsys.readouterr().err
    assert elsewhere.read_text() == before


@pytest.mark.parametrize("name", ["frame-000-master-rgb.png", "frame-009-depth.png", "sheet-RGB.png", "sub/x-rgb.png"])
def test_simulate_refuses_a_contact_sheet_named_as_a_frame_in_its_sequence_folder(tmp_path, capsys, name):
    """`simulate S --contact-sheet S/frame-000-master-rgb.png` replaced that frame with the sheet after
    the simulation; a sheet named <name>-rgb.png in S was read as a frame of its own."""
    argv = ["simulate", str(tmp_path / "s"), "--frames", "2", "--width", "64", "--height", "48", "--texture",
            "procedural", "--no-progress", "--contact-sheet", str(tmp_path / "s" / name)]
    assert main(argv) == 2
    assert "lies in the sequence folder" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, named", [
    (["simulate", "", "--frames", "2"], "a positional argument"),
    (["simulate", "sim", "--texture", ""], "--texture"),
    (["simulate", "sim", "--texture="], "--texture"),
    (["extract", "", "--out", "x"], "a positional argument"),
    (["simulate", "--overwrite", "", "--frames", "2"], "a positional argument"),  # after a flag taking no value
])
def test_an_empty_argument_is_refused_not_read_as_the_current_folder(tmp_path, monkeypatch, capsys, argv, named):
    """`geofeat simulate "$OUT"` with OUT unset passed "", which `Path` reads as ".": the sequence was
    written into the current folder. Every command refuses an empty value, naming where it was given."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert f"{named}: an empty value" in err
    assert list(tmp_path.iterdir()) == []
