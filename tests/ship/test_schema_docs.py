"""The survey plan's schema in docs/ is generated from its one declaration, and is current."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_docs_schema_is_generated_from_the_model():
    spec = importlib.util.spec_from_file_location("gen_schemas", ROOT / "tools" / "gen_schemas.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    for name, (model, fmt) in gen.SCHEMAS.items():
        assert (ROOT / "docs" / "schema" / name).read_text() == gen.render(model, fmt), f"run python tools/gen_schemas.py ({name})"
