"""`geofeat train`: train GeoPatch on simulated sequences."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..outputs import plural
from .options import depth_profile_option, keypoint_count, positive_number, whole_number


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `train` to an argparse subparsers object; returns its parser."""
    p = subparsers.add_parser("train", help="train GeoPatch on simulated sequences (see `geofeat simulate`)")
    p.add_argument("--data", nargs="+", required=True, help="simulated sequence folders, or folders of them")
    p.add_argument("--val", nargs="+", default=None,
                   help="held-out simulated sequences for the per-epoch matching score (of SIFT keypoints with "
                        "one-way nearest-neighbour matches, not the benchmark's figure)")
    p.add_argument("--out", required=True, help="weights file to write (e.g. geopatch.pt)")
    p.add_argument("--overwrite", action="store_true",
                   help="start anew over an earlier run: replace an existing OUT file (and the OUT.ckpt, OUT.json, "
                        "OUT.png, OUT.patches.npz that `train` wrote; another file of those names is refused); the "
                        "earlier OUT, OUT.ckpt, OUT.json and OUT.png are removed when this run writes its first "
                        "file, so an interrupted run leaves no earlier weights beside its own checkpoint")
    p.add_argument("--epochs", type=whole_number(1), default=10, help="passes of --steps batches (default 10)")
    p.add_argument("--steps", type=whole_number(1), default=200, help="batches per epoch (default 200)")
    p.add_argument("--batch-size", type=whole_number(1), default=1000,
                   help="triplets per batch, at least 2 with --mining hardest (default 1000, the paper's)")
    p.add_argument("--lr", type=positive_number, default=0.1, help="SGD learning rate (default 0.1, the paper's)")
    p.add_argument("--mining", choices=("random", "hardest"), default="random",
                   help="negatives: random with anchor swap (the paper) or the hardest in the batch")
    p.add_argument("--augment-shift", action="store_true",
                   help="random circular shifts along the angle axis (GeoPatch and --net logpolar; refused with "
                        "--net tfeat, whose Cartesian patches have none)")
    p.add_argument("--augment-photometric", action="store_true", help="random per-patch gamma and noise")
    p.add_argument("--init", default=None, help="start from these GeoPatch weights ('shipped': geofeat's own)")
    p.add_argument("--channels", type=whole_number(1), nargs=3, default=None, metavar=("C1", "C2", "C3"),
                   help="channels of the three convolutions (default 16 32 64, or with --init the weights' own; "
                        "the paper's and the shipped weights': 32 64 128)")
    p.add_argument("--no-angle-pool", action="store_true",
                   help="flatten instead of max-pooling over angle (ablation; with --init: as the weights do)")
    p.add_argument("--keypoints", type=keypoint_count, default=512, help="SIFT keypoints per reference frame (default 512)")
    p.add_argument("--seed", type=whole_number(0, 2**64 - 1), default=0, help="random seed (default 0)")
    p.add_argument("--net", choices=("geopatch", "tfeat", "logpolar"), default="geopatch",
                   help="network: GeoPatch (geodesic patches) or an image-patch baseline (tfeat-sim, logpolar-sim)")
    p.add_argument("--resume", action="store_true", help="continue from OUT.ckpt (with the same options)")
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda when available)")
    depth_profile_option(p, None)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Train GeoPatch (or an image-patch baseline) and write the weights, a loss plot and a log.
    The options, OUT, the --init weights and the data folders are checked before any work."""
    from functools import partial

    from ..descriptors.geopatch import GeoPatchConfig
    from ..gpu import torch_device
    from ..inputs import check_weights_path
    from ..io import sequence_digest
    from ..outputs import refuse_input_folder
    from ..train.dataset import PatchSet, build_patch_set, check_simulated, validation_pairs, warn_if_not_held_out
    from ..train.loop import (TrainConfig, check_augmentation, check_train_config, check_train_out, load_init,
                              load_resume_state, record_run_files, remove_earlier_run, removed_line, train)

    # the numbers are checked by their argparse types; one rule spans two options
    if args.mining == "hardest" and args.batch_size < 2:
        raise ValueError(f"--batch-size: --mining hardest takes its negatives from the batch's other pairs, so it "
                         f"needs at least 2 triplets per batch, got {args.batch_size}")
    channels_given = args.channels is not None
    if args.init is not None:  # "" said "no GeoPatch checkpoint at ."
        check_weights_path(args.init, "--init", "--init shipped")
    if args.net != "geopatch":  # the image-patch nets have their own fixed widths and read no depth
        unused = [flag for flag, given in (("--channels", channels_given), ("--no-angle-pool", args.no_angle_pool),
                                           ("--depth-profile", args.depth_profile is not None)) if given]
        if unused:
            raise ValueError(f"{', '.join(unused)}: GeoPatch's options, which --net {args.net} (an image-patch "
                             "network of fixed widths on image patches) would ignore; leave them out")
    # fine-tuning takes the shape of the weights it starts from: their widths, unless --channels names others
    # (refused by `load_init` below), and their angle pooling (weights that flatten cannot max-pool)
    start = _init_config(args.init) if args.init is not None and args.net == "geopatch" else None
    if not channels_given:
        args.channels = (16, 32, 64) if start is None else start.channels
    angle_pool = not args.no_angle_pool and (start is None or start.angle_pool)
    if start is not None and args.no_angle_pool and start.angle_pool:  # it said "init: the weights' network
        # GeoPatchConfig(..., angle_pool=True, ...) differs from the requested GeoPatchConfig(...)"
        raise ValueError(f"--no-angle-pool: the --init weights {args.init} max-pool over angle, and a network that "
                         "flattens instead has another shape; leave --no-angle-pool out to fine-tune them")
    config = TrainConfig(
        epochs=args.epochs, steps_per_epoch=args.steps, batch_size=args.batch_size, lr=args.lr,
        mining=args.mining, augment_shift=args.augment_shift, seed=args.seed,
        augment_photometric=args.augment_photometric,
        net=GeoPatchConfig(channels=tuple(args.channels), angle_pool=angle_pool),
    )
    check_train_config(config)
    try:
        check_augmentation(config, args.net)
    except ValueError as error:  # before the patches, named by the flag
        raise ValueError(f"--augment-shift: {str(error).removeprefix('augment_shift: ')}"
                         f" (--net {args.net})") from None
    if args.device is not None:  # torch's own errors came after the patches were built, as tracebacks
        try:
            torch_device(args.device)
        except ValueError:
            raise ValueError(f"--device: expected cpu, cuda or cuda:N, got {args.device!r}") from None
        except RuntimeError as error:  # no CUDA GPU: a user error here
            raise ValueError(f"--device: {error}") from None
    cache = Path(str(args.out) + ".patches.npz")  # the patches, kept for --resume
    refuse_input_folder(args.out, [*args.data, *(args.val or ())])  # the weights among the training sequences
    check_train_out(args.out, args.overwrite, args.resume, also=(".patches.npz",))
    checkpoint = Path(str(args.out) + ".ckpt")
    state = None  # the state of the run --resume continues
    if args.resume and checkpoint.is_file():
        state = load_resume_state(checkpoint, config)  # a corrupt or other run's checkpoint, before the patches
        _check_resumed_network(state, checkpoint, args.net, config)
    if args.init is not None:
        if args.net != "geopatch":
            raise ValueError(f"--init: fine-tuning starts from GeoPatch weights; not with --net {args.net}")
        try:
            load_init(args.init, config.net)
        except ValueError as error:
            if channels_given and "differs from the requested" in str(error):
                raise ValueError(f"--init: {error}; leave --channels out to train the weights' own widths") from None
            if str(error).startswith("weights: "):  # the file's own message, named by the flag that gave it
                raise ValueError(f"--init: {str(error).removeprefix('weights: ')}") from None
            raise
        if args.overwrite and not args.resume:
            _check_init_survives(args.init, args.out)

    net = None  # geodesic polar patches with the depth profile asked for (default: per sequence)
    build = partial(build_patch_set, depth_config=args.depth_profile)
    make_validation = partial(validation_pairs, depth_config=args.depth_profile)
    if args.net != "geopatch":  # image-patch baselines (tfeat-sim, logpolar-sim) on the same data
        from ..descriptors.image_patch_nets import ImagePatchNet, default_config
        from ..train.imagepatches import build_image_patch_set, image_validation_pairs

        import torch

        torch.manual_seed(args.seed)  # its starting weights: `train` seeds torch only after they are drawn
        net = ImagePatchNet(default_config(args.net))
        build = partial(build_image_patch_set, arch=args.net)
        make_validation = partial(image_validation_pairs, arch=args.net)
    val_folders = check_simulated(args.val, "--val") if args.val else []
    data_folders = check_simulated(args.data, "--data")
    warn_if_not_held_out(data_folders, val_folders, "--val", "--data")
    # what the patches are built from (the --data folders and their frames' `sequence_digest`), and the --val
    # sequences that score every epoch (folders and digests): a resumed run takes the cached patches only when
    # they match
    source = {"data": [str(f.resolve()) for f in data_folders], "keypoints": args.keypoints,
              "depth_profile": args.depth_profile, "net": args.net,
              "data_digests": [sequence_digest(f) for f in data_folders],
              "val": [[str(f.resolve()), sequence_digest(f)] for f in val_folders]}
    cached = args.resume and cache.is_file()
    if cached:
        data = PatchSet.load(cache)
        _check_cached_source(cache, data.source, source)
    if state is not None:  # what the checkpoint's run was trained on (`train` records it), with or without a cache
        _check_resumed_source(checkpoint, state.get("source"), source, cached)
    if cached:
        print(f"training patches: {len(data)} from {cache}")
    else:
        data = build(args.data, n_keypoints=args.keypoints)
        _check_triplets(data, args.keypoints)  # before the cache, which a rerun would have to --overwrite
        if args.overwrite and not args.resume:  # this run's first file: the earlier run's weights go with it
            removed = remove_earlier_run(args.out)
            if removed:
                print(removed_line(removed))
        record_run_files(args.out, also=(".patches.npz",))
        data.source = source
        data.save(cache)
        print(f"training patches: {len(data)} of {plural(len(np.unique(data.ids)), 'surface point')} "
              f"(cached in {cache})")
    validation = make_validation(args.val) if args.val else None
    if args.val and not validation:  # each epoch then said "no validation pairs", the end "validation MS nan"
        import warnings

        warnings.warn("--val: no pair of these sequences could be scored (no SIFT keypoint of a target frame has "
                      "ground truth in a reference with keypoints), so this run has no validation MS; larger or "
                      "more textured --val sequences give pairs", UserWarning, stacklevel=2)
    history = train(data, args.out, config, validation=validation, resume=args.resume, device=args.device, net=net,
                    init=args.init, overwrite=args.overwrite)
    scored = (f"validation MS {history['val_ms'][-1]:.3f} ({history['val_measure']})" if validation else
              "no validation pairs in --val" if args.val else "no --val sequences")
    print(f"wrote {args.out} (final loss {history['loss'][-1]:.4f}, {scored}), "
          f"{args.out}.png and {args.out}.json")
    return 0


def _check_triplets(data, keypoints: int) -> None:
    """ValueError naming --data and --keypoints when the patches cannot form a triplet (fewer than 2
    surface points seen in 2 frames); it came after the patch cache was written, as 'data: ...'."""
    from ..train.loop import TripletSampler

    try:
        TripletSampler(data.ids, np.random.default_rng(0))
    except ValueError:
        _, counts = np.unique(data.ids, return_counts=True)
        raise ValueError(f"--data: {plural(int((counts >= 2).sum()), 'surface point')} seen in 2 frames or more "
                         "(a triplet needs 2); simulate more or larger sequences, or raise --keypoints "
                         f"({keypoints} now)") from None


def _check_resumed_source(checkpoint: Path, recorded: dict | None, wanted: dict, cached: bool) -> None:
    """--resume continues the run of `checkpoint`: refuse it when that run was trained on patches of
    other --data, --keypoints, --depth-profile or --net, or scored on other --val, than this run names
    (`_check_cached_source`'s rules, on what `train` recorded in the checkpoint). Without a patch cache
    the patches were rebuilt from whatever --data then held, unchecked. A checkpoint that records
    nothing (an older geofeat's) is warned of when there is no cache to check either."""
    if recorded is None:
        if not cached:
            import warnings

            warnings.warn(f"--resume: {checkpoint} does not record what its run was trained on (written by an older "
                          "geofeat), and its patch cache is gone: the patches are built anew from --data as it is "
                          "now, which nothing can check against that run", UserWarning, stacklevel=2)
        return
    _check_cached_source(checkpoint, recorded, wanted, "the state")


def _check_cached_source(cache: Path, cached: dict | None, wanted: dict, holds: str = "the patches") -> None:
    """--resume trains on the patches cached by the run it resumes: refuse them when they were built
    from other --data, --keypoints, --depth-profile or --net than this run names, or from the same
    --data folders with other frames (simulated again since: they were used silently, and the new
    options or frames ignored), or when the run scored its epochs on other --val sequences, or on the
    same folders with other frames (its validation curve would join two measures). A cache that
    records nothing (an older geofeat's) is used; one without --val or the --data digests (from
    before they were recorded) is not checked for them. `holds`: what `cache` holds, for the message
    (`_check_resumed_source` checks a checkpoint by these rules)."""
    if cached is None:
        return
    flags = {"data": "--data", "keypoints": "--keypoints", "depth_profile": "--depth-profile", "net": "--net",
             "data_digests": "--data", "val": "--val"}
    optional = ("val", "data_digests")  # recorded since: checked where the cache has them

    def shown(key: str, value) -> str:
        if key == "val":  # [[folder, digest], ...]
            return " ".join(Path(p).name for p, _ in value) or "left out"
        if key == "data":
            return " ".join(Path(p).name for p in value)
        return "left out" if value is None else str(value)

    def change(key: str, flag: str) -> str:
        before, now = cached.get(key), wanted.get(key)
        if key == "data_digests":  # the same folders (checked first), other frames
            moved = [Path(p).name for p, d, e in zip(wanted["data"], before, now) if d != e]
            return f"{flag} {' '.join(moved)}: other frames than that run's (simulated again or edited since)"
        if key == "val" and [p for p, _ in before] == [p for p, _ in now]:  # the same folders, other frames
            moved = [Path(p).name for (p, d), (_, e) in zip(before, now) if d != e]
            return f"{flag} {' '.join(moved)}: other frames than that run's (simulated again or edited since)"
        return f"{flag} {shown(key, before)}, not {shown(key, now)}"

    changed = [change(k, flag) for k, flag in flags.items()
               if (k in cached or k not in optional) and cached.get(k) != wanted.get(k)
               and not (k == "data_digests" and cached.get("data") != wanted.get("data"))]
    if not changed:
        return
    raise ValueError(f"--resume: {cache} holds {holds} of a run with other options ({'; '.join(changed)}); "
                     "resume with that run's options, or pass --overwrite (without --resume) to start anew")


def _check_resumed_network(state: dict, checkpoint: Path, net_name: str, config) -> None:
    """ValueError when the weights in a --resume checkpoint are not those of the --net this run
    trains (a GeoPatch run resumed with --net tfeat, or the reverse): their settings are the same
    (`TrainConfig` holds no network name), so without a patch cache that names --net the weights
    were refused by `train` only after the patches of every --data sequence had been built."""
    from ..descriptors.geopatch import GeoPatchNet
    from ..descriptors.image_patch_nets import ImagePatchNet, default_config
    from ..inputs import error_summary

    net = GeoPatchNet(config.net) if net_name == "geopatch" else ImagePatchNet(default_config(net_name))
    try:
        net.load_state_dict(state["state_dict"])
    except Exception as error:  # noqa: BLE001 - missing or misshapen weights: one user error
        raise ValueError(f"--resume: {checkpoint} holds the weights of another network than --net {net_name} "
                         f"({error_summary(error)}); resume with the --net of the run that wrote it, or pass "
                         "--overwrite (without --resume) to start anew") from None


def _check_init_survives(init: str, out: str) -> None:
    """ValueError when the --init weights are a file that --overwrite removes before training (OUT,
    OUT.ckpt, OUT.json or OUT.png): `geofeat train --init w.pt --out w.pt --overwrite` deleted w.pt
    with the earlier run's files, then failed to read it ('no GeoPatch checkpoint'), so the user's
    weights were lost and nothing was trained."""
    import os

    from ..train.loop import BESIDE

    if str(init) == "shipped" or not os.path.exists(init):
        return
    for path in (Path(out), *(Path(str(out) + beside) for beside in BESIDE)):
        if not (path.exists() or path.is_symlink()):
            continue
        if os.path.abspath(init) == os.path.abspath(path) or (path.exists() and os.path.samefile(init, path)):
            raise ValueError(f"--init: {init} would be removed by --overwrite before training (as {path}, an earlier "
                             "run's file), and the weights to start from lost; copy them to another name first, or "
                             "choose another --out")


def _init_config(init: str):
    """The `GeoPatchConfig` (network shape) of the --init weights ("shipped": geofeat's own), whose
    widths and angle pooling a run takes where it names none; None for a missing or foreign file,
    which `load_init` reports with the run's other checks."""
    from ..descriptors.geopatch import load_network

    try:
        start, _ = load_network(None if str(init) == "shipped" else init)
    except (ValueError, OSError):
        return None
    return start.config
