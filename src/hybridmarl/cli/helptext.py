"""Help text from docstrings: the options of every command are documented by the docstrings of
their config dataclasses, wrapped in the source at the project's line length. The help joins
each paragraph's lines, so the terminal, not the source file, decides where lines break.

tyro (1.0) joins a docstring's lines before it removes their indentation, and takes any line
that does not start with a letter as a new line: every continuation line of a docstring written
inside a class body is indented, so each one became a hard break and the help came out ragged at
every terminal width. :func:`use_paragraph_helptext` replaces that one step of tyro's.
"""

from __future__ import annotations

import inspect

#: A line starting with one of these begins a new line of help even inside a paragraph (lists).
#: A line starting with an option ("--run-dir ...") does not: docstrings wrap mid-sentence there.
_LINE_STARTS = ("- ", "* ")


def paragraph_helptext(docstring: str) -> str:
    """``docstring`` with its indentation removed and the lines of each paragraph joined by one
    space; blank lines still separate paragraphs, and a line starting a list item ("- ", "* ")
    still starts a new line."""
    paragraphs: list[str] = []
    for block in inspect.cleandoc(docstring).split("\n\n"):
        lines = [line.strip() for line in block.splitlines() if line.strip()]
        if not lines:
            continue
        joined = lines[0]
        for line in lines[1:]:
            joined += ("\n" if line.startswith(_LINE_STARTS) else " ") + line
        paragraphs.append(joined)
    return "\n\n".join(paragraphs)


def use_paragraph_helptext() -> None:
    """Make tyro build help text with :func:`paragraph_helptext` (idempotent). tyro calls the
    step it replaces through its module attribute; if a tyro release renames it, help keeps
    tyro's own formatting."""
    from tyro import _strings

    if callable(getattr(_strings, "remove_single_line_breaks", None)):
        _strings.remove_single_line_breaks = paragraph_helptext
