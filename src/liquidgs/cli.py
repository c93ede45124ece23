"""The `liquidgs` command: dispatches to the command modules in liquidgs.commands.

Each command module exposes `main(argv: list[str]) -> int`. Modules are imported lazily so
that `liquidgs data check` does not pay for importing the trainer.

Every failure a user can cause ends in one line on stderr and exit 2 (130 for Ctrl-C):
LiquidGSError carries its own message; an OSError (read-only file system, a file where a
folder is expected, permissions) is reported with the path it names. A reader of the output that has
gone (`| head`, progress bar included) ends the command quietly with 141, as SIGPIPE would.
"""

from __future__ import annotations

import importlib
import os
import select
import sys

from liquidgs.errors import LiquidGSError, one_line

COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("liquidgs.commands.demo", "synthetic scene -> train static, MLP, CfC, SDE-LNN, HexPlane -> report"),
    "train": ("liquidgs.commands.train", "train a dynamic scene with a deformation field"),
    "eval": ("liquidgs.commands.evaluate", "re-evaluate a run's checkpoint"),
    "render": ("liquidgs.commands.render", "test renders, depth, time sweep, orbit video"),
    "export": ("liquidgs.commands.export", "canonical PLY, PLY at a time, PLY sequence"),
    "bake": ("liquidgs.commands.bake", "distil a run's field into keyframed motion that renders without it"),
    "view": ("liquidgs.commands.view", "browser viewer: scrub time, compare runs, record camera paths"),
    "data": ("liquidgs.commands.data", "synthetic scenes, checks, downloads, your own video, optical flow"),
    "bench": ("liquidgs.commands.bench", "benchmarks that print JSON (raster, fields, train, bake, gpu, acceptance)"),
    "experiment": ("liquidgs.commands.experiment", "grids of runs (local or Ray) and the paper's tables"),
}


def _usage() -> str:
    lines = ["usage: liquidgs COMMAND [ARGS...]", "", "commands:"]
    width = max(len(name) for name in COMMANDS)
    lines += [f"  {name:<{width}}  {help_text}" for name, (_, help_text) in COMMANDS.items()]
    lines += ["", "Run `liquidgs COMMAND --help` for a command's options."]
    return "\n".join(lines)


def _os_error_line(err: OSError) -> str:
    where = err.filename if err.filename is not None else "a file"
    return f"{where}: {err.strerror or err}"


def _reader_gone(stream) -> bool:
    """Whether the reader of `stream` has gone (`liquidgs ... | head`). Then the stream is pointed
    at /dev/null, so that Python's own flush at exit does not fail again."""
    try:
        poller = select.poll()
        poller.register(stream.fileno(), select.POLLOUT)
        gone = any(events & select.POLLERR for _, events in poller.poll(0))
    except (OSError, ValueError, AttributeError):  # closed or not a file; no poll (Windows)
        return False
    if gone:
        os.dup2(os.open(os.devnull, os.O_WRONLY), stream.fileno())
    return gone


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"liquidgs: error: unknown command '{name}'\n\n{_usage()}", file=sys.stderr)
        return 2
    try:
        module = importlib.import_module(COMMANDS[name][0])
        return int(module.main(rest) or 0)
    except LiquidGSError as err:
        print(f"liquidgs {name}: error: {one_line(str(err))}", file=sys.stderr)
        return 2
    except OSError as err:
        if isinstance(err, BrokenPipeError) and _reader_gone(sys.stdout):  # as a shell command killed by SIGPIPE
            return 141
        print(f"liquidgs {name}: error: {one_line(_os_error_line(err))}", file=sys.stderr)
        return 2
    except SystemExit as err:
        # rich's Console meets a gone reader of its stream (the progress bar's, stdout or stderr) by
        # pointing stdout at /dev/null and exiting 1 from inside the BrokenPipeError: the same 141.
        if err.code == 1 and isinstance(err.__context__, BrokenPipeError):
            _reader_gone(sys.stderr)
            return 141
        raise
    except KeyboardInterrupt as err:
        detail = f": {one_line(str(err))}" if str(err) else ""
        print(f"liquidgs {name}: interrupted{detail}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
