"""The `geofeat` command line. One module per command, each with `add_parser(subparsers)` (its options;
`run` as the parser's `func`) and `run(args) -> int` (the exit status): `demo`, `extract`, `match`,
`bench`, `train`, `train_detector`, `retrieval`, `track`, `simulate`, `groundtruth`. Options several
commands share are in `options`, the helpers of extract and match in `common`; this module builds the
parser and runs the command with the exit-status rules of `main`."""

from __future__ import annotations

import argparse
import sys
import warnings
from importlib import import_module

from ..outputs import release_outputs

#: The command modules, in the order `geofeat --help` lists them.
COMMANDS = ("demo", "extract", "match", "bench", "train", "train_detector", "retrieval", "track", "simulate",
            "groundtruth")


def build_parser() -> argparse.ArgumentParser:
    """The `geofeat` parser with every command of `COMMANDS` registered."""
    from .. import __version__

    parser = argparse.ArgumentParser(prog="geofeat", description="Geodesic-aware local features on RGB-D images.")
    parser.add_argument("--version", action="version", version=f"geofeat {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        import_module(f".{name}", __name__).add_parser(sub)
    return parser


def is_interrupt(error: BaseException) -> bool:
    """True for Ctrl-C, also when a compiled (numba) kernel surfaces it as a SystemError."""
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        if isinstance(error, SystemError) and "KeyboardInterrupt" in str(error):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


def empty_argument(argv: list[str], parser: argparse.ArgumentParser) -> str | None:
    """The option (or "a positional argument") of the command `parser` given an empty string in `argv`,
    or None.

    `geofeat simulate "$OUT"` with OUT unset passes "", which `Path` reads as the current folder; no
    option of geofeat takes an empty value, so such an argument is refused before it is parsed."""
    for i, token in enumerate(argv):
        if token.startswith("--") and token.endswith("=") and len(token) > 3:
            return token[:-1]
        if token.strip() == "":
            option = parser._option_string_actions.get(argv[i - 1]) if i else None
            return argv[i - 1] if option is not None and option.nargs != 0 else "a positional argument"
    return None


#: Exit status of a run stopped by Ctrl-C (128 + SIGINT, as shells report it).
EXIT_INTERRUPTED = 130


def main(argv: list[str] | None = None) -> int:
    """Run the command line: 0 success, 1 something was skipped or failed (named in the output),
    2 bad input (one-line error), 130 interrupted (finished results are kept)."""
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    args, unknown = parser.parse_known_args(argv)
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    empty = empty_argument(argv, commands.choices[args.command])
    if empty is not None:
        commands.choices[args.command].error(
            f"{empty}: an empty value (an unset shell variable?); give a value, or leave the option out")
    if unknown:  # argparse reports them with the top-level usage, which lists the commands, not the command's options
        commands.choices[args.command].error(f"unrecognized arguments: {' '.join(unknown)}")
    plain = warnings.formatwarning
    # a warning (the depth units, an upright descriptor) reads as one line of the command's, without
    # the source line that Python's default format quotes
    warnings.formatwarning = lambda message, category, *_, **__: f"geofeat {args.command}: warning: {message}\n"
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"geofeat {args.command}: interrupted; finished results are kept", file=sys.stderr)
        return EXIT_INTERRUPTED
    except SystemError as error:
        if not is_interrupt(error):
            raise
        print(f"geofeat {args.command}: interrupted; finished results are kept", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (ValueError, OSError) as error:  # user errors; programming errors keep their traceback
        text = " ".join(str(error).split()) or type(error).__name__
        print(f"geofeat {args.command}: error: {text}", file=sys.stderr)
        return 2
    finally:
        warnings.formatwarning = plain
        release_outputs()  # the outputs this command claimed (`check_out_dir`, `check_out_file`)
