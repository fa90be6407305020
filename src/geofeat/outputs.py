"""One output policy for every command: nothing a user had is deleted, nothing half-written is left.

- A result file is written to a temporary sibling and renamed over its final name only when it is
  complete (`atomic_file`), so an error or a kill never leaves a truncated file under the real name.
- A result folder is built in a temporary sibling folder and moved into place at the end
  (`replace_folder`); the folder gets a manifest, `.geofeat-manifest.json`, listing the files
  geofeat wrote there.
- An existing non-empty output folder is refused unless the user passes `--overwrite`
  (`check_out_dir`); `--overwrite` then removes only the files the manifest lists, never a file
  geofeat did not write.
- A command that writes single files beside the user's (`train`'s weights and the files beside them,
  `extract`'s features) records them apart in that folder's manifest (`record_written`,
  `written_by`): its own rerun may replace them, no other command's `--overwrite` does.
- Text results (csv, md, json) are written and read back as UTF-8 whatever the locale, as
  `append_line_durably` appends them: sequence names are folder names, which may be any letters.
- An output folder that holds a sequence's frames or TPS ground truth is refused by every command but
  the one that makes such folders (`check_out_dir`'s `writes`: simulate, groundtruth), input or not.
- One run at a time per output: `check_out_dir` and `check_out_file` claim the output for the run
  (`claim_output`, an exclusive lock), so a second run writing the same folder or file at the same
  time stops at once, naming the first, instead of replacing its files when it finishes.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import sys
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

#: Name of the file listing, relative to its folder, the files geofeat wrote into that folder.
MANIFEST = ".geofeat-manifest.json"


def plural(count: int, noun: str, nouns: str | None = None) -> str:
    """A count and its noun for report text: "1 sequence", "3 sequences", "0 sequences"; `nouns` is
    the plural where adding "s" is wrong ("class" -> "classes", "query" -> "queries")."""
    return f"{count} {noun if count == 1 else nouns or noun + 's'}"


def json_text(value, **kwargs) -> str:
    """`json.dumps(value, **kwargs)` with every NaN or infinite float written as null: json.dumps wrote
    the bare token NaN (an epoch without validation, a frame that failed), which is not JSON, so jq,
    JavaScript and other strict readers refused the whole report."""
    import math
    from numbers import Real

    def clean(v):
        if isinstance(v, Real) and not math.isfinite(v):  # numpy's floats too
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v

    return json.dumps(clean(value), allow_nan=False, **kwargs)


def _manifest_data(folder: str | Path) -> dict:
    """The manifest of `folder` as read (empty when it has none, or none that is a JSON object)."""
    try:
        data = json.loads((Path(folder) / MANIFEST).read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _inside(rel) -> bool:
    """Whether a manifest entry is a relative path that stays inside its folder."""
    return isinstance(rel, str) and bool(rel) and not Path(rel).is_absolute() and ".." not in Path(rel).parts


def read_manifest(folder: str | Path) -> list[str]:
    """Relative paths of the files geofeat wrote into `folder` as its result (empty when it has no
    readable manifest); not the single files of `written_by`."""
    files = _manifest_data(folder).get("files", [])
    return [f for f in files if _inside(f)] if isinstance(files, list) else []


def written_by(folder: str | Path) -> dict[str, str]:
    """{file name: command} of the single files a command recorded in the manifest of `folder`
    (`record_written`: `train`'s weights and the files beside them, `extract`'s features). They are
    geofeat's, so the command that wrote them may replace them, but no part of a result folder there:
    another command's `--overwrite` never replaces or removes them (`replace_folder` reads `files`)."""
    entries = _manifest_data(folder).get("written_by", {})
    if not isinstance(entries, dict):
        return {}
    return {rel: command for rel, command in entries.items() if _inside(rel) and isinstance(command, str)}


def write_manifest(folder: str | Path, files: Iterable[str], written: dict[str, str] | None = None) -> None:
    """Record (atomically) that geofeat wrote `files` (paths relative to `folder`) as the folder's
    result; the single files of `written_by` are kept (`written`: they instead)."""
    folder = Path(folder)
    written = written_by(folder) if written is None else written
    data = {"generator": "geofeat", "files": sorted(set(files))}
    if written:
        data["written_by"] = dict(sorted(written.items()))
    with atomic_file(folder / MANIFEST) as tmp:
        tmp.write_text(json.dumps(data, indent=1))


def record_written(paths: Iterable[str | Path], command: str) -> None:
    """Record in the manifest of each file's folder that `geofeat <command>` writes the file (before
    it writes it, so that an interrupted run is its own to replace): a command that writes single
    files beside the user's (`train`, `extract`), not a result folder. See `written_by`."""
    by_folder: dict[Path, list[str]] = {}
    for path in map(Path, paths):
        path = Path(os.path.abspath(path))
        by_folder.setdefault(path.parent, []).append(path.name)
    for folder, names in by_folder.items():
        folder.mkdir(parents=True, exist_ok=True)
        write_manifest(folder, read_manifest(folder), {**written_by(folder), **dict.fromkeys(names, command)})


def was_written_by(path: str | Path, command: str) -> bool:
    """Whether the manifest of the folder of `path` records that `geofeat <command>` wrote it (`record_written`)."""
    path = Path(os.path.abspath(path))
    return written_by(path.parent).get(path.name) == command


def add_to_manifest(folder: str | Path, files: Iterable[str | Path]) -> None:
    """Add files (absolute, or relative to `folder`) to the folder's manifest."""
    folder = Path(folder)
    rel = [str(Path(f).relative_to(folder)) if Path(f).is_absolute() else str(f) for f in files]
    write_manifest(folder, read_manifest(folder) + rel)


def foreign_entries(folder: str | Path) -> list[str]:
    """Entries of `folder` (files, or folders holding such files) that its manifest does not list."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    ours = set(read_manifest(folder)) | {MANIFEST}
    foreign = []
    for path in sorted(folder.rglob("*")):
        rel = str(path.relative_to(folder))
        if path.is_dir() and not path.is_symlink():
            continue
        # a killed run's temporary file or folder (`partial_name`), and what is in it, is not the user's
        if rel not in ours and not any(part.startswith(".geofeat-partial") for part in Path(rel).parts):
            foreign.append(rel)
    return foreign


def _via_symlink(folder: Path, rel: str) -> bool:
    """Whether a folder on the way from `folder` to `folder / rel` is a symbolic link (so the path
    leads out of `folder`, perhaps into a folder of the user's)."""
    return any((folder / part).is_symlink() for part in Path(rel).parents if part != Path("."))


#: The open lock file (descriptor, path) of each output this process has claimed (`claim_output`), by
#: resolved path.
_CLAIMS: dict[str, tuple[int, Path]] = {}
#: Whether `release_outputs` is registered to run at exit (on the first claim).
_RELEASE_AT_EXIT = False


def lock_file(path: str | Path) -> Path:
    """The lock file that a run writing the output `path` holds (`claim_output`): one per resolved
    absolute path (symbolic links on the way followed, so two spellings of one folder share it), in a
    folder of this user's under the system's temporary folder, never beside the user's files."""
    key = os.path.realpath(os.path.abspath(path))
    user = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    return Path(tempfile.gettempdir()) / f"geofeat-locks-{user}" / f"{hashlib.sha256(key.encode()).hexdigest()[:32]}.lock"


def claim_output(path: str | Path, what: str = "--out") -> None:
    """Claim the output folder or file `path` for this run, until `release_outputs` (the command line
    calls it when a command ends) or the process ends: a second geofeat process that claims the same
    path meanwhile gets a ValueError naming this one. Without it, two runs writing one new `--out` at
    once each built their result in a temporary folder, and the second to finish replaced the files
    of the first (they are geofeat's own, listed in the manifest) with no word. The lock is the
    operating system's (`flock`), so a run that is killed never blocks the next; on a system without
    `fcntl` (Windows) nothing is claimed. Claiming a path this process holds already does nothing."""
    try:
        import fcntl
    except ImportError:
        return
    key = os.path.realpath(os.path.abspath(path))
    if key in _CLAIMS:
        return
    lock = lock_file(path)
    try:
        lock.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError:
        return  # no temporary folder to lock in: run unguarded, as before
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o600)
        except OSError:
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise ValueError(f"{what}: {path} is being written by another geofeat run ({_holder(lock)}); wait for "
                             "it to end, or choose another name") from None
        try:  # the holder we waited on may have removed the file in between (`release_outputs`): lock the new one
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except OSError:
            same = False
        if same:
            break
        os.close(fd)
    program = Path(sys.argv[0]).name if sys.argv and sys.argv[0] not in ("", "-c") else "python"
    text = f"process {os.getpid()}: {' '.join([program, *sys.argv[1:]])}"  # `geofeat bench ...`, or a script's
    os.ftruncate(fd, 0)
    os.write(fd, text[:500].encode(errors="replace"))
    global _RELEASE_AT_EXIT
    if not _RELEASE_AT_EXIT:  # a script's claims (no command line releases them) go at exit, lock files included
        import atexit

        atexit.register(release_outputs)
        _RELEASE_AT_EXIT = True
    _CLAIMS[key] = fd, lock


def _holder(lock: Path) -> str:
    """Who holds `lock`, as its holder wrote it (process id and command line)."""
    try:
        text = lock.read_text(errors="replace").strip()
    except OSError:
        text = ""
    return text or "a process that has just started"


def release_outputs() -> None:
    """Release every output this process has claimed (`claim_output`), and remove their lock files."""
    if not _CLAIMS:
        return
    import fcntl

    for key, (fd, lock) in list(_CLAIMS.items()):
        try:
            if os.stat(lock).st_ino == os.fstat(fd).st_ino:
                lock.unlink()
        except OSError:
            pass
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
        del _CLAIMS[key]


def check_out_file(path: str | Path, overwrite: bool = False, what: str = "--out", claim: bool = True) -> Path:
    """Refuse an output file path that names a folder, sits under a file, or exists (unless `overwrite`;
    a symbolic link, even a dangling one, exists), and claim it for this run (`claim_output`; `claim`
    False: the caller has claimed what the file belongs to, as `extract` claims its prefix once for
    its one file per frame)."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{what}: {path} is a folder; expected a file name")
    for parent in path.parents:
        if parent.exists() and not parent.is_dir():
            raise ValueError(f"{what}: {parent} is a file, so {path} cannot be written")
    if claim:  # before the existence check: a concurrent run may be about to write it
        claim_output(path, what)
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise ValueError(f"{what}: {path} exists; pass --overwrite to replace it, or choose another name")
    check_writable(path.parent, what)
    return path


def check_writable(folder: str | Path, what: str = "--out") -> None:
    """Refuse, before any work, a folder that the results cannot be written into: `folder` itself
    when it exists, else its nearest existing parent (where the missing folders are made) must be
    writable. Without this check a read-only folder failed only at the end, after all the work
    (hours, for `groundtruth` or `train`), naming a temporary file (".geofeat-partial-...")."""
    folder = Path(os.path.abspath(folder))
    existing = next((p for p in (folder, *folder.parents) if p.exists()), None)
    if existing is None or not existing.is_dir():
        return  # a file in the way: `check_out_file` and `check_out_dir` name it
    if not os.access(existing, os.W_OK | os.X_OK):
        made = "" if existing == folder else f", where {folder} would be made"
        raise ValueError(f"{what}: cannot write into {existing}{made} (permission denied); make it writable or "
                         "choose another folder")


def foreign_clashes(folder: str | Path, files: Iterable[str]) -> list[str]:
    """Those of `files` (paths relative to `folder` that a result will be written to) that would
    replace something geofeat did not write there: an existing file its manifest does not list, or a
    file where a folder of the path must go, or a symbolic link to a folder (which would take the file
    out of `folder`)."""
    folder = Path(folder)
    ours = set(read_manifest(folder))
    clashes = []
    for rel in files:
        target = folder / rel
        blocked = [p for p in target.parents if folder in p.parents and p.exists() and not p.is_dir()]
        if (rel not in ours and (target.exists() or target.is_symlink())) or blocked or _via_symlink(folder, rel):
            clashes.append(rel)
    return clashes


def _refuse_clashes(folder: Path, clashes: list[str], what: str) -> None:
    """ValueError naming the `clashes` (`foreign_clashes`) a result would replace in `folder`, and the
    command that wrote each single file of geofeat's among them (`written_by`: `extract`'s features)."""
    if not clashes:
        return
    by = written_by(folder)
    listed = ", ".join(f"{rel} (written by `geofeat {by[rel]}`)" if rel in by else rel for rel in clashes[:5])
    whose = (f"{'is' if len(clashes) == 1 else 'are'} not among the results geofeat wrote there"
             if any(rel in by for rel in clashes) else "geofeat did not write")
    raise ValueError(f"{what}: {folder} holds {listed}{', ...' if len(clashes) > 5 else ''}, which {whose}; "
                     "--overwrite never replaces those: move them away or choose another folder")


#: Files whose presence at the top of an input folder make it a folder of data read file by file
#: (a sequence's frames, a texture folder, flat TPS files), inside which no result is written.
_DATA_FILES = ("*.png", "*.PNG", "*.jpg", "*.JPG", "*.jpeg", "*.JPEG")


def _holds_data_files(folder: Path) -> bool:
    """Whether `folder` holds images at its top level (`_DATA_FILES`)."""
    return any(next(folder.glob(pattern), None) is not None for pattern in _DATA_FILES)


def _read_as_sequence(folder: Path) -> bool:
    """Whether the commands read `folder`, a sub-folder of an input folder, as an input of its own:
    it holds a sequence's frames (`io.frame_names`) or TPS files (`groundtruth.sources`). Other
    images do not make it one: a results folder beside the sequences holds the plots geofeat wrote."""
    from .groundtruth.sources import _has_tps_files
    from .io import frame_names

    return folder.is_dir() and (bool(frame_names(folder)) or _has_tps_files(folder))


def _holds_sequences(folder: Path) -> bool:
    """Whether `folder` is a folder of sequences: a sub-folder of it is read as a sequence. An image
    beside them (a contact sheet) then does not make the folder one read image by image, as a
    texture folder is."""
    return any(_read_as_sequence(child) for child in folder.iterdir() if child.is_dir())


def _input_clash(folder: Path, inputs: Iterable[str | Path | None], replaced: bool = True) -> tuple[str, str] | None:
    """Why writing the result folder (or file) `folder` would put results among, or replace, the
    folders `inputs` the command reads (None entries, options left out, are passed over), and the
    harm, as (why, harm): `folder` is one of them or lies inside one that holds images itself (a
    sequence's frames, a texture folder: through any link; results among the user's files, where a
    later run may read them as inputs) or is, or lies inside, a sub-folder of one that is read as a
    sequence (`_read_as_sequence`; other sub-folders, a results folder with its plots, are not), or
    (when the result `replaced` the folder's earlier files, as `replace_folder` does) its manifest
    lists a file inside one; None when none of these."""
    here = folder.resolve()
    sources = [(given, Path(given).resolve()) for given in inputs if given is not None]
    for given, source in sources:
        if source == here:
            return f"{folder} is the input folder {given}", "writing the result there would replace it"
        # a new folder beside the sequences of a folder of sequences is fine (as COLMAP keeps sparse/
        # beside images/): the commands look for sequences in sub-folders holding frames only; inside one
        # of those sub-folders (a sequence of the folder given) it is not
        if source in here.parents:
            among = "the results would be written among its files"
            if _read_as_sequence(source) or (_holds_data_files(source) and not _holds_sequences(source)):
                return f"{folder} lies inside the input folder {given}", among
            inner = source / here.relative_to(source).parts[0]
            if _read_as_sequence(inner):
                if inner == here:
                    return f"{folder} is the input folder {inner}", "writing the result there would replace it"
                return f"{folder} lies inside the input folder {inner}", among
    listed = [(folder / rel).resolve() for rel in read_manifest(folder)] if replaced and folder.is_dir() else []
    for given, source in sources:
        if any(source in f.parents for f in listed):
            return (f"{folder} holds the input folder {given}, with files geofeat wrote",
                    "writing the result there would replace it")
    return None


def refuse_input_folder(folder: str | Path, inputs: Iterable[str | Path | None], what: str = "--out",
                        harm: str | None = None) -> None:
    """ValueError when the output folder (or file) `folder` is one of the folders `inputs` a command
    reads (sequences, folders of sequences, --tps-dir; None entries are passed over), lies inside
    one that holds images itself (a sequence, a texture folder) or inside a sequence of a folder of
    sequences (a folder beside those sequences is fine), or holds one among files geofeat wrote
    (`_input_clash`), whatever `--overwrite` says. Every command that reads folders checks its
    output with it before any work (`check_out_dir`, through its `inputs`). `harm`: what a command that adds its files to the folder (bench, extract) would do
    there, for the message; None: the harm `_input_clash` names (replacing the input, or writing
    among its files)."""
    clash = _input_clash(Path(folder), inputs, replaced=harm is None)
    if clash:  # before the "pass --overwrite" advice, which would delete the input
        why, default = clash
        raise ValueError(f"{what}: {why}; {harm or default}: choose another folder")


#: The kinds of data folder a command may write (`check_out_dir`'s `writes`), as `_data_kind` names them.
SEQUENCE, GROUND_TRUTH, RESULTS = "sequence", "ground truth", "results"


def _data_kind(folder: Path) -> tuple[str, list[str]] | None:
    """(kind, a few of its files) when `folder` holds a sequence's frames (`io.frame_names`: SEQUENCE)
    or TPS ground truth (`groundtruth.sources`: GROUND_TRUTH), the data that `simulate` and
    `groundtruth` write and the other commands read; None otherwise."""
    from .groundtruth.sources import _has_tps_files
    from .io import RGB_SUFFIX, frame_names

    if not folder.is_dir():
        return None
    frames = frame_names(folder)
    if frames:
        return SEQUENCE, [f"{n}{RGB_SUFFIX}" for n in frames[:3]]
    if _has_tps_files(folder):
        return GROUND_TRUTH, sorted(p.name for p in (*folder.glob("*_theta.npy"), *folder.glob("*_objmask.png")))[:3]
    return None


def check_out_dir(path: str | Path, overwrite: bool = False, what: str = "--out", strict: bool = False,
                  files: Iterable[str] = (), inputs: Iterable[str | Path | None] = (), writes: str = RESULTS) -> Path:
    """Check an output folder before any work: it must not be a file, and an existing non-empty folder
    needs `overwrite`. With `strict`, a folder holding files geofeat did not write (not in its
    manifest) is refused even with `overwrite`, because leftovers would mix with the new output.
    `files`: the result files the command writes at fixed names (relative paths); with `overwrite`,
    one of them that geofeat did not write is refused (`foreign_clashes`) rather than replaced, and
    one in a sub-folder (`track`'s OUT/<sequence>/...) that lies inside an input folder is refused
    (`refuse_input_folder`). `inputs`: the folders the command reads; an output folder that is one of
    them (a simulated sequence, whose files geofeat wrote), or lies inside one, is refused, with or
    without `overwrite` (`refuse_input_folder`). `writes`: the kind of folder the command makes
    (SEQUENCE: `simulate`; GROUND_TRUTH: `groundtruth`; RESULTS: the others); a folder holding another
    kind (`_data_kind`: a simulated sequence, whose frames are in its manifest, is not an input of
    `match --out` but was replaced by its results with `--overwrite`) is refused, with or without it."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{what}: {path} is a file, not a folder")
    if path.is_symlink() and not path.exists():  # the result, made in a temporary folder, cannot be moved there
        raise ValueError(f"{what}: {path} is a symbolic link to {os.readlink(path)}, which does not exist: make that "
                         "folder, or choose another")
    refuse_input_folder(path, inputs, what)
    files = list(files)
    for sub in dict.fromkeys((path / rel).parent for rel in files if len(Path(rel).parts) > 1):
        refuse_input_folder(sub, inputs, what)  # OUT/<sequence>/ with OUT the folder above an input sequence
    held = _data_kind(path)
    if held is not None and held[0] != writes:  # before the "pass --overwrite" advice, which would replace it
        kind, some = held
        data = {SEQUENCE: "a sequence's frames", GROUND_TRUTH: "ground truth (TPS files)"}[kind]
        made = {SEQUENCE: "a simulated sequence", GROUND_TRUTH: "ground truth", RESULTS: "results"}[writes]
        raise ValueError(f"{what}: {path} holds {data} ({', '.join(some)}, ...); writing {made} there would replace "
                         "or mix with them, with or without --overwrite: choose another folder")
    for parent in path.parents:
        if parent.exists() and not parent.is_dir():
            raise ValueError(f"{what}: {parent} is a file, so the folder {path} cannot be created")
    claim_output(path, what)  # before the emptiness check: a concurrent run may be about to fill it
    if path.is_dir() and any(path.iterdir()):
        if not overwrite:
            raise ValueError(f"{what}: {path} exists and is not empty; pass --overwrite to replace what geofeat "
                             "wrote there, or choose another folder")
        foreign = foreign_entries(path)
        if strict and foreign:
            raise ValueError(f"{what}: {path} holds files geofeat did not write ({', '.join(foreign[:5])}"
                             f"{', ...' if len(foreign) > 5 else ''}); --overwrite never deletes those: move them "
                             "away or choose another folder")
        _refuse_clashes(path, foreign_clashes(path, files), what)
    check_writable(path, what)
    return path


def write_picture(path: str | Path, picture: np.ndarray) -> None:
    """Write an image file (its extension picks the format) whole or not at all (`atomic_file`): an
    interrupt leaves no truncated file, and a symbolic link at `path` is replaced, not the file it
    points to. OSError when OpenCV cannot write it (the format, or the disk)."""
    import cv2

    with atomic_file(path) as tmp:
        if not cv2.imwrite(str(tmp), picture):
            raise OSError(f"cannot write the picture {path}")


def write_npz(path: str | Path, arrays: dict, compressed: bool = False) -> None:
    """Write `arrays` to an .npz archive at exactly `path`, whole or not at all (`atomic_file`). Through
    a file object: given a name, numpy appends ".npz" unless it already ends so in lower case ("A.NPZ"
    became "A.NPZ.npz")."""
    import numpy as np

    with atomic_file(path) as tmp, open(tmp, "wb") as fh:
        (np.savez_compressed if compressed else np.savez)(fh, **arrays)


def partial_name(path: Path) -> Path:
    """The temporary sibling that a result is written to before it is renamed to `path`."""
    path = Path(path)
    if path.name in ("", ".", ".."):  # ".", "..", "/": no name to put beside; the absolute path has one
        path = Path(os.path.abspath(path))
    return path.with_name(f".geofeat-partial-{os.getpid()}-{path.name}")


def _running(pid: int) -> bool:
    """Whether a process `pid` exists here (on Windows, where signal 0 would end it, always True)."""
    if os.name == "nt":
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process
        return True
    return True


_PARTIAL = re.compile(r"\.geofeat-partial-(\d+)-(.+)")  # `partial_name`: process id, then the final name


def clear_stale_partials(*paths: str | Path) -> None:
    """Remove the temporary siblings of `paths` (`partial_name`) that a geofeat process killed while
    writing them left behind (SIGKILL or a power cut run no clean-up): those of a process id no longer
    running; a running one's may be a concurrent run's and stay. Each folder is listed once, however
    many of its files are given (`geofeat extract` gives one per frame)."""
    wanted: dict[Path, set[str]] = {}
    for path in map(Path, paths):
        if path.name in ("", ".", ".."):  # as in `partial_name`
            path = Path(os.path.abspath(path))
        wanted.setdefault(path.parent, set()).add(path.name)
    for folder, names in wanted.items():
        if not folder.is_dir():
            continue
        for sibling in folder.iterdir():
            found = _PARTIAL.fullmatch(sibling.name)
            if found is None or found[2] not in names:
                continue
            pid = int(found[1])
            if pid != os.getpid() and not _running(pid):
                if sibling.is_dir() and not sibling.is_symlink():
                    shutil.rmtree(sibling, ignore_errors=True)
                else:
                    sibling.unlink(missing_ok=True)


@contextmanager
def signals_deferred() -> Iterator[None]:
    """Hold Ctrl-C (SIGINT) and SIGTERM until the block ends, then act on them as before: for a few
    renames that must happen all or none (`extract`'s one file per frame: stopped half way, the
    rerun's features and the earlier run's stayed mixed, frame by frame, with no word). The handlers
    are swapped for ones that only take note (blocking the signals would not do: the kernel hands a
    process's signal to any thread that does not block it, numba's and torch's among them). Off the
    main thread, where handlers cannot be set, it does nothing; SIGKILL cannot be held."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    held = [sig for sig in (signal.SIGINT, getattr(signal, "SIGTERM", None)) if sig is not None]
    before = {sig: signal.signal(sig, lambda number, _frame: caught.append(number)) for sig in held}
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(caught):  # each once, in the order they came
            handler = before[sig]
            if callable(handler):
                handler(sig, None)  # Python's own SIGINT handler raises KeyboardInterrupt here
            elif handler == signal.SIG_DFL:
                os.kill(os.getpid(), sig)  # the default action (SIGTERM: the process ends)


@contextmanager
def atomic_file(path: str | Path) -> Iterator[Path]:
    """Yield a temporary sibling path to write; on success it replaces `path` (os.replace), on any
    error (or interrupt) it is removed and `path` is left as it was. IsADirectoryError naming `path`
    when it is a folder, before anything is written (the replace at the end failed, naming the
    temporary file)."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a folder; expected the path of a file to write")
    path.parent.mkdir(parents=True, exist_ok=True)
    clear_stale_partials(path)
    tmp = partial_name(path)
    if tmp.exists():
        tmp.unlink()
    try:
        yield tmp
        if tmp.exists():
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def temporary_folder(out: str | Path) -> Path:
    """A fresh, empty temporary sibling folder of `out` to build a result folder in; inside `out`
    when `out` is an existing folder whose parent is not writable (`--out /scratch/me` under a
    read-only /scratch), where a sibling failed at the end of the run (`replace_folder` moves the
    files out of it)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = partial_name(out)
    if out.is_dir() and not os.access(tmp.parent, os.W_OK | os.X_OK):
        tmp = out / tmp.name
    clear_stale_partials(tmp.parent / Path(os.path.abspath(out)).name)
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    return tmp


def _prune_empty_parents(folder: Path, rel: str) -> None:
    """Remove the folders of `rel` inside `folder` that are left empty, deepest first."""
    for parent in (folder / rel).parents:
        if parent == folder or folder not in parent.parents:
            break
        try:
            parent.rmdir()  # only when empty
        except OSError:
            break


def _removable(folder: Path, rel: str) -> bool:
    """A manifest entry that is a file (or link) inside `folder`, not reached through a linked folder."""
    path = folder / rel
    return (path.is_file() or path.is_symlink()) and not _via_symlink(folder, rel)


def remove_written(folder: str | Path) -> None:
    """Remove the files that the manifest of `folder` lists (and the folders that leaves empty); never
    a file reached through a symbolic link to a folder, which may be the user's."""
    folder = Path(folder)
    for rel in read_manifest(folder):
        if _removable(folder, rel):
            (folder / rel).unlink()
            _prune_empty_parents(folder, rel)
    if written_by(folder):  # the single files another command wrote there stay, and so does their record
        write_manifest(folder, [])
    else:
        (folder / MANIFEST).unlink(missing_ok=True)


def replace_folder(tmp: str | Path, out: str | Path) -> Path:
    """Move the finished folder `tmp` into `out`. Files geofeat wrote earlier into `out` (its manifest)
    are replaced; every other file there stays, and a result that would replace one of them is
    refused (ValueError, `out` untouched). The new manifest lists the files moved in. An error or an
    interrupt while moving puts the earlier files back (the new ones return to `tmp`), and until the
    move is complete the manifest lists both, so a rerun with --overwrite can always clean up."""
    tmp, out = Path(tmp), Path(out)
    files = [str(p.relative_to(tmp)) for p in sorted(tmp.rglob("*")) if p.is_file() and p.name != MANIFEST]
    if not out.exists():
        write_manifest(tmp, files)
        os.replace(tmp, out)
        return out
    _refuse_clashes(out, foreign_clashes(out, files), "--out")  # before anything is moved
    old = [rel for rel in read_manifest(out) if _removable(out, rel)]
    backup = tmp / f".geofeat-partial-old-{os.getpid()}"
    write_manifest(out, old + files)
    moved_old: list[str] = []
    moved_new: list[str] = []
    try:
        for rel in old:
            (backup / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(out / rel, backup / rel)
            moved_old.append(rel)
            _prune_empty_parents(out, rel)  # a new file may take the name of a folder left empty
        for rel in files:
            target = out / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp / rel, target)
            moved_new.append(rel)
    except BaseException:
        for rel in reversed(moved_new):
            os.replace(out / rel, tmp / rel)
        for rel in reversed(moved_old):
            (out / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(backup / rel, out / rel)
        write_manifest(out, old)
        raise
    write_manifest(out, files)
    shutil.rmtree(tmp, ignore_errors=True)
    return out


@contextmanager
def output_folder(out: str | Path) -> Iterator[Path]:
    """Build a result folder: yields a temporary sibling folder to write into, which replaces what
    geofeat wrote in `out` when the block ends without error (`replace_folder`); on error it is
    removed and `out` is untouched. Call `check_out_dir` first."""
    tmp = temporary_folder(out)
    try:
        yield tmp
        replace_folder(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def append_line_durably(path: str | Path, text: str) -> None:
    """Append complete csv lines (`text` ends with a newline) in one write, then flush and fsync, so a
    kill leaves either all of them or a torn tail that the reader drops. ValueError when `path` is a
    symbolic link: the lines would go into whatever file it points to, perhaps one of the user's."""
    if not text.endswith("\n"):
        raise ValueError("text: must end with a newline")
    if os.path.islink(path):  # and O_NOFOLLOW where there is one: no link made in between is followed either
        raise ValueError(f"{path} is a symbolic link (to {os.readlink(path)}); geofeat appends only to a file of its "
                         "own there: remove the link, or choose another folder")
    fd = os.open(str(path), os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
    try:
        data = text.encode()
        written = 0
        while written < len(data):
            written += os.write(fd, data[written:])
        os.fsync(fd)
    finally:
        os.close(fd)
