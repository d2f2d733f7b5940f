"""Tables as text to paste into a paper or a README: Markdown (GitHub's pipe tables) and LaTeX
(a ``tabular`` with booktabs rules), from rows of dicts as ``wiloc compare --markdown`` and
``--latex`` print them. Numbers have 3 decimals (a threshold as many as :func:`wiloc.labels.threshold_text`
gives), a missing one is ``-``."""
from __future__ import annotations

import math
import re
from collections.abc import Sequence
from typing import Any


class Digits(str):
    """A number already written out (a threshold by :func:`wiloc.labels.threshold_text`): aligned as numbers are."""


def _text(value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else ""
    if isinstance(value, float):
        return "-" if not math.isfinite(value) else f"{value:.3f}"
    return "-" if value is None else str(value)


def _numeric(rows: Sequence[dict[str, Any]], column: str) -> bool:
    return any(isinstance(row.get(column), (int, float, Digits)) and not isinstance(row.get(column), bool)
               for row in rows)


def markdown(rows: Sequence[dict[str, Any]], columns: Sequence[str], labels: dict[str, str]) -> str:
    """A pipe table: one line per row, numbers right-aligned; ``|`` in text escaped."""
    def line(cells: Sequence[str]) -> str:
        return "| " + " | ".join(text.replace("|", "\\|") for text in cells) + " |"

    rules = ["---:" if _numeric(rows, c) else "---" for c in columns]
    return "\n".join([line([labels.get(c, c) for c in columns]), "|" + "|".join(rules) + "|",
                      *(line([_text(row.get(c)) for c in columns]) for row in rows)])


_LATEX_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
                  "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
                  # typeset as symbols: in LaTeX's default font encoding (OT1, IEEEtran's) > prints as
                  # an inverted question mark and | as a dash
                  ">=": r"$\geq$", "<=": r"$\leq$", "+-": r"$\pm$", ">": r"\textgreater{}",
                  "<": r"\textless{}", "|": r"\textbar{}"}
_LATEX_TOKEN = re.compile("|".join(re.escape(token) for token in sorted(_LATEX_SPECIAL, key=len, reverse=True)))


def _latex_text(text: str) -> str:
    return _LATEX_TOKEN.sub(lambda found: _LATEX_SPECIAL[found.group()], text)


def latex(rows: Sequence[dict[str, Any]], columns: Sequence[str], labels: dict[str, str], caption: str) -> str:
    """A ``table`` with a booktabs ``tabular`` (``\\usepackage{booktabs}``), its caption as given;
    LaTeX's special characters escaped."""
    spec = "".join("r" if _numeric(rows, c) else "l" for c in columns)
    body = [" & ".join(_latex_text(_text(row.get(c))) for c in columns) + r" \\" for row in rows]
    return "\n".join([r"\begin{table}", r"\centering", rf"\caption{{{_latex_text(caption)}}}",
                      rf"\begin{{tabular}}{{{spec}}}", r"\toprule",
                      " & ".join(_latex_text(labels.get(c, c)) for c in columns) + r" \\", r"\midrule",
                      *body, r"\bottomrule", r"\end{tabular}", r"\end{table}"])
