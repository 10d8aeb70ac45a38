"""Reading a user's YAML or JSON file (scenario, stack parameters, survey plan, camera file: ROS
camera_info or OpenCV FileStorage) into
plain Python values, every failure one :class:`~inspect_pipe.errors.InputError`.

PyYAML's ``safe_load`` with four changes a user's file needs:

- numbers as YAML 1.2 and JSON write them: ``3e0``, ``1e-3`` and ``1.0e3`` are floats (YAML 1.1, which
  PyYAML follows, reads them as text, so a valid JSON file was refused as "not a number");
- a key given twice in one mapping is refused (PyYAML keeps the last one silently);
- a document whose aliases expand beyond ``MAX_VALUES`` values is refused before anything walks it
  (a few hundred bytes of nested aliases expand to billions of values: a "billion laughs");
- nesting too deep for the parser, and integers too long for Python to convert, are a bad file,
  not a traceback.
"""

from __future__ import annotations

import re
from typing import Any

import yaml

from inspect_pipe.errors import InputError

#: Most values (scalars, lists and mappings, aliases counted at each use) a document may expand to.
MAX_VALUES = 1_000_000

_FLOAT_1_2 = re.compile(
    r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |[-+]?\.[0-9_]+(?:[eE][-+]?[0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""",
    re.X,
)


class Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 floats and no duplicate keys (subclass it to add a tag's
    constructor and pass it to :func:`load_yaml`)."""

    def construct_mapping(self, node, deep=False):  # noqa: D102 - PyYAML's hook
        if isinstance(node, yaml.MappingNode):
            # The mapping's own keys, before merge keys (``<<: *base``) copy others in: a key the
            # mapping gives once overrides the merged one, as YAML means it.
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=deep)
                try:
                    dup = key in seen
                except TypeError:  # an unhashable key: PyYAML's own error follows
                    continue
                if dup:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {str(key)[:40]!r} given twice in one mapping", key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


# The resolvers are class-level lists shared with SafeLoader: copy before changing ours.
Loader.yaml_implicit_resolvers = {k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}
Loader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_1_2, list("-+0123456789."))


def _count(doc: Any, limit: int) -> int:
    """Number of values ``doc`` expands to, stopping once it passes ``limit`` (shared
    sub-documents, which aliases make, are counted at each use, as a reader walks them)."""
    memo: dict[int, int] = {}

    def walk(v: Any) -> int:
        if isinstance(v, (list, dict)):
            k = id(v)
            if k in memo:
                return memo[k]
            items = v.values() if isinstance(v, dict) else v
            n = 1 + (len(v) if isinstance(v, dict) else 0)
            for x in items:
                n += walk(x)
                if n > limit:
                    break
            memo[k] = n
            return n
        return 1

    return walk(doc)


def load_yaml(text: str, where: str, hint: str = "", *, loader: type[Loader] = Loader) -> Any:
    """The document in ``text`` (YAML or JSON); ``where`` names the file in the error."""
    try:
        doc = yaml.load(text, Loader=loader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None) or getattr(err, "context_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or ""
        why = f": {problem}" if "given twice" in problem else ""
        raise InputError(where, f"not valid YAML{at}{why}", hint) from None
    except RecursionError:
        raise InputError(where, "not valid YAML: nested too deeply", hint) from None
    except ValueError as err:  # e.g. an integer of more digits than Python converts (4,300), a 30th of February
        why = "a number of thousands of digits" if "digits" in str(err) else str(err).strip().splitlines()[0][:80]
        raise InputError(where, f"not valid YAML: {why}", hint) from None
    try:
        n = _count(doc, MAX_VALUES)
    except RecursionError:
        raise InputError(where, "nested too deeply", hint) from None
    if n > MAX_VALUES:
        raise InputError(where, f"expands to more than {MAX_VALUES:,} values (YAML aliases)", hint)
    return doc
