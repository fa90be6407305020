"""`geofeat simulate`: simulate a deforming cloth and write an RGB-D sequence with exact ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..sim.scenes import FOV_RANGE_DEG, PRESETS, SCENARIOS
from ..sim.textures import FABRIC_KINDS
from ..sim.writer import SIDE_RANGE_PX
from ..outputs import plural
from .options import number_between, whole_number


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `simulate` to an argparse subparsers object; returns its parser."""
    p = subparsers.add_parser(
        "simulate",
        help="simulate a deforming cloth and write an RGB-D sequence with exact ground truth",
        description="Simulate a textured cloth in wind and write an RGB-D sequence in the public layout "
        "(<name>-rgb.png, 16-bit <name>-depth.png in 0.1 mm units, or 1 mm where the scene may pass 6.55 m, "
        "geofeat.json with that scale, intrinsics.xml, <name>.csv landmarks) plus dense ground truth (<name>-gt.npz, "
        "groundtruth.json).",
    )
    p.add_argument("out_dir", type=Path, help="sequence folder to create")
    p.add_argument("--scenario", choices=SCENARIOS, default="deform",
                   help="deform: the cloth moves, the camera stays put (with --preset paper or hard it swings closer and "
                   "farther and orbits the cloth); rotate: camera roll 0..180 deg; scale: camera moves back to twice "
                   "its distance (default deform)")
    p.add_argument("--preset", choices=tuple(PRESETS), default="mild",
                   help="mild: the original gentle scenes; paper: the paper's simulation section (scale swings "
                   "0.5x-1.3x, bends, gusts); hard: strong folds, foreshortening up to ~70 deg, self-occlusion, "
                   "gusts, moving specular lights, image noise (default mild)")
    p.add_argument("--fov", type=number_between(*FOV_RANGE_DEG), default=None,
                   help="vertical field of view in degrees, in (20, 120) (default: Kinect-like f = 525 px at "
                   "640 x 480, 49.1 deg; the paper authors rendered 90)")
    p.add_argument("--motion-blur", action="store_true", help="motion blur on the target frames (--preset paper or hard; mild has none)")
    p.add_argument("--frames", type=whole_number(1), default=30, help="number of frames, reference included (default 30)")
    p.add_argument("--seed", type=whole_number(0), default=0, help="random seed (default 0)")
    tex = p.add_mutually_exclusive_group()
    tex.add_argument("--texture", help="texture image file, 'procedural', or 'fabric' or 'fabric:KIND' (a generated fabric; "
                     f"KIND one of {', '.join(FABRIC_KINDS)}) (default: a packaged photo or a procedural texture, the "
                     "textures the shipped weights were trained on, so not a held-out test of them: for that, give "
                     "photographs of your own with --texture or --texture-dir)")
    tex.add_argument("--texture-dir", type=Path, help="draw the texture at random from this folder")
    p.add_argument("--width", type=whole_number(*SIDE_RANGE_PX), default=640, help="image width in pixels, 32 to 8192 (default 640)")
    p.add_argument("--height", type=whole_number(*SIDE_RANGE_PX), default=480, help="image height in pixels, 32 to 8192 (default 480)")
    p.add_argument("--steps-per-frame", type=whole_number(1), default=6, help="simulation steps between frames (default 6)")
    p.add_argument("--kinect-noise", action="store_true", help="Kinect-like depth noise and holes")
    p.add_argument("--contact-sheet", type=Path, help="also write a contact sheet PNG with ground-truth tracks")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier simulation in OUT_DIR (only files geofeat wrote; "
                   "a folder holding other files is refused) and an existing --contact-sheet file")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def _refuse_sheet_among_frames(sheet: Path, out_dir: Path) -> None:
    """ValueError when the contact sheet lies in the sequence folder `out_dir` (or a folder in it) under
    a frame's file name (`<name>-rgb.png`, `<name>-depth.png`, in any case): written after the
    simulation, it replaced that frame's picture, or was read as a frame of its own by every command
    (and made its folder a sequence). Another name there (`OUT_DIR/sheet.png`) is fine."""
    from ..io import DEPTH_SUFFIX, RGB_SUFFIX

    inside = out_dir.resolve() in sheet.resolve().parents
    if inside and sheet.name.lower().endswith((RGB_SUFFIX, DEPTH_SUFFIX)):
        raise ValueError(f"--contact-sheet: {sheet} lies in the sequence folder {out_dir} under a frame's file name "
                         f"(<name>{RGB_SUFFIX}, <name>{DEPTH_SUFFIX}): it would replace that frame's picture, or be "
                         "read as a frame: name it otherwise (sheet.png), or write it outside the folder")


def run(args: argparse.Namespace) -> int:
    """Run `simulate`; ValueError on bad input. Returns the exit code."""
    from ..sim.writer import simulate_sequence

    if args.motion_blur and not PRESETS[args.preset].blur_px > 0:
        raise ValueError(f"--motion-blur: the {args.preset} preset has no motion blur; add --preset paper or "
                         "--preset hard, or leave --motion-blur out")
    if args.contact_sheet is not None:  # checked before the simulation, which takes minutes
        import cv2

        from ..outputs import check_out_file

        texture = Path(args.texture) if args.texture is not None else None
        if texture is not None and texture.is_file() and texture.resolve() == args.contact_sheet.resolve():
            # before "exists; pass --overwrite to replace it", which replaced the user's photograph with the sheet
            raise ValueError(f"--contact-sheet: {args.contact_sheet} is the --texture image; the sheet would replace "
                             "it, with or without --overwrite: choose another name")
        _refuse_sheet_among_frames(args.contact_sheet, args.out_dir)
        check_out_file(args.contact_sheet, args.overwrite, "--contact-sheet")
        if args.texture_dir is not None:  # the next simulation would draw the sheet as a cloth texture
            from ..outputs import refuse_input_folder

            refuse_input_folder(args.contact_sheet, [args.texture_dir], "--contact-sheet")
        if not cv2.haveImageWriter(str(args.contact_sheet)):
            raise ValueError(f"--contact-sheet: cannot write an image named {args.contact_sheet}; name a .png file")
    folder = simulate_sequence(
        args.out_dir,
        scenario=args.scenario,
        n_frames=args.frames,
        seed=args.seed,
        texture=args.texture,
        texture_dir=args.texture_dir,
        width=args.width,
        height=args.height,
        kinect_noise=args.kinect_noise,
        progress=not args.no_progress,
        steps_per_frame=args.steps_per_frame,
        overwrite=args.overwrite,
        preset=args.preset,
        fov=args.fov,
        motion_blur=args.motion_blur,
    )
    print(f"wrote {plural(args.frames, 'frame')} to {folder}")
    if args.contact_sheet is not None:
        from ..sim.contact_sheet import contact_sheet

        contact_sheet(folder, args.contact_sheet)
        import os

        from ..outputs import add_to_manifest

        sheet, root = Path(os.path.abspath(args.contact_sheet)), Path(os.path.abspath(folder))
        if root in sheet.parents:  # geofeat's file: unlisted, it made a rerun with --overwrite refuse the folder
            add_to_manifest(folder, [sheet.relative_to(root)])
        print(f"wrote contact sheet {args.contact_sheet}")
    return 0
