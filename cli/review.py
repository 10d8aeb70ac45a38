"""``inspect-pipe review RUN_DIR``: the surveyor's review of the register in the browser."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from cli._common import one_line_errors, web_server_token

HELP = (
    "Serve the run's defect register for review in the browser: confirm, reject, reclassify "
    "(corrosion/crack) or comment each entry, with its crop and its place in the mosaic, from the "
    "keyboard (j/k next/previous, c confirm, r reject, s suggested, t toggle class, n note, p re-render).\n\n"
    "Every change is appended to RUN_DIR/report/audit.jsonl (reviewer, UTC time, entry, field, before, "
    "after; flushed to disk before the page is told it is saved) and written to defects.json/defects.csv "
    "atomically; report.html (and report.pdf) re-render 10 s after the last change (--render-after), on p and when the "
    "server stops. A later `inspect-pipe run` keeps the decisions.\n\n"
    "Binds 127.0.0.1 unless --host is given; on any other address a token is printed, typed into the page "
    "once and exchanged for a session cookie (as the base station).\n\n"
    "Examples:\n\n"
    "  inspect-pipe review out/run1 --reviewer 'J. Smith'     # http://127.0.0.1:8766/\n\n"
    "  inspect-pipe review out/run1 --host 0.0.0.0 --certfile cert.pem --keyfile key.pem"
)


@one_line_errors
def review(
    run_dir: Annotated[Path, typer.Argument(help="Run directory (inspect-pipe run) with report/defects.json.")],
    reviewer: Annotated[Optional[str], typer.Option("--reviewer", help="Name in the audit log (default: the survey plan's surveyor).")] = None,
    port: Annotated[int, typer.Option("--port", min=1, max=65535, help="TCP port")] = 8766,
    host: Annotated[str, typer.Option("--host", help="address to bind; not loopback: a token is required")] = "127.0.0.1",
    token: Annotated[Optional[str], typer.Option("--token", help="token to require (default: a new random one off loopback)")] = None,
    render_after: Annotated[float, typer.Option("--render-after", min=0.0, help="re-render the report this many seconds after the last change")] = 10.0,
    certfile: Annotated[Optional[Path], typer.Option("--certfile", help="PEM certificate (chain): serve HTTPS")] = None,
    keyfile: Annotated[Optional[Path], typer.Option("--keyfile", help="PEM private key of --certfile")] = None,
) -> None:
    """Review the register in the browser."""
    from inspect_pipe.flight.base_station import check_listen, is_loopback_host, serve
    from inspect_pipe.review_app import ReviewConfig, ReviewServer, open_review

    token = web_server_token(host, token, certfile, keyfile)
    check_listen(host, port)  # before the banner and the token are printed
    rv, store, cfg = open_review(run_dir, reviewer)
    server = ReviewServer(rv, store, cfg, ReviewConfig(host=host, port=port, token=token, tls=certfile is not None, render_after_s=render_after))
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    typer.echo(f"review of {rv.json_path} ({len(rv.defects)} entries) by {rv.reviewer}: {'https' if certfile else 'http'}://{shown}:{port}/")
    if token:
        typer.echo(f"token: {token}  (type it into the page once; requests without a session are refused)")
    if not is_loopback_host(host) and certfile is None:
        typer.echo("warning: plain HTTP off loopback: the token and the session cookie cross the network readable; "
                   "give --certfile/--keyfile", err=True)
    typer.echo(f"changes logged to {rv.audit_path}; Ctrl-C to stop (the report re-renders on the way out)")
    serve(server, host=host, port=port, certfile=certfile, keyfile=keyfile)
