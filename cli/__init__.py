"""The ``inspect-pipe`` command line (typer). Commands are thin: parse, call one step, report."""
