"""Help text of the command lines (train.py, eval.py): defaults shown on every option, the method grammar.

:class:`HelpFormatter` appends ``(default: X)`` to every option whose default is a value (not None, not
a ``store_true`` flag's False) and whose help does not state it already, and keeps descriptions and
epilogs as written. :func:`method_grammar` is the method-spec table of :mod:`agents.methods` for
``eval.py --help``, with the list of the registered filter methods. :func:`undocumented_options` lists the options of a parser (and its subcommands)
without a help line (the test asks for none).
"""
from __future__ import annotations

import argparse
import re


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Raw description / epilog; every option's help ends with its default (when it has a value)."""

    def _get_help_string(self, action):
        text = action.help or ""
        d = action.default
        if (d is None or d is False or d is argparse.SUPPRESS or not action.option_strings
                or "%(default)" in text or "default" in text.lower()):
            return text
        if isinstance(d, (list, tuple)):
            d = " ".join(map(str, d))
        return f"{text} (default: {str(d).replace('%', '%%')})"


def _plain(text: str) -> str:
    """reST inline markup to plain text: ``x`` and :role:`x` -> x."""
    return re.sub(r":\w+:`([^`]*)`", r"\1", text).replace("``", "")


def method_grammar() -> str:
    """The method-spec table and its notes from :mod:`agents.methods`' docstring as plain text (an epilog):
    the reST table re-aligned without its markup."""
    import agents.methods as methods
    text = (methods.__doc__ or "").strip()
    body = text.split("\n\n", 1)[1] if "\n\n" in text else text
    lines = body.splitlines()
    rules = [i for i, ln in enumerate(lines) if ln.startswith("===")]
    if len(rules) < 3:
        return "method specs (--methods, comma-separated):\n\n" + _plain(body)
    rows = []
    for ln in lines[rules[1] + 1:rules[2]]:
        m = re.match(r"^((?:``[^`]*``(?:, )?)+)\s+(.*)$", ln)  # a row: ``spec``[, ``spec``] meaning
        rows.append((_plain(m.group(1)), _plain(m.group(2))) if m else ("", _plain(ln.strip())))
    w2 = max(len(a) for a, _ in rows) + 2
    table = [f"  {a:<{w2}}{b}" for a, b in rows]
    rest = _plain("\n".join(lines[rules[2] + 1:])).strip()
    return ("method specs (--methods, comma-separated):\n\n" + "\n".join(table) + "\n\n" + filter_methods()
            + "\n\n" + rest)


def filter_methods(width: int = 100) -> str:
    """The registered filter methods (:data:`nav_filters.registry.FORMS`), wrapped to ``width`` columns."""
    import textwrap

    from nav_filters.registry import FORMS
    return textwrap.fill("Filter methods: " + ", ".join(sorted(FORMS)) + ".", width=width)


def undocumented_options(parser: argparse.ArgumentParser, prefix: str = "") -> list[str]:
    """``'<subcommand> --option'`` for every option of ``parser`` and its subparsers without help text."""
    out = []
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sub in a.choices.items():
                out += undocumented_options(sub, f"{prefix}{name} ")
        elif isinstance(a, argparse._HelpAction):
            continue
        elif not (a.help or "").strip():
            out.append(prefix + (a.option_strings[0] if a.option_strings else a.dest))
    return out
