"""Errors a user can act on. The CLI turns them into one line and exit code 2."""

from __future__ import annotations


class InputError(Exception):
    """Bad input: names the file or device, the problem and what to do.

    ``str(err)`` is the one-line message shown to the user.
    """

    def __init__(self, where: str, problem: str, hint: str = "") -> None:
        self.where = str(where)
        self.problem = problem
        self.hint = hint
        msg = f"{self.where}: {problem}"
        if hint:
            msg += f" ({hint})"
        super().__init__(msg)
