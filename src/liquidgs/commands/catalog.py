"""Every `liquidgs` command and the settings it takes, for checking a command line without running
it and for the command-line reference of the documentation (docs/hooks.py renders it at build time).

A command's settings are its configuration dataclass (parsed by liquidgs.settings) or, for the
benchmarks, its argparse parser; this table only says which command parses which, so the reference
and the check read the flags from the same place the commands do.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import importlib
import inspect
import shlex
import textwrap
from collections.abc import Callable
from pathlib import Path

from liquidgs.cli import COMMANDS
from liquidgs.commands import bench, data, experiment
from liquidgs.commands.bake import BakeArgs
from liquidgs.commands.demo import DemoArgs
from liquidgs.commands.evaluate import EvalArgs
from liquidgs.commands.export import ExportArgs
from liquidgs.commands.render import RenderArgs
from liquidgs.commands.train import config_file_argument
from liquidgs.commands.view import ViewArgs
from liquidgs.errors import ConfigError
from liquidgs.fields.config import PRESET_NAMES
from liquidgs.settings import Flag, describe, flags_of, option_strings, parse_flag_settings
from liquidgs.train.config import TrainConfig, preset_config

# Commands without sub-commands, by the configuration they parse.
SINGLE = {"demo": DemoArgs, "train": TrainConfig, "eval": EvalArgs, "render": RenderArgs, "export": ExportArgs,
          "bake": BakeArgs, "view": ViewArgs}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Command:
    """One command line's head (`data video`) and what parses the rest."""

    words: tuple[str, ...]
    summary: str
    settings: type | None = None  # a configuration dataclass
    parser: Callable[[], argparse.ArgumentParser] | None = None  # a benchmark's parser

    @property
    def name(self) -> str:
        return "liquidgs " + " ".join(self.words)


def _first_line(text: str | None) -> str:
    return (text or "").strip().splitlines()[0] if (text or "").strip() else ""


def commands() -> list[Command]:
    """Every command, in the order `liquidgs --help` lists them."""
    out = []
    for word, (_, summary) in COMMANDS.items():
        if word in SINGLE:
            out.append(Command((word,), summary, settings=SINGLE[word]))
        elif word == "data":
            for sub, (cls, _) in data.SUBCOMMANDS.items():
                out.append(Command((word, sub), _first_line(cls.__doc__), settings=cls))
        elif word == "experiment":
            for sub, (cls, summary_line) in experiment.ACTIONS.items():
                out.append(Command((word, sub), summary_line, settings=cls))
        elif word == "bench":
            for sub, module in bench.BENCHMARKS.items():
                build = importlib.import_module(module).build_parser
                out.append(Command((word, sub), build().description or "", parser=build))
        else:
            raise AssertionError(f"liquidgs {word}: not in the command catalog")  # a new command: add it above
    return out


def check_command_line(line: str) -> None:
    """Parse a shown `liquidgs ...` command line with the current flags, running nothing; a flag that
    does not exist, a value of the wrong type or a missing required argument raises a ConfigError."""
    try:
        words = shlex.split(line, comments=True)
    except ValueError as err:
        raise ConfigError(f"cannot split the line: {err}") from None
    if not words or words[0] != "liquidgs":
        raise ConfigError("not a liquidgs command line")
    argv = words[1:]
    if not argv or argv[0] in ("-h", "--help"):
        return
    table = {c.words: c for c in commands()}
    command = table.get(tuple(argv[:2])) or table.get(tuple(argv[:1]))
    if command is None:
        known = sorted({" ".join(c.words) for c in table.values()})
        raise ConfigError(f"unknown command 'liquidgs {' '.join(argv[:2])}' (commands: {', '.join(known)})")
    rest = argv[len(command.words) :]
    if any(arg in ("-h", "--help") for arg in rest):
        return
    if command.parser is not None:
        command.parser().parse_args(rest)  # its ArgumentParser raises ConfigError
        return
    if command.settings is None:
        if rest:
            raise ConfigError(f"{command.name} takes no arguments, got {' '.join(rest)}")
        return
    if command.settings is TrainConfig:
        _, rest = config_file_argument(rest)
    given = parse_flag_settings(command.settings, rest, command.name)
    missing = [f for f in flags_of(command.settings) if f.required and f.key not in given]
    if missing:
        what = missing[0].flag.upper() if missing[0].positional else "--" + missing[0].flag
        raise ConfigError(f"{command.name}: the following arguments are required: {what}")


def all_option_strings() -> set[str]:
    """Every flag of every command (for checking a flag named on its own in the documentation)."""
    out = {"--help", "--config"}
    for command in commands():
        if command.parser is not None:
            out |= {s for action in command.parser()._actions for s in action.option_strings}
        elif command.settings is not None:
            out |= {s for flag in flags_of(command.settings) for s in option_strings(flag)}
    return out


# The reference.


def attribute_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of a dataclass (and of its bases), as tyro shows it in --help."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        body = tree.body[0].body
        for node, after in zip(body, body[1:]):
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                    and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
                    and isinstance(after.value.value, str)):  # fmt: skip
                docs[node.target.id] = " ".join(inspect.cleandoc(after.value.value).split())
    return docs


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _code(value) -> str:
    text = str(value) if not isinstance(value, (list, tuple)) else " ".join(map(str, value)) or "(none)"
    return f"`{text}`" if text else "`''`"


def _leaf_default(cls: type, flag: Flag, instance=None):
    """A setting's default as a user reads it: the value, or how it is computed."""
    node = instance
    if node is not None:
        for part in flag.key.split("."):
            node = getattr(node, part)
        return _code(node)
    holder, name = cls, flag.key
    for part in flag.key.split(".")[:-1]:
        holder = _group_type(holder, part)
        name = name.split(".", 1)[1]
    field = {f.name: f for f in dataclasses.fields(holder)}[name]
    if field.default is not dataclasses.MISSING:
        return _code(field.default) if field.default is not None else "none"
    if field.default_factory is not dataclasses.MISSING:
        return f"computed (`{field.default_factory.__name__}`)"
    return "required"


def _group_type(cls: type, name: str) -> type:
    import typing

    hint = typing.get_type_hints(cls, include_extras=True)[name]
    return typing.get_args(hint)[0] if typing.get_origin(hint) is typing.Annotated else hint


def _docs_by_key(cls: type, prefix: str = "") -> dict[str, str]:
    docs = {f"{prefix}{k}": v for k, v in attribute_docs(cls).items()}
    for f in dataclasses.fields(cls):
        group = _group_type(cls, f.name)
        if dataclasses.is_dataclass(group):
            docs.update(_docs_by_key(group, f"{prefix}{f.name}."))
    return docs


def _flag_name(flag: Flag) -> str:
    strings = option_strings(flag)
    return " / ".join(f"`{s}`" for s in strings) if strings else f"`{flag.flag.upper()}` (positional)"


def _settings_table(cls: type) -> list[str]:
    docs = _docs_by_key(cls)
    if cls is TrainConfig:  # defaults per preset: the presets are settings over TrainConfig's
        presets = {name: preset_config(name, Path("SCENE")) for name in PRESET_NAMES}
        lines = ["| flag | type | " + " | ".join(f"`{p}` default" for p in presets) + " | what |",
                 "|---|---|" + "---|" * len(presets) + "---|"]  # fmt: skip
        for flag in flags_of(cls):
            defaults = " | ".join(_leaf_default(cls, flag, cfg) for cfg in presets.values())
            lines.append(f"| {_flag_name(flag)} | {_cell(describe(flag.hint))} | {defaults} | "
                         f"{_cell(docs.get(flag.key, ''))} |")  # fmt: skip
        return lines
    lines = ["| flag | type | default | what |", "|---|---|---|---|"]
    for flag in flags_of(cls):
        lines.append(f"| {_flag_name(flag)} | {_cell(describe(flag.hint))} | {_leaf_default(cls, flag)} | "
                     f"{_cell(docs.get(flag.key, ''))} |")  # fmt: skip
    return lines


def _parser_table(parser: argparse.ArgumentParser) -> list[str]:
    lines = ["| flag | type | default | what |", "|---|---|---|---|"]
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if action.choices:
            kind = "one of " + ", ".join(map(str, action.choices))
        elif action.nargs == 0:
            kind = "switch"
        else:
            kind = getattr(action.type, "__name__", None) or "a string"
            kind = {"int": "an integer", "float": "a number", "Path": "a path"}.get(kind, kind)
        default = "required" if action.required else ("none" if action.default is None else _code(action.default))
        if action.nargs == 0:
            default = "off"
        lines.append(f"| {' / '.join(f'`{s}`' for s in action.option_strings)} | {_cell(kind)} | {default} | "
                     f"{_cell(action.help or '')} |")  # fmt: skip
    return lines


def cli_reference() -> str:
    """The command-line reference page (Markdown), from the configuration dataclasses and parsers."""
    lines = [
        "# Command-line reference",
        "",
        "Generated when the site is built from the settings the commands parse (`liquidgs.settings`"
        " and the configuration dataclasses; the benchmarks' parsers), so it cannot drift from the"
        " code. `liquidgs COMMAND --help` prints the same flags. Booleans are switches: `--resume`"
        " sets one, `--no-resume` clears it.",
        "",
    ]
    for command in commands():
        lines += [f"## {command.name}", "", command.summary.rstrip(".") + ".", ""]
        if command.settings is TrainConfig:
            lines += ["`--config FILE` trains a resolved configuration (a run folder's `config.yml`) as it"
                      " is; the flags below change settings on top of it.", ""]  # fmt: skip
        if command.parser is not None:
            lines += _parser_table(command.parser())
        elif command.settings is not None:
            lines += _settings_table(command.settings)
        else:
            lines.append("No arguments.")
        lines.append("")
    return "\n".join(lines)
