"""An exported ONNX file's integrity seal: the file carries its own SHA-256 in
``metadata_props['thermonet_sha256']`` (:data:`DIGEST_KEY`), the digest of the file's bytes
with those 64 hex digits written as zeros (:data:`UNSEALED`).  :func:`seal_bytes` fills it in
once the file is written; :func:`seal_onnx` re-seals a file edited on purpose.  The runtime
(``export/thermonet_runtime.py``) recomputes it and refuses a file edited after export.
"""

from __future__ import annotations

from pathlib import Path

from ..core.errors import ExportError
from ..core.fileio import atomic_path

__all__ = ["DIGEST_KEY", "UNSEALED", "seal_bytes", "seal_onnx"]

#: Metadata key of the file's own SHA-256 (see the module docstring and :func:`seal_onnx`).
DIGEST_KEY = "thermonet_sha256"


UNSEALED = "0" * 64


def seal_bytes(path: Path) -> str:
    """Replace the zero placeholder of :data:`DIGEST_KEY` in the file at ``path`` by the
    SHA-256 of the file's bytes (taken with the placeholder in place); return the digest."""
    import hashlib

    data = path.read_bytes()
    marker = UNSEALED.encode("ascii")
    if data.count(marker) != 1:
        raise ExportError(f"{path}: cannot seal the ONNX file (its digest placeholder occurs "
                          f"{data.count(marker)} times)")
    digest = hashlib.sha256(data).hexdigest()
    path.write_bytes(data.replace(marker, digest.encode("ascii")))
    return digest


def seal_onnx(path: str | Path) -> str:
    """Store a fresh integrity digest in the exported ONNX file at ``path``; return it.

    For a file you trust that the runtime refuses for its digest (edited on purpose,
    or exported before thermonet sealed its files).  Written atomically.
    """
    import onnx

    path = Path(path)
    proto = onnx.load(str(path))
    props = [p for p in proto.metadata_props if p.key != DIGEST_KEY]
    del proto.metadata_props[:]
    proto.metadata_props.extend(props)
    entry = proto.metadata_props.add()
    entry.key, entry.value = DIGEST_KEY, UNSEALED
    with atomic_path(path) as tmp:
        onnx.save_model(proto, str(tmp), save_as_external_data=False)
        digest = seal_bytes(Path(tmp))
    return digest
