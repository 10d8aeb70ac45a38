"""The surveyor's review page: ``inspect-pipe review RUN_DIR`` serves the run's register for
confirming, rejecting, reclassifying and commenting each entry with its crop and its place in the
mosaic, keyboard-driven. Every edit goes to ``report/audit.jsonl`` and the register files
(``inspect_pipe.report._review``); the report re-renders with the statuses. Same stack and login
as the base station (Starlette, uvicorn, ``inspect_pipe.webauth``); needs the ``base`` extra."""

from inspect_pipe.review_app.app import ReviewConfig, ReviewServer, open_review, render_config

__all__ = ["ReviewConfig", "ReviewServer", "open_review", "render_config"]
