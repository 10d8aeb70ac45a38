"""Shared CLI plumbing: one-line errors with exit code 2."""

from __future__ import annotations

import functools
import sys
from typing import Callable, TypeVar

import typer

from inspect_pipe.errors import InputError

F = TypeVar("F", bound=Callable)


def fail(message: str, code: int = 2) -> "typer.Exit":
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code)


def one_line_errors(func: F) -> F:
    """Turn :class:`InputError` (and a few OS errors) into ``error: ...`` on stderr and exit 2."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except InputError as err:
            raise fail(str(err)) from None
        except FileNotFoundError as err:
            raise fail(f"{err.filename}: not found") from None
        except PermissionError as err:
            raise fail(f"{err.filename}: permission denied") from None
        except KeyboardInterrupt:
            typer.echo("interrupted; everything written so far is kept", err=True)
            sys.exit(130)

    return wrapper  # type: ignore[return-value]
