"""Strict YAML for config and mapping files: a repeated key is an error, not a silent override."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

__all__ = ["load_yaml", "DuplicateKeyError"]


class DuplicateKeyError(ValueError):
    """A mapping in the YAML file names the same key twice (``line`` is 1-based)."""

    def __init__(self, key: str, line: int) -> None:
        super().__init__(f"key '{key}' given twice (line {line})")
        self.key, self.line = key, line


class _StrictLoader(yaml.SafeLoader):
    pass


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
    """Parse ``path`` with YAML's safe loader, refusing duplicate keys.

    Raises
    ------
    yaml.YAMLError
        Not valid YAML.
    DuplicateKeyError
        A key repeated in one mapping.
    """
    return yaml.load(Path(path).read_text(encoding="utf-8"), Loader=_StrictLoader)  # noqa: S506
