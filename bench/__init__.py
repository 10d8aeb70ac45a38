"""Benchmarks (``make bench``). Each ``bench/bench_<name>.py`` has ``run(data: Path) -> str``
returning a Markdown section; ``python -m bench`` runs them and rewrites ``docs/BENCHMARKS.md``."""
