"""Text from the inputs (a robot's ``name``, CSV column names) made safe to show.

A robot description or a recordings header is data, not markup: a name may hold an escape
sequence that recolours or clears the terminal, a line break that forges a line of the
output (``"x\\n**Verdict:** ..."``), HTML, Markdown or a matplotlib ``$math$`` span. The
functions here escape such characters where the text is *shown*; the JSON outputs keep the
text as it is (JSON escapes it by itself).
"""

import unicodedata

_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}
_MARKDOWN = frozenset("\\`*_[]<>|&#~$")  # the characters that start Markdown, HTML or an entity


def _unprintable(ch: str) -> bool:
    """Control (C0, DEL, C1), format (bidirectional overrides, zero-width) and separator
    characters other than the plain space."""
    return ch != " " and unicodedata.category(ch) in ("Cc", "Cf", "Zl", "Zp", "Zs")


def terminal(text) -> str:
    """``text`` for one line of the terminal: every control, format or line-separator
    character written as an escape (``\\n``, ``\\x1b``, ``\\u202e``); everything else as is.

    **Arguments:** ``text``: any object (``str()`` of it is shown).

    **Returns:** a string without line breaks or terminal control sequences.
    """
    out = []
    for ch in str(text):
        if ch in _NAMED:
            out.append(_NAMED[ch])
        elif _unprintable(ch):
            code = ord(ch)
            out.append(f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}")
        else:
            out.append(ch)
    return "".join(out)


def markdown(text) -> str:
    """``text`` inside a line of a Markdown report (a heading, a paragraph, a table cell):
    :func:`terminal`, then every character that Markdown, HTML or a table reads as markup
    (:data:`_MARKDOWN`: backslash, backtick, ``* _ [ ] < > | & # ~ $``) escaped with a
    backslash, so the text renders literally and cannot open a tag, a link or a new cell.

    **Returns:** a string without line breaks that renders as ``text``.
    """
    return "".join("\\" + ch if ch in _MARKDOWN else ch for ch in terminal(text))


def markdown_code(text) -> str:
    """``text`` as a Markdown code span (rendered literally, in a fixed-width font; no HTML,
    emphasis or link inside): :func:`terminal`, fenced by one backtick more than its longest
    run of backticks, with ``|`` escaped so that it cannot end a table cell (GitHub's tables
    read ``\\|`` inside a code span as ``|``).

    **Returns:** the code span, without line breaks.
    """
    t = terminal(text).replace("|", "\\|")
    run = longest = 0
    for ch in t:
        run = run + 1 if ch == "`" else 0
        longest = max(longest, run)
    fence = "`" * (longest + 1)
    pad = " " if t.startswith("`") or t.endswith("`") else ""
    return f"{fence}{pad}{t}{pad}{fence}"


def figure(text) -> str:
    """``text`` for a matplotlib title or label: :func:`terminal`, with ``$`` escaped (matplotlib
    reads ``$...$`` as mathtext; a malformed span would stop the figure)."""
    return terminal(text).replace("$", r"\$")
