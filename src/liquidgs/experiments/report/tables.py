"""Score tables in the paper's layout (column groups of PSNR / SSIM / LPIPS), as Markdown and LaTeX.

Colouring follows the paper: per column, the best, second and third value are coloured
red!60, orange!57 and yellow!55 (higher is better for PSNR and SSIM, lower for LPIPS).
Values are ranked as printed: equal values at the printed precision share a rank, and the
next distinct value takes the next rank (dense ranking) - as the paper's Table II does
(Press SSIM: 0.8618 twice, both second; 0.8613 third). Every row with `ranked` takes part:
this experiment's runs and, with --references, the baselines the paper's table quotes
(D-NeRF, TiNeuVox, NeRF-DS), because the paper ranks every printed row of a column. The
reference rows our rows are compared with (`compare_to`: the paper's own retrained rows, the
published D-3DGS numbers) are shown but not ranked.
"""

from __future__ import annotations

from dataclasses import dataclass, field

# Column groups per block of rows, as the paper's tables wrap their eight scenes in two blocks of four.
GROUPS_PER_BLOCK = 4
RANK_COLOURS = ("red!60", "orange!57", "yellow!55")
MARKDOWN_MARKS = (("**", "**"), ("*", "*"), ("<u>", "</u>"))
MARKDOWN_LEGEND = "best **bold**, second *italic*, third <u>underlined</u>"
SCENE_TITLES = {
    "hellwarrior": "Hell Warrior",
    "bouncingballs": "Bouncing Balls",
    "trex": "T-Rex",
    "standup": "Stand Up",
    "jumpingjacks": "Jumping Jacks",
    "as": "As",
    "mean": "Mean",
}


@dataclass(frozen=True)
class Metric:
    key: str
    title: str
    digits: int
    higher_is_better: bool

    @property
    def latex_title(self) -> str:
        arrow = "\\uparrow" if self.higher_is_better else "\\downarrow"
        return f"{self.title}$\\,{arrow}$"


METRICS = (Metric("psnr", "PSNR", 2, True), Metric("ssim", "SSIM", 4, True), Metric("lpips", "LPIPS", 4, False))


@dataclass(frozen=True)
class Cell:
    value: float
    std: float | None = None
    """Spread over seeds; None with one seed."""


@dataclass
class Row:
    label: str
    latex_label: str
    cells: dict[tuple[str, str], Cell]
    """(group, metric key) -> cell; a missing key prints as a dash."""
    ranked: bool = True
    compare_to: str | None = None
    """For a reference row: the label of the row of ours it is compared with."""


@dataclass
class Table:
    groups: list[str]
    metrics: tuple[Metric, ...]
    rows: list[Row]
    caption: str
    latex_caption: str
    label: str
    colours: int = 3
    """How many ranks are coloured per column (3 in Tables I/II, 1 in the noise study)."""
    signed: bool = False
    """Differences: print an explicit sign."""
    row_header: str = "Method"
    latex_row_header: str | None = None
    """Default: row_header."""
    group_titles: dict[str, str] = field(default_factory=dict)

    def title(self, group: str) -> str:
        return self.group_titles.get(group) or SCENE_TITLES.get(group) or group.capitalize()


def printed(value: float, digits: int, signed: bool = False) -> str:
    return f"{value:+.{digits}f}" if signed else f"{value:.{digits}f}"


def ranks(table: Table) -> dict[tuple[int, str, str], int]:
    """(row index, group, metric key) -> 0 (best), 1, 2 for the coloured cells of ranked rows."""
    out: dict[tuple[int, str, str], int] = {}
    if table.colours == 0:
        return out
    for group in table.groups:
        for metric in table.metrics:
            shown = {
                i: float(printed(row.cells[(group, metric.key)].value, metric.digits))
                for i, row in enumerate(table.rows)
                if row.ranked and (group, metric.key) in row.cells
            }
            distinct = sorted(set(shown.values()), reverse=metric.higher_is_better)[: table.colours]
            for i, value in shown.items():
                if value in distinct:
                    out[(i, group, metric.key)] = distinct.index(value)
    return out


def _cell_text(table: Table, cell: Cell | None, metric: Metric, plus_minus: str) -> str:
    if cell is None:
        return "-"
    text = printed(cell.value, metric.digits, table.signed)
    if cell.std is not None:
        text += f"{plus_minus}{printed(cell.std, metric.digits)}"
    return text


def _blocks(groups: list[str]) -> list[list[str]]:
    return [groups[i : i + GROUPS_PER_BLOCK] for i in range(0, len(groups), GROUPS_PER_BLOCK)]


def to_markdown(table: Table) -> str:
    rank = ranks(table)
    lines = [table.caption, ""]
    for block in _blocks(table.groups):
        header = [table.row_header] + [f"{table.title(g)} {m.title}" for g in block for m in table.metrics]
        lines += ["| " + " | ".join(header) + " |", "|---" + "|---:" * (len(header) - 1) + "|"]
        for i, row in enumerate(table.rows):
            cells = [row.label]
            for group in block:
                for metric in table.metrics:
                    text = _cell_text(table, row.cells.get((group, metric.key)), metric, " ± ")
                    if (i, group, metric.key) in rank:
                        opening, closing = MARKDOWN_MARKS[rank[(i, group, metric.key)]]
                        text = f"{opening}{text}{closing}"
                    cells.append(text)
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def latex_escape(text: str) -> str:
    for char in ("\\", "&", "%", "#", "_", "$", "{", "}"):
        text = text.replace(char, "\\" + char if char != "\\" else "\\textbackslash{}")
    return text


def to_latex(table: Table) -> str:
    """A booktabs table* in the paper's layout; needs \\usepackage[table]{xcolor} and booktabs."""
    rank = ranks(table)
    blocks = _blocks(table.groups)
    width = len(table.metrics)
    spec = "l" + "".join("|" + "c" * width for _ in range(max(len(b) for b in blocks)))
    lines = [
        "\\begin{table*}[!t]",
        "\\centering",
        f"\\caption{{{table.latex_caption}}}",
        f"\\label{{{table.label}}}",
        "\\setlength{\\tabcolsep}{3pt}",
        "\\footnotesize",
        f"\\begin{{tabular}}{{{spec}}}",
        "\\toprule",
    ]
    for b, block in enumerate(blocks):
        if b:
            lines.append("\\midrule")
        heads = [
            f"\\multicolumn{{{width}}}{{c{'|' if j < len(block) - 1 else ''}}}{{{latex_escape(table.title(g))}}}"
            for j, g in enumerate(block)
        ]
        lines.append("& " + " & ".join(heads) + "\\\\")
        titles = [m.latex_title for _ in block for m in table.metrics]
        lines.append(" & ".join([table.latex_row_header or table.row_header, *titles]) + "\\\\")
        lines.append("\\midrule")
        for i, row in enumerate(table.rows):
            cells = [row.latex_label]
            for group in block:
                for metric in table.metrics:
                    text = _cell_text(table, row.cells.get((group, metric.key)), metric, "$\\pm$")
                    if (i, group, metric.key) in rank:
                        text = f"\\cellcolor{{{RANK_COLOURS[rank[(i, group, metric.key)]]}}}{text}"
                    cells.append(text)
            lines.append(" & ".join(cells) + " \\\\")
    lines += ["\\bottomrule", "\\end{tabular}", "\\end{table*}", ""]
    return "\n".join(lines)


def differences(table: Table, caption: str, latex_caption: str, label: str) -> Table | None:
    """Ours minus each reference row, per cell both have; None when no reference row has a partner."""
    ours = {row.label: row for row in table.rows if row.compare_to is None}
    rows = []
    for reference in table.rows:
        partner = ours.get(reference.compare_to or "")
        if reference.compare_to is None or partner is None:
            continue
        cells = {
            key: Cell(partner.cells[key].value - ref.value)
            for key, ref in reference.cells.items()
            if key in partner.cells
        }
        rows.append(
            Row(f"{partner.label} − {reference.label}", f"{partner.latex_label} $-$ {reference.latex_label}", cells)
        )
    if not rows:
        return None
    return Table(table.groups, table.metrics, rows, caption, latex_caption, label, colours=0, signed=True,
                 row_header=table.row_header, latex_row_header=table.latex_row_header,
                 group_titles=table.group_titles)  # fmt: skip


@dataclass
class PlainTable:
    """A simple table (cost, seed spread): a header and rows of (label, LaTeX label, formatted cells)."""

    header: list[str]
    rows: list[tuple[str, str, list[str]]] = field(default_factory=list)

    def add(self, label: str, latex_label: str, cells: list[str]) -> None:
        self.rows.append((label, latex_label, cells))

    def to_markdown(self) -> str:
        lines = ["| " + " | ".join(self.header) + " |", "|---" + "|---:" * (len(self.header) - 1) + "|"]
        return "\n".join(lines + ["| " + " | ".join([label, *cells]) + " |" for label, _, cells in self.rows]) + "\n"

    def to_latex(self, caption: str, label: str) -> str:
        lines = [
            "\\begin{table}[!t]",
            "\\centering",
            f"\\caption{{{caption}}}",
            f"\\label{{{label}}}",
            "\\footnotesize",
            f"\\begin{{tabular}}{{l|{'c' * (len(self.header) - 1)}}}",
            "\\toprule",
            " & ".join(latex_escape(h) for h in self.header) + " \\\\",
            "\\midrule",
            *(" & ".join([latex, *map(latex_escape, cells)]) + " \\\\" for _, latex, cells in self.rows),
            "\\bottomrule",
            "\\end{tabular}",
            "\\end{table}",
            "",
        ]
        return "\n".join(lines)


# Table III (the paper's cost table): one row per deformation field, its parameters in millions and
# how it infers; the smallest field coloured best, the only colour the paper's Table III uses.
PARAMS_MILLIONS = Metric("params", "Params (M)", 2, False)
SIZE_GROUP = "size"


@dataclass(frozen=True)
class SizeRow:
    label: str
    latex_label: str
    params_millions: float
    inference: str
    ranked: bool = True
    """False for the paper's printed rows (--references): shown, not ranked."""


def size_table(rows: list[SizeRow], caption: str, latex_caption: str, label: str) -> tuple[str, str]:
    """Table III in the paper's layout, (Markdown, LaTeX): Deformation field | Params (M) | Inference."""
    table = Table([SIZE_GROUP], (PARAMS_MILLIONS,),
                  [Row(r.label, r.latex_label, {(SIZE_GROUP, "params"): Cell(r.params_millions)}, r.ranked)
                   for r in rows], caption, latex_caption, label, colours=1)  # fmt: skip
    best = {i for (i, _, _), rank in ranks(table).items() if rank == 0}
    header = ["Deformation field", PARAMS_MILLIONS.title, "Inference"]
    md = [caption, "", "| " + " | ".join(header) + " |", "|---|---:|---|"]
    tex = ["\\begin{table}[!t]", "\\centering", f"\\caption{{{latex_caption}}}", f"\\label{{{label}}}",
           "\\setlength{\\tabcolsep}{5pt}", "\\footnotesize", "\\begin{tabular}{l|c|c}", "\\toprule",
           " & ".join(header) + " \\\\", "\\midrule"]  # fmt: skip
    for i, row in enumerate(rows):
        value = printed(row.params_millions, PARAMS_MILLIONS.digits)
        opening, closing = MARKDOWN_MARKS[0] if i in best else ("", "")
        md.append(f"| {row.label} | {opening}{value}{closing} | {row.inference} |")
        cell = f"\\cellcolor{{{RANK_COLOURS[0]}}}{value}" if i in best else value
        tex.append(f"{row.latex_label} & {cell} & {latex_escape(row.inference)} \\\\")
    tex += ["\\bottomrule", "\\end{tabular}", "\\end{table}", ""]
    return "\n".join(md) + "\n", "\n".join(tex)
