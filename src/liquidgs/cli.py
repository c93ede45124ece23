"""The `liquidgs` command: dispatches to the command modules in liquidgs.commands.

Each command module exposes `main(argv: list[str]) -> int`. Modules are imported lazily so
that `liquidgs data check` does not pay for importing the trainer.
"""

from __future__ import annotations

import importlib
import sys

from liquidgs.errors import LiquidGSError

COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("liquidgs.commands.demo", "synthetic scene -> train MLP, CfC, SDE-LNN -> report"),
    "train": ("liquidgs.commands.train", "train a dynamic scene with a deformation field"),
    "eval": ("liquidgs.commands.evaluate", "re-evaluate a finished run"),
    "render": ("liquidgs.commands.render", "test renders, depth, time sweep, orbit video"),
    "export": ("liquidgs.commands.export", "canonical PLY, PLY at a time, PLY sequence"),
    "data": ("liquidgs.commands.data", "generate synthetic scenes, validate dataset folders"),
    "bench": ("liquidgs.commands.bench", "benchmarks that print JSON (raster, fields)"),
    "experiment": ("liquidgs.commands.experiment", "grids of runs (local or Ray) and the paper's tables"),
}


def _usage() -> str:
    lines = ["usage: liquidgs COMMAND [ARGS...]", "", "commands:"]
    width = max(len(name) for name in COMMANDS)
    lines += [f"  {name:<{width}}  {help_text}" for name, (_, help_text) in COMMANDS.items()]
    lines += ["", "Run `liquidgs COMMAND --help` for a command's options."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"liquidgs: error: unknown command '{name}'\n\n{_usage()}", file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[name][0])
    try:
        return int(module.main(rest) or 0)
    except LiquidGSError as err:
        print(f"liquidgs {name}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"liquidgs {name}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
