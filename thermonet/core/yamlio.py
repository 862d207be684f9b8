"""Strict YAML for every YAML file thermonet reads (configs, column mappings).

One loader, YAML's safe loader, with two refusals made at parse time:

* a repeated key in one mapping is an error, not a silent override;
* anchors and aliases (``&a`` / ``*a``) are refused.  A config or a mapping
  never needs them, and 630 bytes of chained aliases (a "billion laughs"
  bomb) expand to gigabytes: the composer stops at the first anchor, before
  anything is expanded.

Both raise a :class:`YamlRefusal` (a ``ValueError``) whose message names the
1-based line; callers add the file name.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

__all__ = ["load_yaml", "YamlRefusal", "DuplicateKeyError", "AliasError"]


class YamlRefusal(ValueError):
    """A YAML construct thermonet refuses (``line`` is 1-based)."""

    def __init__(self, message: str, line: int) -> None:
        super().__init__(f"{message} (line {line})")
        self.line = line


class DuplicateKeyError(YamlRefusal):
    """A mapping in the YAML file names the same key twice."""

    def __init__(self, key: str, line: int) -> None:
        super().__init__(f"key '{key}' given twice", line)
        self.key = key


class AliasError(YamlRefusal):
    """An anchor or alias: refused so that no file can expand into a bomb."""


class _StrictLoader(yaml.SafeLoader):
    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None) is not None:
            kind = "alias" if isinstance(event, yaml.AliasEvent) else "anchor"
            sign = "*" if kind == "alias" else "&"
            raise AliasError(f"YAML {kind} '{sign}{event.anchor}' refused (thermonet reads no "
                             "anchors or aliases; write the value out)",
                             event.start_mark.line + 1)
        return super().compose_node(parent, index)


def _mapping(loader: _StrictLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise DuplicateKeyError(str(key), key_node.start_mark.line + 1)
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)


def load_yaml(path: str | Path) -> Any:
    """Parse ``path`` with YAML's safe loader, refusing duplicate keys, anchors and aliases.

    Raises
    ------
    yaml.YAMLError
        Not valid YAML.
    YamlRefusal
        A key repeated in one mapping (:class:`DuplicateKeyError`), an anchor
        or alias (:class:`AliasError`), or a file that is not UTF-8 text.
    """
    data = Path(path).read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        line = data[:err.start].count(b"\n") + 1
        raise YamlRefusal(f"not UTF-8 text (byte {err.start})", line) from None
    return yaml.load(text, Loader=_StrictLoader)  # noqa: S506
