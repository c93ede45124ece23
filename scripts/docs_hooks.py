"""The reference pages generated from the code: docs/reference/cli.md, specs.md and errors.md.

They are committed, so that their links work where the Markdown is read (GitHub shows the files as
they are in the repository); `make reference` (this file run as a script) rewrites them after the code
changes, and tests/test_docs.py fails while a committed page differs from what the code generates.
As MkDocs hooks (mkdocs.yml `hooks:`) they are generated again when the site is built, so the site is
never older than the code it is built from."""

from __future__ import annotations

from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"


def generated_pages() -> dict[str, str]:
    """Generated page path (under docs/) -> its Markdown."""
    from liquidgs.commands.catalog import cli_reference

    return {
        "reference/cli.md": cli_reference(),
        "reference/specs.md": specs_reference(),
        "reference/errors.md": errors_reference(),
    }


def specs_reference() -> str:
    """The built-in experiment specs with their runs and training iterations (the GPU estimate's input)."""
    from pathlib import Path

    from liquidgs.experiments import BUILTIN_SPECS
    from liquidgs.train.config import preset_config

    lines = [
        "# Built-in experiment specs",
        "",
        "Generated from `liquidgs.experiments.BUILTIN_SPECS` (what"
        " `liquidgs experiment list` prints). *Iterations* is the spec's training iterations summed over"
        " its runs (each run's `iterations` override, else its preset's); runs shared between specs"
        " (see [Experiments](../experiments.md#sharing-runs)) are counted in each. At R training iterations"
        " per second on one GPU, a spec trains in about iterations / R seconds on that GPU, plus evaluation;"
        " `liquidgs bench gpu` measures R ([GPU acceptance](../gpu.md)).",
        "",
        "| spec | runs | iterations | what |",
        "|---|---|---|---|",
    ]
    for name, spec in BUILTIN_SPECS.items():
        runs = sum(grid.run_count() for grid in spec.grids)
        iterations = sum(
            grid.run_count() * grid.overrides.get("iterations", preset_config(grid.preset, Path(".")).iterations)
            for grid in spec.grids
        )
        what = spec.description.replace("|", "\\|")
        lines.append(f"| `{name}` | {runs:,} | {iterations:,} | {what} |")
    return "\n".join(lines) + "\n"


def on_files(files, config):
    from mkdocs.structure.files import File  # imported here: the tests read generated_pages without MkDocs

    for path, text in generated_pages().items():
        committed = files.get_file_from_path(path)
        if committed is not None:
            files.remove(committed)
        files.append(File.generated(config, path, content=text))
    return files


def write_pages(docs: Path = DOCS) -> list[str]:
    """Write every generated page under ``docs``; return those whose text changed."""
    changed = []
    for path, text in generated_pages().items():
        target = docs / path
        if not target.is_file() or target.read_text() != text:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(text)
            changed.append(path)
    return changed



# The errors a user sees: liquidgs.errors.LiquidGSError and its subclasses (the CLI prints them as one line).
USER_ERRORS = {"LiquidGSError", "ConfigError", "DataError", "RunFolderLocked", "TrainingDiverged",
               "FieldGroupsChanged", "SolveError", "LPIPSUnavailable", "FieldContractError", "NameTaken",
               "WriteRefused"}  # fmt: skip


def _template(node) -> str:
    """A message expression as a template: the literal text, each computed part as `{...}`."""
    import ast

    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(part.value if isinstance(part, ast.Constant) else "{…}" for part in node.values)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        return _template(node.left) + _template(node.right)
    return "{…}"


def error_messages(src) -> list[tuple[str, int, str]]:
    """(module path, line, message template) of every user-facing error raised in the package, in
    the order of the source."""
    import ast

    out = []
    for path in sorted(src.rglob("*.py")):
        if path.name == "catalog.py":  # its errors are the documentation tests', not a user's
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call)):
                continue
            name = getattr(node.exc.func, "id", None) or getattr(node.exc.func, "attr", None)
            if name not in USER_ERRORS or not node.exc.args:
                continue
            args = node.exc.args
            message = f"PATH: {_template(args[1])}" if name == "DataError" and len(args) > 1 else _template(args[0])
            out.append((path.relative_to(src.parent).as_posix(), node.lineno, message))
    return sorted(out)


def errors_reference() -> str:
    """Every one-line error the package raises, by module (the troubleshooting page explains them)."""
    from pathlib import Path

    import liquidgs

    src = Path(liquidgs.__file__).parent
    lines = [
        "# Every error message",
        "",
        "Generated from the package's source (`make reference`, and again when the site is built): every"
        " error liquidgs raises for a user to read (`liquidgs.errors.LiquidGSError` and its kinds), as the template of its line"
        " (`{…}` is filled in: a path, a value, a count). The command prints it as"
        " `liquidgs COMMAND: error: LINE` and exits 2. What the common ones mean and what to do:"
        " [Troubleshooting](../troubleshooting.md).",
        "",
    ]
    module = None
    for path, _, message in error_messages(src):  # no line numbers: any edit above a raise would move them
        if path != module:
            module = path
            lines += ["", f"## `{path}`", ""]
        text = " ".join(message.split()).replace("`", "'")
        lines.append(f"- `{text}`")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    for name in write_pages():
        print(f"wrote docs/{name}")
