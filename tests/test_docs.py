"""The documentation is tested: every relative link and anchor in README.md and the docs pages
resolves where the page is read - on GitHub (the files as committed, GitHub's heading anchors) and on
the built site (docs/ plus the generated pages, MkDocs' anchors) - and every `liquidgs ...` command line
they show parses with the current flags. Each problem is one line naming the page and the line. No
MkDocs needed (`make docs` builds the site itself)."""

from __future__ import annotations

import importlib.util
import re
import sys
import unicodedata
from pathlib import Path

import pytest
import yaml

from liquidgs.commands.catalog import all_option_strings, check_command_line, commands
from liquidgs.errors import ConfigError
from liquidgs.fields.testing import plugin_registry

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

FENCE = re.compile(r"^\s*(```|~~~)")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
INLINE_CODE = re.compile(r"(`+)(.+?)\1")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
SHELLS = {"", "bash", "sh", "shell", "console"}


def generated_pages() -> dict[str, str]:
    """The pages `make docs` writes from the code (scripts/docs_hooks.py), by path under docs/."""
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "scripts" / "docs_hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generated_pages()


GENERATED = generated_pages()


def pages() -> dict[Path, str]:
    """Every page as the site shows it: README.md, docs/**/*.md, the generated ones as the code writes them."""
    out = {ROOT / "README.md": (ROOT / "README.md").read_text()}
    out.update({path: path.read_text() for path in sorted(DOCS.rglob("*.md"))})
    out.update({DOCS / name: text for name, text in GENERATED.items()})
    return out


PAGES = pages()
# The pages as committed (what GitHub shows), the generated ones only where they are committed.
COMMITTED = {path: path.read_text() for path in [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]}


def mkdocs_slug(text: str) -> str:
    """The anchor MkDocs gives a heading (Python-Markdown's toc slugify)."""
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def github_slug(text: str) -> str:
    """The anchor GitHub gives a heading of a Markdown file it shows (README.md)."""
    return re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")


def prose_lines(text: str):
    """(line number, line, in a shell code block?) for each line; fence lines themselves skipped."""
    fence, shell = None, False
    for number, line in enumerate(text.splitlines(), 1):
        match = FENCE.match(line)
        if match and (fence is None or line.strip().startswith(fence)):
            if fence is None:
                fence, shell = match.group(1), line.strip()[3:].strip().lower() in SHELLS
            else:
                fence = None
            continue
        yield number, line, fence is not None, shell


def anchors(path: Path, github: bool) -> set[str]:
    """The heading anchors of a page as GitHub gives them (the file as committed) or as the site does."""
    slug = github_slug if github else mkdocs_slug
    seen: dict[str, int] = {}
    out = set()
    text = COMMITTED[path] if github else PAGES[path]
    for _, line, in_code, _ in prose_lines(text):
        heading = HEADING.match(line)
        if in_code or not heading:
            continue
        text = re.sub(r"`([^`]*)`", r"\1", heading.group(2))
        text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
        anchor = slug(text)
        count = seen.get(anchor, 0)
        seen[anchor] = count + 1
        out.add(anchor if count == 0 else f"{anchor}_{count}" if slug is mkdocs_slug else f"{anchor}-{count}")
    return out


def link_problem(page: Path, target: str) -> str | None:
    """What is wrong with a relative link where its page is read, or None: on GitHub (a file or folder
    committed at that path; the anchor GitHub gives the heading) and, for a page under docs/, on the
    site (a file under docs/ or a generated page; the anchor MkDocs gives the heading)."""
    if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
        return None
    where, _, anchor = target.partition("#")
    resolved = (page.parent / where).resolve() if where else page
    name = resolved.relative_to(ROOT) if resolved.is_relative_to(ROOT) else resolved
    on_github = resolved in COMMITTED or resolved.exists()
    on_site = page.is_relative_to(DOCS) and (resolved in PAGES or on_github) and resolved.is_relative_to(DOCS)
    if not on_github and resolved not in PAGES:
        return f"broken link '{target}': no {name}"
    if not on_github:
        return f"link '{target}' is broken on GitHub: {name} is generated, not committed (`make reference`)"
    if page.is_relative_to(DOCS) and not on_site:
        return f"link '{target}' is broken on the site: {name} is outside docs/"
    if anchor and resolved.suffix == ".md":
        if resolved not in PAGES or resolved not in COMMITTED:
            return f"link '{target}': {resolved.name} is not a documentation page"
        views = [("GitHub", True)] + ([("the site", False)] if page.is_relative_to(DOCS) else [])
        broken = [view for view, github in views if anchor not in anchors(resolved, github)]
        if len(broken) == len(views):
            return f"broken anchor '{target}': no heading '#{anchor}' in {name}"
        if broken:
            return f"anchor '{target}' is broken on {broken[0]}: no heading gives '#{anchor}' there in {name}"
    return None


COMMAND_NAMES = {command.name for command in commands()} | {"liquidgs"}


def names_a_command(code: str) -> bool:
    """Prose names a command (`liquidgs data video`) or a command family with a placeholder
    (`liquidgs COMMAND --help`, `liquidgs bench raster|fields`): not a command line to parse."""
    words = code.split()
    return code in COMMAND_NAMES or any(word.isupper() or "|" in word for word in words[1:3])


def command_problem(line: str) -> str | None:
    try:
        check_command_line(line)
    except ConfigError as err:
        return f"'{line.strip()}' does not parse: {err}"
    return None


def shell_commands(text: str):
    """(line number, command) of each `liquidgs ...` line in the shell code blocks (continuations joined)."""
    pending, start = "", 0
    for number, line, in_code, shell in prose_lines(text):
        if not (in_code and shell):
            continue
        line = line.strip().removeprefix("$ ")
        if pending:
            line, number = pending + " " + line, start
            pending = ""
        if line.endswith("\\"):
            pending, start = line[:-1], number
            continue
        if line.startswith("liquidgs "):
            yield number, line


def problems(path: Path) -> list[str]:
    text = PAGES[path]
    name = path.relative_to(ROOT)
    options = all_option_strings()
    found = []
    for number, line, in_code, _ in prose_lines(text):
        if in_code:
            continue
        prose = INLINE_CODE.sub("", line)
        for target in LINK.findall(prose):
            problem = link_problem(path, target)
            if problem:
                found.append(f"{name}:{number}: {problem}")
        for _, code in INLINE_CODE.findall(line):
            code = code.strip()
            if code.startswith("liquidgs ") and not names_a_command(code):
                problem = command_problem(code)
            elif re.fullmatch(r"--[a-z][a-z0-9.-]*", code.split(" ")[0]) and code.split(" ")[0] not in options:
                problem = f"flag '{code.split(' ')[0]}' is no flag of any liquidgs command"
            else:
                problem = None
            if problem:
                found.append(f"{name}:{number}: {problem}")
    for number, command in shell_commands(text):
        problem = command_problem(command)
        if problem:
            found.append(f"{name}:{number}: {problem}")
    return found


@pytest.fixture(scope="module")
def template_plugin():
    """The docs' plugin examples train the template plugin's `wave` field (examples/field-plugin):
    registered from the checkout, as its own tests do, so its command lines parse."""
    sys.path.insert(0, str(ROOT / "examples" / "field-plugin" / "src"))
    try:
        from wave_field import register

        with plugin_registry(register, package="liquidgs-wave-field"):
            yield
    finally:
        sys.path.remove(str(ROOT / "examples" / "field-plugin" / "src"))


@pytest.mark.parametrize("path", list(PAGES), ids=lambda p: str(p.relative_to(ROOT)))
def test_links_resolve_and_commands_parse(path, template_plugin):
    found = problems(path)
    assert not found, "\n".join(found)


def test_a_broken_link_a_missing_anchor_and_a_removed_flag_are_each_one_line(tmp_path):
    page = DOCS / "getting-started.md"
    PAGES[page] = PAGES[page] + (
        "\nSee [the demo](results/nowhere.md) and [presets](training.md#no-such-heading).\n"
        "```bash\nliquidgs train --data scenes/x --no-such-flag 3\n```\n"
        "Or `--densify.no-such-setting 2`.\n"
    )
    try:
        found = problems(page)
    finally:
        PAGES[page] = page.read_text()
    lines = len(PAGES[page].splitlines())
    assert len(found) == 4, found
    assert found[0].startswith(f"docs/getting-started.md:{lines + 2}: broken link 'results/nowhere.md'")
    assert found[1].startswith(f"docs/getting-started.md:{lines + 2}: broken anchor 'training.md#no-such-heading'")
    assert found[2].startswith(f"docs/getting-started.md:{lines + 6}: flag '--densify.no-such-setting'")
    assert found[3].startswith(f"docs/getting-started.md:{lines + 4}: 'liquidgs train --data scenes/x --no-such-flag")
    assert "unrecognized arguments: --no-such-flag" in found[3]
    assert all("\n" not in line for line in found)


def test_a_link_or_anchor_that_works_only_on_github_or_only_on_the_site_is_one_line():
    page, fake, generated = DOCS / "getting-started.md", DOCS / "fake.md", DOCS / "reference" / "fake.md"
    # Python-Markdown drops the dash, GitHub keeps it: '#sizes-and-caps' on the site, '#sizes--and-caps' on GitHub.
    COMMITTED[fake] = PAGES[fake] = "# Fake\n\n## Sizes — and caps\n"
    PAGES[generated] = "# Generated only\n"
    PAGES[page] = COMMITTED[page] + (
        "\n[ref](reference/fake.md), [make](../Makefile), [a](fake.md#sizes-and-caps), [b](fake.md#sizes--and-caps)\n"
    )
    try:
        found = problems(page)
    finally:
        PAGES[page] = COMMITTED[page]
        del COMMITTED[fake], PAGES[fake], PAGES[generated]
    assert found == [
        f"docs/getting-started.md:{len(PAGES[page].splitlines()) + 2}: {problem}"
        for problem in (
            "link 'reference/fake.md' is broken on GitHub: docs/reference/fake.md is generated, not committed"
            " (`make reference`)",
            "link '../Makefile' is broken on the site: Makefile is outside docs/",
            "anchor 'fake.md#sizes-and-caps' is broken on GitHub: no heading gives '#sizes-and-caps' there in"
            " docs/fake.md",
            "anchor 'fake.md#sizes--and-caps' is broken on the site: no heading gives '#sizes--and-caps' there in"
            " docs/fake.md",
        )
    ], found
    # README.md is read on GitHub only: a link from it to a file outside docs/ is fine.
    assert link_problem(ROOT / "README.md", "Makefile") is None


def test_the_committed_reference_pages_are_what_the_code_generates():
    """docs/reference/{cli,specs,errors}.md are committed so that links to them work on GitHub; after a
    change to the settings, the specs or an error message, `make reference` rewrites them."""
    stale = [name for name, text in GENERATED.items() if COMMITTED.get(DOCS / name) != text]
    assert not stale, f"out of date with the code (run `make reference`): {', '.join(f'docs/{n}' for n in stale)}"


def nav_pages(entries) -> set[str]:
    """The page paths the site's nav names, at any depth (an entry is a path or {title: entries})."""
    found = set()
    for entry in entries:
        if isinstance(entry, str):
            found.add(entry)
        else:
            for value in entry.values():
                found |= {value} if isinstance(value, str) else nav_pages(value)
    return found


def test_every_docs_page_is_in_the_site_nav():
    # `mkdocs build --strict` (run by .ci/run after the tests) refuses a page left out of the nav;
    # this holds the same rule inside `make test`, where it names the page.
    site = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    listed = nav_pages(site["nav"])
    on_disk = {str(path.relative_to(DOCS)) for path in DOCS.rglob("*.md")} | set(GENERATED)
    assert not on_disk - listed, f"pages missing from mkdocs.yml nav: {sorted(on_disk - listed)}"
    assert not listed - on_disk, f"mkdocs.yml nav names pages that do not exist: {sorted(listed - on_disk)}"


def test_slugs_are_those_mkdocs_and_github_give():
    assert mkdocs_slug("7. A lens: data undistort") == "7-a-lens-data-undistort"
    assert mkdocs_slug("The paper's protocol, setting by setting") == "the-papers-protocol-setting-by-setting"
    assert github_slug("What the demo shows (measured)") == "what-the-demo-shows-measured"


def test_the_cli_reference_lists_every_flag_of_every_command():
    reference = GENERATED["reference/cli.md"]
    for option in all_option_strings() - {"--help", "-h", "--config"}:
        assert f"`{option}`" in reference, option


def test_every_flag_of_every_command_says_what_it_does():
    """Each flag's row in the command-line reference (built from the same help as --help) has a
    description, and none is a type checker's comment."""
    section, empty = "", []
    for line in GENERATED["reference/cli.md"].splitlines():
        if line.startswith("## "):
            section = line[3:]
        elif line.startswith("| `--"):
            cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
            if not cells[-1] or "type: ignore" in cells[-1]:
                empty.append(f"{section} {cells[0]}")
    assert not empty, empty


def test_the_help_states_the_track_step_the_code_uses():
    """`data flow` and `--flow.tracks` say how many pairs a track chains; TRACK_STEP owns the number."""
    from liquidgs.data.flow import TRACK_STEP

    words = {2: "two", 3: "three", 4: "four", 5: "five", 6: "six"}
    reference = GENERATED["reference/cli.md"]
    stated = re.findall(r"chained over (\w+) pairs", reference)
    assert len(stated) == 2, stated
    assert set(stated) <= {str(TRACK_STEP), words.get(TRACK_STEP)}, (stated, TRACK_STEP)


# An absolute path of the machine a page or report was written on (/tmp/..., /work/..., /root/...,
# /home/...): meaningless to a reader elsewhere. After a space, a bracket, a quote, a backtick, `=` or `:`.
MACHINE_PATH = re.compile(r"(?<![^\s(`'\"=:,])/(?:tmp|work|root|home)/")


def machine_paths(root: Path) -> list[str]:
    """'file:line: path' for each machine path in README.md and the committed .md / .txt / .tex under docs/."""
    # The generated reference pages print the code's own defaults (bench acceptance's /tmp folder).
    generated = {root / "docs" / name for name in GENERATED}
    files = [root / "README.md"] + sorted(
        p for p in (root / "docs").rglob("*") if p.suffix in {".md", ".txt", ".tex"} and p not in generated
    )
    found = []
    for path in files:
        for number, line in enumerate(path.read_text().splitlines(), 1):
            for match in MACHINE_PATH.finditer(line):
                word = line[match.start() :].split()[0].strip("`'\",;()")
                found.append(f"{path.relative_to(root)}:{number}: {word}")
    return found


def test_no_page_or_committed_report_names_a_machine_path(tmp_path):
    found = machine_paths(ROOT)
    assert not found, "\n".join(found)
    (tmp_path / "docs" / "experiments" / "x").mkdir(parents=True)
    (tmp_path / "README.md").write_text("Scores at 1/8; see https://example.org/tmp/a.\n")
    (tmp_path / "docs" / "experiments" / "x" / "report.md").write_text("folder `/tmp/exp1`, data root `x`\n")
    (tmp_path / "docs" / "experiments" / "x" / "tables.tex").write_text("looked for: /root/.cache/a.pth\n")
    (tmp_path / "docs" / "experiments" / "x" / "note.txt").write_text("\n(/home/me/data)\n")
    assert machine_paths(tmp_path) == ["docs/experiments/x/note.txt:2: /home/me/data",
                                       "docs/experiments/x/report.md:1: /tmp/exp1",
                                       "docs/experiments/x/tables.tex:1: /root/.cache/a.pth"]  # fmt: skip


RESULTS_PAGE_LINES = 250
"""A results page's most lines: its current figures; the runs behind them and what they superseded
go to the measurement log (docs/results/log.md), which may be long."""
README_LINES = 120


def page_size_problems(root: Path) -> list[str]:
    """'file: N lines (at most M)' for README.md and each results page but the log over its bound."""
    bounds = {root / "README.md": README_LINES}
    bounds |= {p: RESULTS_PAGE_LINES for p in sorted((root / "docs" / "results").glob("*.md")) if p.name != "log.md"}
    sizes = {path: len(path.read_text().splitlines()) for path in bounds}
    return [f"{p.relative_to(root)}: {n} lines (at most {bounds[p]})" for p, n in sizes.items() if n > bounds[p]]


def test_the_readme_and_each_results_page_stay_short(tmp_path):
    assert not page_size_problems(ROOT), page_size_problems(ROOT)
    (tmp_path / "docs" / "results").mkdir(parents=True)
    (tmp_path / "README.md").write_text("line\n" * README_LINES)
    (tmp_path / "docs" / "results" / "log.md").write_text("line\n" * 1000)
    (tmp_path / "docs" / "results" / "clips.md").write_text("line\n" * (RESULTS_PAGE_LINES + 1))
    assert page_size_problems(tmp_path) == ["docs/results/clips.md: 251 lines (at most 250)"]


# Words for how this project is built rather than how liquidgs is used: an issue number with no link,
# the project's shared folder in a command a user would type.
PROJECT_WORDS = re.compile(r"\b[Ii]ssues?\s+#?\d+|(?<![\w./])\.\./shared\b")


def project_word_problems(root: Path) -> list[str]:
    """'file:line: words' in README.md and the docs pages but development.md, which describes the
    test suite's shared folder (../shared beside the clone) as the Makefile uses it."""
    skip = {root / "docs" / "development.md"} | {root / "docs" / name for name in GENERATED}
    files = [root / "README.md"] + sorted(p for p in (root / "docs").rglob("*.md") if p not in skip)
    found = []
    for path in files:
        text = path.read_text()
        for match in PROJECT_WORDS.finditer(text):  # the whole text: "issue" may end a line
            number = text.count("\n", 0, match.start()) + 1
            found.append(f"{path.relative_to(root)}:{number}: {' '.join(match[0].split())}")
    return found


def test_no_page_names_an_issue_number_or_the_projects_shared_folder(tmp_path):
    assert not project_word_problems(ROOT), "\n".join(project_word_problems(ROOT))
    (tmp_path / "docs").mkdir()
    (tmp_path / "README.md").write_text("a bound issue 32 allows\nsee `issues/12`, the issue\n7 times\n")
    (tmp_path / "docs" / "a.md").write_text("liquidgs experiment run mini --data-root ../shared/data/dnerf\n")
    (tmp_path / "docs" / "development.md").write_text("tests read ../shared\n")
    assert project_word_problems(tmp_path) == [
        "README.md:1: issue 32",
        "README.md:2: issue 7",
        "docs/a.md:1: ../shared",
    ]


def test_the_site_widens_its_column_and_wraps_table_cells():
    """The readthedocs theme's 800 px column and one-line cells cut wide tables (development.md)."""
    config = (ROOT / "mkdocs.yml").read_text()
    sheets = re.search(r"^extra_css:\n((?:  - .+\n)+)", config, re.M)
    assert sheets, "mkdocs.yml has no extra_css"
    css = "".join((DOCS / line.strip()[2:]).read_text() for line in sheets[1].splitlines())
    css = re.sub(r"/\*.*?\*/", "", css, flags=re.S)
    column = re.search(r"\.wy-nav-content\s*\{[^}]*max-width:\s*(\d+)px", css)
    assert column and int(column[1]) >= 1366, "the content column must reach a 1366 px window's width"
    assert re.search(r"\.wy-table-responsive table td[^{]*\{[^}]*white-space:\s*normal", css)
