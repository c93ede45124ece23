"""Settings: the one typed way from YAML, a spec's overrides or command-line flags to a config.

Every config of liquidgs is a dataclass (nested for groups such as `eval.*`). Three sources
fill one in, all through `from_dict`, so each value is type-checked the same way and every
dataclass's `__post_init__` (its validation) runs on the final values:

- a YAML file or a stored config (`from_dict`),
- dotted overrides such as {'eval.every': 100} from a spec or a preset (`with_settings`),
- command-line flags (`parse_flags`), named as tyro names them, so `--help` (rendered by tyro)
  and the parser agree; tests/test_settings.py holds the two flag sets equal for every command.

A usage error is one line (a ConfigError) through argparse's documented `error` hook; no code
reads tyro's rendered help text.

A group whose settings depend on the config's other values (train's field_options: a plugin
field's own options) is named by two class methods of the config: `settings_group(key, raw)`,
the group's class for the config's plain values, and `settings_extra_flags()`, the flags of the
settings such groups may hold beyond their declared class (not in tyro's --help).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import types
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal, TypeVar

import tyro
import yaml

from liquidgs.errors import ConfigError

T = TypeVar("T")

_NONE_TEXT = "None"
_NONE_TEXTS = (_NONE_TEXT, "null")
"""How a flag says None: Python's word, or YAML's (which `describe` and the reference use)."""


MAX_YAML_VALUES = 100_000
"""Values a YAML file may hold once its aliases (*name) are expanded: a config or spec holds a few
hundred; a few nested aliases (an "alias bomb") would expand to billions and hang every reader."""


def load_yaml_file(path: Path, what: str):
    """The plain values of a YAML file, or one error naming it: unreadable, or larger than
    MAX_YAML_VALUES once its aliases are expanded (a self-referencing alias never ends)."""
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ConfigError(f"{path}: unreadable {what} ({first})") from None
    pending, seen = [raw], 0
    while pending:  # a walk with a budget, not recursion: a cycle or a bomb stops at the budget
        value = pending.pop()
        seen += 1
        if seen > MAX_YAML_VALUES:
            raise ConfigError(
                f"{path}: {what} holds more than {MAX_YAML_VALUES:,} values once its aliases (*name) are "
                "expanded, or an alias that contains itself"
            )
        if isinstance(value, dict):
            pending += [*value.keys(), *value.values()]
        elif isinstance(value, list):
            pending += value
    return raw


def to_dict(obj) -> dict:
    """A config as plain YAML/JSON values (paths as strings, tuples as lists)."""

    def convert(value):
        if isinstance(value, Path):
            return str(value)
        if isinstance(value, dict):
            return {k: convert(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [convert(v) for v in value]
        return value

    return convert(dataclasses.asdict(obj))


@functools.cache
def _hints(cls) -> dict[str, Any]:
    """A class's resolved type hints (read-only). Cached: resolving them re-evaluates every
    annotation string, and expanding a spec of 60 runs asked for them 27,000 times (18 s of its 19)."""
    return typing.get_type_hints(cls, include_extras=True)


def _strip(hint):
    """The type under Annotated[...] markers."""
    return typing.get_args(hint)[0] if typing.get_origin(hint) is typing.Annotated else hint


def _markers(hint) -> tuple:
    return typing.get_args(hint)[1:] if typing.get_origin(hint) is typing.Annotated else ()


def _is_union(hint) -> bool:
    return typing.get_origin(hint) in (typing.Union, types.UnionType)


def _items(hint) -> tuple | None:
    """The item types of a list / tuple setting (one type and Ellipsis for any length), else None."""
    hint = _strip(hint)
    origin = typing.get_origin(hint)
    if origin is list:
        return (typing.get_args(hint)[0], ...)
    if origin is tuple:
        return typing.get_args(hint)
    return None


def _item_types(items: tuple, count: int) -> list:
    return [items[0]] * count if items[-1] is Ellipsis else list(items)


def nested_class(cls, key: str) -> type | None:
    """The dataclass the setting `key` of `cls` groups, as declared."""
    return _nested(_hints(cls)[key])


def _nested(hint) -> type | None:
    """The dataclass a setting groups, if it is a group."""
    hint = _strip(hint)
    return hint if dataclasses.is_dataclass(hint) else None


def describe(hint) -> str:
    """A type as a user reads it: 'an integer', 'one of vgg, alex, squeeze', ..."""
    hint = _strip(hint)
    if typing.get_origin(hint) is Literal:
        return "one of " + ", ".join(map(str, typing.get_args(hint)))
    if _is_union(hint):
        return " or ".join(describe(arg) for arg in typing.get_args(hint))
    if _items(hint) is not None:
        return "a list of " + describe(_items(hint)[0]).removeprefix("an ").removeprefix("a ") + "s"
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string", Path: "a path",
            type(None): "null"}.get(hint, str(hint))  # fmt: skip


def matches(value, hint) -> bool:
    """Whether a plain (YAML) value fits a setting's type."""
    hint = _strip(hint)
    origin = typing.get_origin(hint)
    if origin is Literal:
        return any(value == choice and type(value) is type(choice) for choice in typing.get_args(hint))
    if _is_union(hint):
        return any(matches(value, arg) for arg in typing.get_args(hint))
    if hint is type(None):
        return value is None
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint in (int, bool, str):
        return type(value) is hint
    if hint is Path:
        return isinstance(value, (str, Path))
    items = _items(hint)
    if items is not None:
        if not isinstance(value, (list, tuple)) or (items[-1] is not Ellipsis and len(value) != len(items)):
            return False
        return all(matches(item, kind) for item, kind in zip(value, _item_types(items, len(value))))
    raise TypeError(f"settings of type {hint} are not supported")


def _convert(value, hint):
    """A matching plain value as the setting holds it (paths as Path, lists as tuples, ints as floats)."""
    hint = _strip(hint)
    if value is None:
        return None
    if _is_union(hint):
        options = [arg for arg in typing.get_args(hint) if arg is not type(None)]
        return next(_convert(value, arg) for arg in options if matches(value, arg))
    if hint is Path:
        return Path(value)
    if hint is float:
        return float(value)
    items = _items(hint)
    if items is not None:
        converted = [_convert(item, kind) for item, kind in zip(value, _item_types(items, len(value)))]
        return converted if typing.get_origin(hint) is list else tuple(converted)
    return value


def from_dict(cls: type[T], raw, source: str | Path = "config", prefix: str = "") -> T:
    """A `cls` from plain values; a setting of the wrong type or an unknown one is one error naming it."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: setting '{prefix.rstrip('.') or cls.__name__}' must be a mapping, got {raw!r}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = _hints(cls)
    kwargs = {}
    for key, value in raw.items():
        if key not in fields:
            raise ConfigError(f"{source}: unknown setting '{prefix}{key}' for {cls.__name__}")
        group = _group(cls, key, raw)
        if group is not None:
            kwargs[key] = from_dict(group, value, source, f"{prefix}{key}.")
        elif not matches(value, hints[key]):
            raise ConfigError(f"{source}: setting '{prefix}{key}' must be {describe(hints[key])}, got {value!r}"[:300])
        else:
            kwargs[key] = _convert(value, hints[key])
    try:
        return cls(**kwargs)
    except TypeError:  # a required setting is missing
        missing = [n for n, f in fields.items() if n not in kwargs and _required(f)]
        if missing:
            raise ConfigError(f"{source}: setting '{prefix}{missing[0]}' is required") from None
        raise


def _group(cls, key: str, raw: dict) -> type | None:
    """The dataclass the setting `key` of `cls` groups (given the config's plain values), if any."""
    group = _nested(_hints(cls)[key])
    if group is not None and hasattr(cls, "settings_group"):
        return cls.settings_group(key, raw)
    return group


def _required(field: dataclasses.Field) -> bool:
    return field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING


def with_settings(obj: T, settings: dict[str, Any], source: str | Path = "settings") -> T:
    """A copy of `obj` with dotted settings ({'eval.every': 100}) changed, checked as YAML is."""
    raw = to_dict(obj)
    for dotted, value in settings.items():
        *groups, last = dotted.split(".")
        node = raw
        for part in groups:
            if not isinstance(node.get(part), dict):
                raise ConfigError(f"{source}: unknown setting '{dotted}'")
            node = node[part]
        node[last] = to_dict_value(value)
    # Checked once every value is in: which settings a group has can depend on the others.
    for dotted in settings:
        *groups, last = dotted.split(".")
        node, cls = raw, type(obj)
        for part in groups:
            group = _group(cls, part, node) if part in _hints(cls) else None
            if group is None:
                raise ConfigError(f"{source}: unknown setting '{dotted}'")
            node, cls = node[part], group
        if last not in _hints(cls) or _nested(_hints(cls)[last]) is not None:
            raise ConfigError(f"{source}: unknown setting '{dotted}'")
    return from_dict(type(obj), raw, source)


def to_dict_value(value):
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [to_dict_value(v) for v in value]
    return value


def flatten(d: dict, prefix: str = "") -> dict:
    """{'eval': {'every': 100}} -> {'eval.every': 100}."""
    flat = {}
    for key, value in d.items():
        if isinstance(value, dict):
            flat.update(flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


# Command-line flags, named by tyro's rules: --name-with-dashes, groups as --group.name,
# booleans as --name / --no-name, tyro.conf.arg(name=...) renaming, OmitArgPrefixes dropping the
# group's prefix, tyro.conf.Positional for positional arguments.

_POSITIONAL = _markers(tyro.conf.Positional[int])
_OMIT_PREFIX = tyro.conf.OmitArgPrefixes
_APPEND = tyro.conf.UseAppendAction


def _renamed(hint) -> str | None:
    for marker in _markers(hint):
        name = getattr(marker, "name", None)
        if type(marker).__name__ == "_ArgConfig" and name is not None:
            return name
    return None


@dataclasses.dataclass(frozen=True)
class Flag:
    """One command-line setting: its dotted key in the config and its flag (or positional name)."""

    key: str
    flag: str
    hint: Any
    positional: bool
    required: bool


def flags_of(cls, prefix: str = "", flag_prefix: str = "") -> list[Flag]:
    """Every leaf setting of `cls` with the flag tyro gives it."""
    out = []
    for f in dataclasses.fields(cls):
        hint = _hints(cls)[f.name]
        name = (_renamed(hint) or f.name).replace("_", "-")
        group = _nested(hint)
        if group is not None:
            inner = flag_prefix if _OMIT_PREFIX in _markers(hint) else f"{flag_prefix}{name}."
            out += flags_of(group, f"{prefix}{f.name}.", inner)
            continue
        positional = any(m in _POSITIONAL for m in _markers(hint))
        out.append(Flag(f"{prefix}{f.name}", f"{flag_prefix}{name}", hint, positional, _required(f) and not prefix))
    return out


def command_flags(cls) -> list[Flag]:
    """The flags a command accepts: flags_of(cls) and the config's settings_extra_flags()."""
    extra = cls.settings_extra_flags() if hasattr(cls, "settings_extra_flags") else []
    return flags_of(cls) + extra


def option_strings(flag: Flag) -> list[str]:
    if flag.positional:
        return []
    if _strip(flag.hint) is bool:
        head, _, last = flag.flag.rpartition(".")
        return [f"--{flag.flag}", f"--{head + '.' if head else ''}no-{last}"]
    return [f"--{flag.flag}"]


def _parse_value(text: str, hint, flag: str):
    hint = _strip(hint)
    if text == "" and Path in (typing.get_args(hint) if _is_union(hint) else (hint,)):
        # Path("") is the current folder: an empty --out would write there, --run read there.
        raise ConfigError(f"{flag}: an empty path; name the file or folder ('.' for the current folder)")
    if _is_union(hint):
        args = typing.get_args(hint)
        if type(None) in args and text in _NONE_TEXTS:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _parse_value(text, arg, flag)
            except ConfigError:
                continue
        raise ConfigError(f"{flag}: expected {describe(hint)}, got {text!r}")
    if typing.get_origin(hint) is Literal:
        for choice in typing.get_args(hint):
            if str(choice) == text:
                return choice
        choices = ", ".join(map(str, typing.get_args(hint)))
        name = flag.rsplit(".", 1)[-1].lstrip("-").replace("-", " ")
        raise ConfigError(f"{flag}: unknown {name} '{text}' (choose from {choices})")
    try:
        if hint is int:
            return int(text)
        if hint is float:
            return float(text)
    except ValueError:
        raise ConfigError(f"{flag}: expected {describe(hint)}, got {text!r}") from None
    if hint is Path:
        return Path(text)
    if hint is str:
        return text
    if hint is bool:  # a bool that may be unset takes a value (tyro's --name {None,True,False})
        if text.lower() in ("true", "false"):
            return text.lower() == "true"
        raise ConfigError(f"{flag}: expected {describe(hint)}, got {text!r}")
    raise TypeError(f"flags of type {hint} are not supported")


class ArgumentParser(argparse.ArgumentParser):
    """argparse with usage errors as one line (a ConfigError), through its documented `error` hook."""

    def error(self, message: str) -> typing.NoReturn:
        raise ConfigError(message)


def _looks_negative(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return text.startswith("-")


def _negative_values_joined(argv: list[str], one_value: set[str]) -> list[str]:
    """argv with `--flag -1e-3` written `--flag=-1e-3`: argparse takes a value that starts with '-'
    for an option unless it reads as a plain negative number, and '-1e-3' or '-inf' do not."""
    out: list[str] = []
    for arg in argv:
        if out and out[-1] in one_value and _looks_negative(arg):
            out[-1] = f"{out[-1]}={arg}"
        else:
            out.append(arg)
    return out


def parse_flag_settings(cls, argv: list[str], prog: str) -> dict[str, Any]:
    """The settings the flags in argv give, as {dotted key: typed value}; only those given."""
    parser = ArgumentParser(prog=prog, add_help=False, allow_abbrev=False)
    flags = command_flags(cls)
    for flag in flags:
        strings = option_strings(flag)
        hint = _strip(flag.hint)
        if not strings:
            parser.add_argument(flag.key, metavar=flag.flag.upper(), default=argparse.SUPPRESS,
                                nargs=None if flag.required else "?")  # fmt: skip
        elif hint is bool:
            parser.add_argument(strings[0], dest=flag.key, action="store_const", const=True, default=argparse.SUPPRESS)
            parser.add_argument(strings[1], dest=flag.key, action="store_const", const=False, default=argparse.SUPPRESS)
        else:
            items = _items(hint)
            if _APPEND in _markers(flag.hint):  # --run A --run B
                parser.add_argument(strings[0], dest=flag.key, action="append", default=argparse.SUPPRESS)
                continue
            nargs = None if items is None else "*" if items[-1] is Ellipsis else len(items)
            parser.add_argument(strings[0], dest=flag.key, nargs=nargs, default=argparse.SUPPRESS)
    one_value = {strings[0] for flag in flags if (strings := option_strings(flag)) and _strip(flag.hint) is not bool
                 and _items(flag.hint) is None and _APPEND not in _markers(flag.hint)}  # fmt: skip
    values = vars(parser.parse_args(_negative_values_joined(argv, one_value)))
    hints = {flag.key: (flag.hint, "--" + flag.flag) for flag in flags}
    settings = {}
    for key, value in values.items():
        hint, flag = hints[key]
        if isinstance(value, bool):
            settings[key] = value
        elif isinstance(value, list):
            kinds = _item_types(_items(hint), len(value))
            settings[key] = _convert([_parse_value(v, kind, flag) for v, kind in zip(value, kinds)], hint)
        else:
            settings[key] = _parse_value(value, hint, flag)
    return settings


def print_help(cls: type, prog: str, description: str | None, default=None) -> typing.NoReturn:
    """tyro renders --help (and exits): the parser above never reads it."""
    tyro.cli(cls, args=["--help"], prog=prog, description=description, default=default)
    raise SystemExit(0)


def wants_help(argv: list[str]) -> bool:
    return any(arg in ("-h", "--help") for arg in argv)


def parse_flags(
    cls: type[T],
    argv: list[str],
    prog: str,
    description: str | None = None,
    default: T | Callable[[dict], T] | None = None,
) -> T:
    """A `cls` from command-line flags on top of `default` (an instance, or a function of the
    parsed settings that makes one, e.g. a preset's defaults once --preset is known)."""
    if wants_help(argv):
        print_help(cls, prog, description, default if dataclasses.is_dataclass(default) else None)
    settings = parse_flag_settings(cls, argv, prog)
    base = default(settings) if callable(default) and not dataclasses.is_dataclass(default) else default
    if base is None:
        raw: dict = {}
        for dotted, value in settings.items():
            node = raw
            *groups, last = dotted.split(".")
            for part in groups:
                node = node.setdefault(part, {})
            node[last] = to_dict_value(value)
        missing = [f for f in flags_of(cls) if f.required and f.key not in settings]
        if missing:
            what = missing[0].flag.upper() if missing[0].positional else "--" + missing[0].flag
            raise ConfigError(f"the following arguments are required: {what}")
        return from_dict(cls, raw, prog)
    return with_settings(base, settings, prog)


def setting_keys(cls, named: dict[str, Any], source: str | Path = "settings") -> dict[str, Any]:
    """Settings named by dotted key ('data.downscale') or by flag ('downscale', 'eval.lpips-normalize'),
    by dotted key."""
    keys = {}
    for flag in command_flags(cls):
        keys[flag.key] = flag.key
        keys[flag.flag] = keys[flag.flag.replace("-", "_")] = flag.key
    out = {}
    for name, value in named.items():
        if name not in keys:
            raise ConfigError(f"{source}: unknown setting '{name}'")
        out[keys[name]] = value
    return out


def to_flags(cls, named: dict[str, Any]) -> list[str]:
    """Command-line flags that give these settings (named by dotted key or flag)."""
    by_key = {flag.key: flag for flag in command_flags(cls)}
    args: list[str] = []
    for key, value in setting_keys(cls, named).items():
        flag = by_key[key]
        strings = option_strings(flag)
        if isinstance(value, bool) and _strip(flag.hint) is bool:
            args.append(strings[0] if value else strings[1])
        elif isinstance(value, (list, tuple)):
            args += [strings[0], *map(str, value)]
        else:
            text = _NONE_TEXT if value is None else str(value)
            args += [strings[0], text] if strings else [text]
    return args
