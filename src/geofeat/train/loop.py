"""Training loop of GeoPatch: triplet margin loss with anchor swap (paper, "Convolutional Network
Training"), SGD, a validation matching score per epoch, checkpoints to resume from, and a plot."""

from __future__ import annotations

import warnings

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from ..scoring import score_detect
from ..descriptors.geopatch import GeoPatchConfig, GeoPatchNet, save_checkpoint
from ..gpu import torch_device
from ..inputs import check_non_negative, check_positive, check_whole, error_summary
from ..matching import match
from ..outputs import MANIFEST, atomic_file, check_out_file, json_text, plural, record_written, was_written_by
from .dataset import PatchSet, ValidationPair


@dataclass
class TrainConfig:
    """Training settings (paper values where it gives them: SGD, lr 0.1, weight decay 1e-4, batch 1000).

    mining: "random" (the paper: one random negative per triplet, anchor swap picks the harder of
    the two negative distances) or "hardest" (the hardest negative among the batch, as HardNet).
    augment_shift: roll every training patch by a random number of angle columns.
    augment_photometric: per patch, a random gamma (exp U(-0.5, 0.5)) and Gaussian noise (sigma up to
    0.03): contrast changes the per-patch z-score of the network does not remove by itself.
    """

    epochs: int = 10
    steps_per_epoch: int = 200
    batch_size: int = 1000
    lr: float = 0.1
    momentum: float = 0.9
    weight_decay: float = 1e-4
    margin: float = 1.0
    mining: str = "random"
    augment_shift: bool = False
    augment_photometric: bool = False
    seed: int = 0
    net: GeoPatchConfig = field(default_factory=GeoPatchConfig)


#: Negative mining modes of `TrainConfig.mining`.
MINING = ("random", "hardest")


def check_train_config(config: TrainConfig) -> TrainConfig:
    """The settings of `train`, checked before any work: ValueError naming the first one that cannot
    train. epochs >= 1; steps_per_epoch >= 0 (0: no step, the starting weights are written);
    batch_size >= 1 (>= 2 for hardest mining, whose negatives are the batch's other pairs); lr and
    margin positive; momentum and weight_decay finite and >= 0; a known mining mode; seed >= 0."""
    if config.mining not in MINING:
        raise ValueError(f"mining: expected one of {', '.join(MINING)}, got {config.mining!r}")
    check_whole(config.epochs, "epochs", 1)
    check_whole(config.steps_per_epoch, "steps_per_epoch", 0)
    check_whole(config.batch_size, "batch_size", 2 if config.mining == "hardest" else 1)
    check_whole(config.seed, "seed", 0)
    check_positive(config.lr, "lr")
    check_positive(config.margin, "margin")
    for name in ("momentum", "weight_decay"):  # 0 turns it off
        check_non_negative(getattr(config, name), name)
    return config


#: Networks whose patches have no angle axis to roll (`TrainConfig.augment_shift`): TFeat's are Cartesian
#: image patches (GeoPatch's polar patches and Log-Polar's have the angle along their columns).
NO_ANGLE_AXIS = ("tfeat",)


def check_augmentation(config: TrainConfig, arch: str | None) -> None:
    """ValueError when `config.augment_shift` is asked for the network `arch` ("tfeat", "logpolar";
    None or "geopatch": GeoPatchNet) whose (B, 32, 32) patches have no angle axis: rolling the
    columns of a Cartesian image patch wraps its left edge around beside its right edge, a patch no
    keypoint ever gives (it trained without a word)."""
    if config.augment_shift and arch in NO_ANGLE_AXIS:
        raise ValueError(f"augment_shift: rolls the angle columns of polar patches (a rotation about the keypoint); "
                         f"{arch}'s patches are Cartesian image patches, whose columns it would wrap around (left "
                         "edge beside right edge); leave it out for this network")


def check_train_out(out: str | Path, overwrite: bool = False, resume: bool = False,
                    also: tuple[str, ...] = ()) -> Path:
    """The weights file `train` writes (`check_out_file`): an existing file is replaced only with
    `overwrite`, or with `resume` when its checkpoint `out`.ckpt exists (the run that wrote it). So are
    the files written beside it (`out`.ckpt, `out`.json, `out`.png, and the suffixes `also` of other
    files a caller writes there and, resuming, reads back, such as the `train` command's
    `out`.patches.npz), replaced only with `overwrite` or `resume`: a run stopped after some epochs
    leaves its checkpoint, which a new run would restart over. Even then, an existing file beside `out`
    is replaced (or removed) only when the folder's manifest records that `train` wrote it
    (`record_run_files`): a model.json of the user's beside `--out model` was deleted by --overwrite.
    Resuming, the checkpoint and the `also` files are read back as the earlier run's, and refused
    when they are not (`load_resume_state`; the caller's checks), recorded or not."""
    out = Path(out)
    if out.suffix.lower() == ".onnx":  # the weights were written, then read as an ONNX model and refused
        raise ValueError(f"--out: {out}: `train` writes PyTorch weights, and a .onnx name is read as an ONNX model "
                         "(geopatch=WEIGHTS); name it .pt")
    check_out_file(out, overwrite or (resume and out.with_suffix(out.suffix + ".ckpt").is_file()))
    for beside in (*BESIDE, *also):
        path = Path(str(out) + beside)  # as `train` names them
        exists = path.exists() or path.is_symlink()
        if not (overwrite or resume) and exists:
            raise ValueError(f"--out: {path} exists (an earlier run's?); pass --resume to continue that run, "
                             "--overwrite to start anew over it, or choose another name")
        read_back = resume and beside in (".ckpt", *also)  # checked by content: an older geofeat recorded none
        if exists and not read_back and not was_written_by(path, "train"):
            raise ValueError(f"--out: {path} exists, and `geofeat train` did not write it (its folder's "
                             f"{MANIFEST} does not list it); {'--resume' if resume else '--overwrite'} would "
                             "replace it: move it away, or choose another --out")
        check_out_file(path, True)  # not a folder, not under a file
    return out


#: The files `train` writes beside its weights file `out` (suffixes of its name).
BESIDE = (".ckpt", ".json", ".png")


def record_run_files(out: str | Path, also: tuple[str, ...] = ()) -> None:
    """Record in the manifest of the folder of `out` that `train` writes `out` and the files beside it
    (`BESIDE`, and the suffixes `also`), before it writes the first: a rerun with --overwrite or
    --resume replaces only recorded files (`check_train_out`)."""
    record_written([Path(str(out) + beside) for beside in ("", *BESIDE, *also)], "train")


def remove_earlier_run(out: str | Path) -> list[Path]:
    """Remove the files of an earlier run at `out` (`out` itself, `out`.ckpt, `out`.json, `out`.png),
    which an `overwrite` run replaces anyway: called when the new run writes its first file, so that
    one interrupted before its end leaves no earlier weights beside its own checkpoint, to be taken
    for its result. A file beside `out` that `train` did not write (`record_run_files`) stays.
    Returns the paths removed (a symbolic link is removed, not what it points to)."""
    removed = []
    for path in (Path(out), *(Path(str(out) + beside) for beside in BESIDE)):
        if path != Path(out) and not was_written_by(path, "train"):
            continue
        if path.is_file() or path.is_symlink():
            path.unlink()
            removed.append(path)
    return removed


def removed_line(removed: list[Path]) -> str:
    """What `remove_earlier_run` did, in words, for the output of `train`."""
    return (f"--overwrite: removed the earlier run's {', '.join(str(p) for p in removed)} (an interrupted run "
            "leaves no weights but its own)")


def load_init(init: str | Path, config: GeoPatchConfig) -> GeoPatchNet:
    """The GeoPatch weights to start from ("shipped": geofeat's own); ValueError when the file is
    missing, not a GeoPatch checkpoint, or of another shape than `config`."""
    from ..descriptors.geopatch import load_network

    start, _ = load_network(None if str(init) == "shipped" else init)
    if start.config != config:
        raise ValueError(f"init: the weights' network {start.config} differs from the requested {config}")
    return start


def load_resume_state(ckpt_path: str | Path, config: TrainConfig) -> dict:
    """The state `train` saved in `ckpt_path` after its last epoch, to resume with `config`; ValueError
    naming the file when it cannot be read as one, or was written with other settings (resuming
    with another schedule would silently train a different run). Called by `train` and, before any
    patches are built, by the `train` command. The state is read onto the CPU, whatever device `train`
    trains on (`load_state_dict` copies the weights and optimizer state there)."""
    ckpt_path = Path(ckpt_path)
    try:
        # on the CPU whatever the training device: torch's random state must stay there (torch.set_rng_state refuses
        # a GPU tensor, so no resume on a GPU worked), and the network and optimizer copy theirs when loaded
        state = torch.load(str(ckpt_path), map_location="cpu", weights_only=False)
        written_with = state["history"]["config"]
        for key in ("state_dict", "optimizer", "scheduler", "rng", "torch_rng", "epoch"):
            state[key]
    except Exception as error:  # noqa: BLE001 - unpickling, a missing key: one user error
        raise ValueError(f"resume: {ckpt_path} is not a checkpoint written by `geofeat train` "
                         f"({error_summary(error)})") from None
    wanted = asdict(config)
    if written_with != wanted:
        changed = [k for k in wanted if written_with.get(k) != wanted[k]]
        raise ValueError(f"resume: {ckpt_path} was written with other settings ("
                         + ", ".join(f"{k} {written_with.get(k)!r}, not {wanted[k]!r}" for k in changed)
                         + "); resume with the same options, or train anew")
    return state


def triplet_loss(a: torch.Tensor, p: torch.Tensor, n: torch.Tensor | None, margin: float, mining: str,
                 ids: torch.Tensor | None = None) -> torch.Tensor:
    """Margin ranking loss with anchor swap on unit descriptors (B, D).

    random: delta* = min(|a - n|, |p - n|) for the given negatives.
    hardest: delta* = min over the batch of |a_i - p_j| and |p_i - a_j| (j != i, and with `ids`, the (B,)
    surface-point ids of the rows, ids[j] != ids[i]: a point drawn twice is not its own negative)."""
    d_pos = (a - p).norm(dim=1)
    if mining == "random":
        d_neg = torch.minimum((a - n).norm(dim=1), (p - n).norm(dim=1))
    elif mining == "hardest":
        dist = torch.cdist(a, p)
        same = torch.eye(len(a), device=a.device) if ids is None else (ids[:, None] == ids[None, :]).to(dist)
        dist = dist + same * 10.0
        d_neg = torch.minimum(dist.min(dim=1).values, dist.min(dim=0).values)
    else:
        raise ValueError(f"mining: expected 'random' or 'hardest', got {mining!r}")
    return F.relu(margin + d_pos - d_neg).mean()


class TripletSampler:
    """Draws (anchor, positive, negative) patch indices: anchor and positive share an id.

    `distinct` (hardest mining, whose negatives are the batch's other points): a batch of two rows or
    more always holds two surface points at least. With fewer points than rows the points are drawn
    with replacement, and a batch drawn from one point only (half the batches of 2 rows on 2 points)
    has its last row moved to another point: hardest mining found no negative in it, and its step's loss
    was 0, with no gradient, without a word."""

    def __init__(self, ids: np.ndarray, rng: np.random.Generator, distinct: bool = False) -> None:
        order = np.argsort(ids, kind="stable")
        sorted_ids = ids[order]
        starts = np.flatnonzero(np.r_[True, sorted_ids[1:] != sorted_ids[:-1]])
        counts = np.diff(np.r_[starts, len(ids)])
        keep = counts >= 2
        self.order, self.starts, self.counts = order, starts[keep], counts[keep]
        if len(self.starts) < 2:
            raise ValueError("data: need at least 2 surface points seen in 2 frames to form triplets")
        self.ids = ids
        self.rng = rng
        self.distinct = distinct

    def sample(self, batch: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rng = self.rng
        groups = rng.choice(len(self.starts), size=batch, replace=len(self.starts) < batch)
        if self.distinct and batch >= 2 and (groups == groups[0]).all():  # one point: no negative in the batch
            groups[-1] = (groups[0] + rng.integers(1, len(self.starts))) % len(self.starts)
        first = rng.integers(0, self.counts[groups])
        second = (first + rng.integers(1, self.counts[groups])) % self.counts[groups]
        a = self.order[self.starts[groups] + first]
        p = self.order[self.starts[groups] + second]
        n = rng.integers(0, len(self.ids), size=batch)
        clash = self.ids[n] == self.ids[a]
        while clash.any():
            n[clash] = rng.integers(0, len(self.ids), size=int(clash.sum()))
            clash = self.ids[n] == self.ids[a]
        return a, p, n


def validation_measure(pairs: list[ValidationPair]) -> str:
    """What `validation_score` measures on `pairs`, in words, for the lines, plot and history of
    `train`: the matching score of protocol "detect" with one-way nearest-neighbour matches (no ratio
    test, no mutual check) between the SIFT keypoints of each pair, not the benchmark's 2048."""
    counts = "/".join(str(n) for n in sorted({int(p.n_keypoints) for p in pairs})) or "no"
    return f"{counts} SIFT keypoints per frame, one-way nearest-neighbour matches"


@torch.no_grad()
def validation_score(net: GeoPatchNet, pairs: list[ValidationPair], device) -> float:
    """Mean matching score (protocol "detect", MS) of the network over validation pairs, with one-way
    nearest-neighbour matches (`validation_measure`)."""
    net.eval()
    scores = []
    for pair in pairs:
        def describe(values, valid):
            out = np.zeros((len(values), net.config.dim), np.float32)
            if valid.any():
                x = torch.from_numpy(np.asarray(values[valid], np.float32)).unsqueeze(1).to(device)
                out[valid] = torch.cat([net(c) for c in x.split(512)]).cpu().numpy()
            return out
        from ..features import Features

        f0 = Features(np.zeros((len(pair.ref_valid), 2)), describe(pair.ref_patches, pair.ref_valid), pair.ref_valid)
        f1 = Features(np.zeros((len(pair.tgt_valid), 2)), describe(pair.tgt_patches, pair.tgt_valid), pair.tgt_valid)
        m = match(f0, f1)
        scores.append(score_detect(m.matches0, pair.gt_pairs, len(pair.ref_valid), len(pair.tgt_valid)).ms)
    net.train()
    return float(np.mean(scores)) if scores else float("nan")


def _batch(patches: np.ndarray, index: np.ndarray, rng: np.random.Generator, shift: bool,
           photometric: bool = False) -> torch.Tensor:
    """(B, 1, R, A) float32 patches in [0, 1] of `index`, augmented as asked (see TrainConfig)."""
    x = patches[index].astype(np.float32) / 255.0
    if photometric:
        gamma = np.exp(rng.uniform(-0.5, 0.5, (len(x), 1, 1))).astype(np.float32)
        sigma = rng.uniform(0.0, 0.03, (len(x), 1, 1)).astype(np.float32)
        x = x ** gamma + sigma * rng.standard_normal(x.shape, dtype=np.float32)
    if shift:
        k = rng.integers(0, x.shape[2], size=len(x))
        cols = (np.arange(x.shape[2])[None, :] + k[:, None]) % x.shape[2]
        x = np.take_along_axis(x, cols[:, None, :].repeat(x.shape[1], axis=1), axis=2)
    return torch.from_numpy(x).unsqueeze(1)


def train(data: PatchSet, out: str | Path, config: TrainConfig = TrainConfig(),
          validation: list[ValidationPair] | None = None, resume: bool = False,
          device: str | None = None, progress: bool = True, net: torch.nn.Module | None = None,
          init: str | Path | None = None, overwrite: bool = False) -> dict:
    """Train GeoPatchNet (or `net`, any module mapping (B, 1, H, W) patches to unit (B, dim)
    descriptors with a dataclass `config` holding `dim`, e.g. the image-patch baselines); writes
    `out` (final weights), `out`.ckpt (resumable state after every epoch, with `data.source`: what the
    run trains on, which `geofeat train --resume` compares with its options, and `data.digest()`: `resume` on
    other patches is a ValueError), `out`.json (history) and
    `out`.png (loss / validation plot). Returns the history. With `overwrite` (and not `resume`), an
    earlier run's `out` and files beside it are removed before the first epoch (`remove_earlier_run`). `init`: start GeoPatchNet from these
    weights ("shipped" = geofeat's own) instead of at random (fine-tuning; the network shape must
    match `config.net`). The settings and `out` are checked first (`check_train_config`,
    `check_train_out`: an existing `out`, or files beside it, only with `overwrite`, or when resuming
    its run); every file is written whole or not at all."""
    check_train_config(config)
    # `is None`, not falsy: device=0 (torch's cuda:0) trained on the CPU without a word
    device = torch_device(device if device is not None else ("cuda" if torch.cuda.is_available() else "cpu"))
    out = check_train_out(out, overwrite, resume)
    ckpt_path = out.with_suffix(out.suffix + ".ckpt")
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    if net is None:
        net = GeoPatchNet(config.net)
        if init is not None:
            net.load_state_dict(load_init(init, config.net).state_dict())
    elif init is not None:
        raise ValueError("init: fine-tuning starts from GeoPatch weights; not with another network")
    check_augmentation(config, getattr(getattr(net, "config", None), "arch", None))
    net = net.to(device)
    opt = torch.optim.SGD(net.parameters(), lr=config.lr, momentum=config.momentum, weight_decay=config.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=config.epochs * config.steps_per_epoch)
    history = {"epoch": [], "loss": [], "val_ms": [], "config": asdict(config)}
    measure = validation_measure(validation) if validation else None
    start_epoch = 0
    if resume and not ckpt_path.is_file():  # it started from the first epoch without a word
        warnings.warn(f"resume: no {ckpt_path} to resume from (no earlier run stopped here); training from the "
                      "first epoch", UserWarning, stacklevel=2)
    patches_digest = data.digest()
    if resume and ckpt_path.is_file():
        state = load_resume_state(ckpt_path, config)
        try:
            net.load_state_dict(state["state_dict"])
            opt.load_state_dict(state["optimizer"])
            sched.load_state_dict(state["scheduler"])
            rng.bit_generator.state = state["rng"]
            torch.set_rng_state(state["torch_rng"])
        except Exception as error:  # noqa: BLE001 - another network's state, a missing key: one user error
            raise ValueError(f"resume: {ckpt_path} is not a checkpoint of this network written by `geofeat train` "
                             f"({error_summary(error)})") from None
        recorded = state.get("patches_digest")  # None in checkpoints of an older geofeat
        if recorded is not None and recorded != patches_digest:
            raise ValueError(f"resume: {ckpt_path} continues a run trained on other patches than `data` "
                             f"({len(data)} patches of {len(np.unique(data.ids))} surface points now): resume with "
                             "the patches of that run (the same sequences and options, or its .patches.npz), or "
                             "train anew")
        history = state["history"]
        start_epoch = state["epoch"] + 1
    if measure is not None:  # what "val_ms" is, in <out>.json and on the plot
        history["val_measure"] = measure
    sampler = TripletSampler(data.ids, rng, distinct=config.mining == "hardest")
    points = len(sampler.starts)
    if config.mining == "hardest" and points < config.batch_size:
        warnings.warn(f"mining: hardest takes each row's negative from the batch's other surface points, but the data "
                      f"has {plural(points, 'surface point')} seen in 2 frames or more for batches of "
                      f"{config.batch_size} triplets: every batch draws points more than once, and a row's hardest "
                      f"negative is one of at most {points - 1} others; give more data (or --keypoints), a "
                      f"batch_size (--batch-size) of at most {points}, or random mining", UserWarning, stacklevel=2)
    if overwrite and not resume:  # before the first checkpoint of this run (the `train` command removed them sooner)
        removed = remove_earlier_run(out)
        if removed and progress:
            tqdm.write(removed_line(removed))
    record_run_files(out)
    net.train()
    for epoch in range(start_epoch, config.epochs):
        losses = []
        bar = tqdm(range(config.steps_per_epoch), desc=f"epoch {epoch + 1}/{config.epochs}", disable=not progress)
        for step in bar:
            a, p, n = sampler.sample(config.batch_size)
            aug = (config.augment_shift, config.augment_photometric)
            xa = _batch(data.patches, a, rng, *aug).to(device)
            xp = _batch(data.patches, p, rng, *aug).to(device)
            if config.mining == "random":
                xn = _batch(data.patches, n, rng, *aug).to(device)
                da, dp, dn = net(torch.cat([xa, xp, xn])).split(len(a))
            else:
                (da, dp), dn = net(torch.cat([xa, xp])).split(len(a)), None
            loss = triplet_loss(da, dp, dn, config.margin, config.mining, ids=torch.from_numpy(data.ids[a]).to(device))
            if not torch.isfinite(loss):  # its step would make every weight NaN, and OUT with them
                raise ValueError(f"lr: training diverged at epoch {epoch + 1}, step {step + 1} (loss {loss.item()}); "
                                 f"nothing written for this epoch; train anew with a smaller learning rate than "
                                 f"{config.lr:g} (--lr)")
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            losses.append(loss.item())
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.3f}")
        val = validation_score(net, validation, device) if validation else float("nan")
        history["epoch"].append(epoch + 1)
        history["loss"].append(float(np.mean(losses)) if losses else float("nan"))
        history["val_ms"].append(val)
        if progress:
            scored = f"validation MS {val:.3f} ({measure})" if validation else "no validation pairs"
            tqdm.write(f"epoch {epoch + 1}: loss {history['loss'][-1]:.4f}, {scored}")
        with atomic_file(ckpt_path) as tmp, open(tmp, "wb") as fh:  # a file object: see `save_checkpoint`
            torch.save({"state_dict": net.state_dict(), "optimizer": opt.state_dict(),
                        "scheduler": sched.state_dict(), "rng": rng.bit_generator.state,
                        "torch_rng": torch.get_rng_state(), "history": history, "epoch": epoch,
                        "source": data.source,  # what the run trains on: `geofeat train --resume` compares it
                        "patches_digest": patches_digest}, fh)  # and the patches themselves: `resume` compares them
    net.eval()
    with atomic_file(out) as tmp:
        save_checkpoint(tmp, net.cpu(), history=history)
    with atomic_file(Path(str(out) + ".json")) as tmp:
        tmp.write_text(json_text(history, indent=1), encoding="utf-8")  # no validation: null, not NaN
    with atomic_file(Path(str(out) + ".png")) as tmp:
        _plot(history, tmp)
    return history


def _figure(history: dict):
    """The matplotlib figure of `_plot`: training loss (left axis) and validation MS (right axis,
    0-1, labelled with what it measures, `validation_measure`) per epoch; without validation pairs (MS all NaN) the right axis says so instead of staying empty."""
    import matplotlib.ticker

    from ..viz import plot_figure

    fig, ax = plot_figure((6, 3.5))
    ax.plot(history["epoch"], history["loss"], "o-", color="tab:blue", label="training loss")
    ax.set_xlabel("epoch")
    ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))  # no epoch 1.2
    ax.set_ylabel("triplet loss", color="tab:blue")
    ax2 = ax.twinx()
    ax2.plot(history["epoch"], history["val_ms"], "s-", color="tab:green", label="validation MS")
    ax2.set_ylabel("validation matching score", color="tab:green")
    if history.get("val_measure"):  # `validation_measure`: not the benchmark's score
        ax.set_title(f"validation MS: {history['val_measure']}", fontsize=9, color="tab:green")
    if not np.isfinite(np.asarray(history["val_ms"], float)).any():
        ax2.set_ylim(0, 1)
        ax2.text(0.5, 0.5, "no validation pairs: no validation MS", transform=ax2.transAxes, ha="center",
                 va="center", color="tab:green")
    fig.tight_layout()
    return fig


def _plot(history: dict, path: Path) -> None:
    """Write `_figure(history)` as a PNG at `path` (whatever its name's extension)."""
    _figure(history).savefig(path, dpi=100, format="png")
