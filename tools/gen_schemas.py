"""Write the JSON Schema of every format declared with pydantic into docs/schema/ (the docs are
generated from the one declaration; tests/ship/test_schema_docs.py checks they are current).

    python tools/gen_schemas.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from inspect_pipe.flight.scenario import FORMAT as SCENARIO_FORMAT  # noqa: E402
from inspect_pipe.flight.scenario import ScenarioDoc  # noqa: E402
from inspect_pipe.formats import FORMATS  # noqa: E402
from inspect_pipe.ship import FORMAT, SurveyPlan  # noqa: E402

SCHEMAS = {"survey_plan.schema.json": (SurveyPlan, FORMAT), "scenario.schema.json": (ScenarioDoc, SCENARIO_FORMAT), **FORMATS}


def render(model, fmt: str) -> str:
    doc = model.model_json_schema(by_alias=True)
    doc = {"$schema": "https://json-schema.org/draft/2020-12/schema", "$id": fmt, **doc}
    return json.dumps(doc, indent=1, sort_keys=False) + "\n"


def main() -> None:
    out = ROOT / "docs" / "schema"
    out.mkdir(parents=True, exist_ok=True)
    for name, (model, fmt) in SCHEMAS.items():
        (out / name).write_text(render(model, fmt))
        print(out / name)


if __name__ == "__main__":
    main()
