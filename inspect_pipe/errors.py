"""Errors a user can act on. The CLI turns them into one line and exit code 2."""

from __future__ import annotations


class InputError(Exception):
    """Bad input: names the file or device, the problem and what to do.

    ``str(err)`` is the one-line message shown to the user.
    """

    def __init__(self, where: str, problem: str, hint: str = "") -> None:
        # a file's own text echoed in the message (a key, a value) must not break the one line
        self.where = _one_line(str(where))
        self.problem = _short(_one_line(str(problem)))
        self.hint = _short(_one_line(str(hint)))
        where, problem, hint = self.where, self.problem, self.hint
        msg = f"{self.where}: {problem}"
        if hint:
            msg += f" ({hint})"
        super().__init__(msg)


#: Longest problem or hint shown (a value echoed from a file can be megabytes long).
MAX_PART_CHARS = 400


def _short(text: str) -> str:
    return text if len(text) <= MAX_PART_CHARS else text[: MAX_PART_CHARS - 3] + "..."


def _one_line(text: str) -> str:
    """``text`` with newlines and other control characters written as escapes (\\n, \\x1b)."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)
