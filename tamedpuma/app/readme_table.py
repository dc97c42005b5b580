"""The README's Table 1: the current success rates beside the paper's, written from the table
that ``python -m tamedpuma.analysis.tables`` wrote (``table1.md``), never typed.

``python -m tamedpuma.app.results_page table1 RUNS --readme README.md`` replaces the README's
block between ``<!-- result: table1-summary -->`` and ``<!-- /result -->`` with the text of
:func:`summary_block`: a line of provenance (dates, run count, code revision and models, as the
runs' ``summary.json`` record them) and one row per method of the analysis's table, in its
order, with the paper's success rate and path difference where the paper has the method
(Bakker et al. 2025, Table 1).
"""

from __future__ import annotations

#: the README's block (results_page.MARKERS wraps it)
BLOCK = "table1-summary"

#: the paper's Table 1: success rate and path difference to PUMA [m] (mean ± std)
PAPER = {"puma": ("0.40", "0"), "modulation_ik": ("0.57", "0.39 ± 0.42"),
         "fabrics": ("0.83", "0.22 ± 0.27"), "fpm": ("1.00", "0.02 ± 0.04"),
         "cpm": ("1.00", "0.04 ± 0.06")}

#: how the README names a method label (others: the label itself, in code type)
NAMES = {"puma": "PUMA", "modulation_ik": "Modulation-IK", "fabrics": "Fabrics", "fpm": "FPM",
         "cpm": "CPM", "fpm_literal": "FPM, eq. 9 as written (`fpm_literal`)",
         "cpm_literal": "CPM, eq. 10 as written (`cpm_literal`)",
         "cpm_original": "CPM, the authors' code (`cpm_original`)",
         "pink_cbf": "PUMA + QP IK with barriers (`pink_cbf`, examples/)"}

#: (README column, the analysis's column, which part of an "a / b" cell)
COLUMNS = (("success, paper criterion", "success (paper)", 0),
           ("success, whole body", "success (whole body)", 0),
           ("with orientation (paper)", "with orientation (paper / whole body)", 0),
           ("converged (paper)", "converged (paper / whole body)", 0),
           ("path difference to PUMA [m]", "path difference to PUMA [m]", 0))


def markdown_rows(text: str) -> list[dict[str, str]]:
    """The rows of the first Markdown pipe table in ``text``, as {header: cell}."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip().startswith("|")]
    if len(lines) < 2:
        return []
    cells = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines]
    header = cells[0]
    return [dict(zip(header, row)) for row in cells[2:]]


def _cell(row: dict[str, str], column: str, part: int) -> str:
    value = row.get(column, "").split(" / ")
    return value[part].strip() if len(value) > part and value[part].strip() else "—"


def summary_block(table1_md: str, provenance: str) -> str:
    """The block's text (without its markers): ``provenance``, then the table."""
    heads = [c[0] for c in COLUMNS] + ["paper: success / path difference"]
    lines = [provenance, "", "| method | " + " | ".join(heads) + " |",
             "|---|" + "---|" * len(heads)]
    for row in markdown_rows(table1_md):
        label = row.get("method", "?")
        paper = " / ".join(PAPER[label]) if label in PAPER else "—"
        values = [_cell(row, column, part) for _, column, part in COLUMNS]
        lines.append(f"| {NAMES.get(label, f'`{label}`')} | " + " | ".join(values)
                     + f" | {paper} |")
    return "\n".join(lines)
