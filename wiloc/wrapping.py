"""Table text that wraps only between words: names break after a separator (``/``, ``-``, ``_``,
a space), never inside a word (nor a number), so ``catgraph/sad`` in a narrow column reads
``catgraph/`` then ``sad``, and ``day_right`` ``day_`` then ``right``.

Rich wraps cell text at spaces only and folds a longer word at any character; :class:`Words`
tells rich's table the narrowest width that keeps every word whole (its measure) and wraps at the
separators in the width the table gives it. A column narrower than a word (a console too narrow
for every word) folds that word onto more lines: no character is ever cut.
"""
from __future__ import annotations

import re
from collections.abc import Iterator

from rich.console import Console, ConsoleOptions
from rich.measure import Measurement
from rich.text import Text

#: A word and the separator after it: text breaks after a separator or before a space.
_PIECE = re.compile(r"[^/\-_ ]+[/\-_]*|[/\-_]+| +")


def pieces(line: str) -> list[str]:
    """``line`` cut where it may break: after each run of separators, around spaces."""
    return _PIECE.findall(line)


def wrap(text: str, width: int) -> list[str]:
    """``text``'s lines, each wrapped at its break points into lines of at most ``width``
    characters (a single word longer than that stays whole on its own line); spaces at a
    break are dropped."""
    lines: list[str] = []
    for line in text.split("\n"):
        current = ""
        for piece in pieces(line):
            if current and len(current) + len(piece.rstrip()) > width:
                lines.append(current.rstrip())
                current = "" if piece.isspace() else piece
            else:
                current += piece
        lines.append(current.rstrip())
    return lines


def widest_word(text: str) -> int:
    """The width below which ``text`` cannot wrap without breaking a word."""
    return max((len(piece.strip()) for line in text.split("\n") for piece in pieces(line)), default=0)


class Words:
    """A table cell or header of plain text that rich wraps at separators only (see the module);
    with ``whole_lines`` its lines never wrap (``P 1.000`` stays one line)."""

    def __init__(self, text: str, whole_lines: bool = False) -> None:
        self.text = text
        self.whole_lines = whole_lines

    def __str__(self) -> str:
        return self.text

    def __rich_measure__(self, console: Console, options: ConsoleOptions) -> Measurement:
        longest = max((len(line) for line in self.text.split("\n")), default=0)
        narrowest = longest if self.whole_lines else widest_word(self.text)
        return Measurement(narrowest, longest).clamp(max_width=options.max_width)

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> Iterator[Text]:
        width = max(options.max_width, 1)
        lines = self.text.split("\n") if self.whole_lines else wrap(self.text, width)
        for line in lines:  # justified as the column says; a line wider than the column folds
            for start in range(0, max(len(line), 1), width):
                yield Text(line[start:start + width], no_wrap=True, overflow="fold", end="\n")
