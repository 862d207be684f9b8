"""thermonet's Parquet format (:mod:`thermonet.data.io` documents the layout): its version
and metadata key, the ``thermonet`` metadata blob parsed and checked field by field
(:func:`parse_blob`: the one check of a thermonet file's metadata, for the whole-file reader
and the streamed one, :mod:`thermonet.data.chunks`, alike), the per-column data digest
(:class:`Digest`, :func:`stored_digest`) and the page checksums written and verified
(:data:`WRITE_OPTIONS`, :data:`READ_OPTIONS`).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError
from ..core.names import AXIS, SIGNAL, TEXT_ID, UNIT, check_finite, check_name
from .tables import GROUPS

__all__ = ["FORMAT_VERSION", "METADATA_KEY", "DIGEST_KEY", "Digest", "stored_digest",
           "WRITE_OPTIONS", "READ_OPTIONS", "parse_blob", "str_dict", "MAX_SAMPLE_RATE_HZ"]

#: Version of the Parquet layout written by :func:`write_parquet`.
FORMAT_VERSION = 1


#: Schema-metadata key of the JSON blob.
METADATA_KEY = "thermonet"


#: Parquet key-value metadata key of the data digest: the SHA-256 of each float column's
#: values (little-endian float64, nulls as NaN) in file order, added when the file is closed.
#: A file rewritten by another tool loses it (it is not part of the schema) and is then
#: read unchecked; a damaged one is refused.
DIGEST_KEY = "thermonet.digest"


class Digest:
    """SHA-256 of float columns, fed in file order a piece at a time."""

    def __init__(self) -> None:
        self.sha: dict[str, Any] = {}

    def add(self, name: str, values: Any) -> None:
        if not isinstance(values, np.ndarray):
            values = values.to_numpy(zero_copy_only=False)
        v = np.ascontiguousarray(values, dtype="<f8")
        if name not in self.sha:
            self.sha[name] = hashlib.sha256()
        self.sha[name].update(v.tobytes())

    def text(self) -> str:
        return json.dumps({"sha256": {k: h.hexdigest() for k, h in self.sha.items()}})

    def check(self, path: Path, stored: dict[str, str] | None) -> None:
        """Every column fed here that the file's digest lists has the digest written."""
        if not stored:
            return
        for name, h in self.sha.items():
            if name in stored and h.hexdigest() != stored[name]:
                raise InputError.at(path, "data digest mismatch: the values read are not "
                                    "those thermonet wrote (the file is damaged)", column=name)


def stored_digest(path: Path, metadata: Any) -> dict[str, str] | None:
    """The per-column digests a Parquet file's key-value ``metadata`` holds, or None."""
    raw = (metadata or {}).get(DIGEST_KEY.encode())
    if raw is None:
        return None
    try:
        info = json.loads(raw)
        sha = info["sha256"]
        if not isinstance(sha, dict) or not all(
                isinstance(k, str) and isinstance(v, str) for k, v in sha.items()):
            raise ValueError("not a mapping of column names to hex digests")
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as err:
        raise InputError.at(path, f"corrupt '{DIGEST_KEY}' metadata ({err})") from None
    return sha


#: How thermonet writes Parquet: every data page with a CRC-32 checksum, which the readers
#: verify (:data:`READ_OPTIONS`), so a damaged byte is refused, not read as another number.
WRITE_OPTIONS: dict[str, Any] = {"write_page_checksum": True}
#: How thermonet reads Parquet: page checksums verified where the writer stored them.
READ_OPTIONS: dict[str, Any] = {"page_checksum_verification": True}


def parse_blob(path: Path, blob: bytes) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The ``thermonet`` metadata blob, checked field by field, and its format version
    against this reader's: the one check of a thermonet file's metadata, for the whole-file
    reader and the streamed one alike."""
    try:
        info = json.loads(blob)
    except (ValueError, UnicodeDecodeError) as err:
        raise InputError.at(path, f"corrupt '{METADATA_KEY}' metadata (not JSON: {err})") from None
    entries = _check_blob(path, info)
    version = info["version"]
    if version > FORMAT_VERSION:
        raise InputError.at(path, f"format version {version} is newer than this thermonet "
                            f"reads ({FORMAT_VERSION}); upgrade thermonet")
    if version < 1:
        raise InputError.at(path, f"corrupt '{METADATA_KEY}' metadata: field 'version': "
                            f"{version} is not a format version (1 … {FORMAT_VERSION})")
    return info, entries


def str_dict(d: dict, what: str) -> dict[str, str]:
    for k, v in d.items():
        if not isinstance(k, str) or not isinstance(v, str):
            raise InputError(f"{what}: key {k!r} has value {v!r}; only strings can be stored")
    return dict(d)


#: Highest sample rate accepted from a file's metadata (Hz); absurd values are corrupt files.
MAX_SAMPLE_RATE_HZ = 1e6


def _check_blob(path: Path, info: Any) -> list[dict[str, Any]]:
    """Every field of the ``thermonet`` metadata blob, by type and rule; return the run entries.

    A Parquet file is input: each value is checked before use and a bad one
    is named (``runs[0].units``), never a traceback.
    """
    def bad(key: str, why: str) -> InputError:
        return InputError.at(path, f"corrupt '{METADATA_KEY}' metadata: field '{key}': {why}")

    if not isinstance(info, dict):
        raise bad("<top>", f"expected a mapping, got {type(info).__name__}")
    for key in ("version", "runs"):
        if key not in info:
            raise bad(key, "missing")
    if isinstance(info["version"], bool) or not isinstance(info["version"], int):
        raise bad("version", f"{info['version']!r} is not an integer")
    if not isinstance(info["runs"], list) or not info["runs"]:
        raise bad("runs", "expected a non-empty list of runs")
    if not isinstance(info.get("meta", {}), dict):
        raise bad("meta", "expected a mapping")
    need = ("run_id", "device_id", "sensor_kind", "sample_rate_hz", "meta", "units",
            "temperature") + GROUPS
    for i, e in enumerate(info["runs"]):
        at = f"runs[{i}]"
        if not isinstance(e, dict):
            raise bad(at, "expected a mapping")
        for key in need:
            if key not in e:
                raise bad(f"{at}.{key}", "missing")
        for key in ("run_id", "device_id"):
            check_name(e[key], TEXT_ID, f"{path}: '{METADATA_KEY}' metadata field '{at}.{key}'")
        if e["sensor_kind"] is not None and not isinstance(e["sensor_kind"], str):
            raise bad(f"{at}.sensor_kind", f"{e['sensor_kind']!r} is not a string")
        if e["sample_rate_hz"] is not None:
            check_finite(e["sample_rate_hz"], f"{path}: '{METADATA_KEY}' metadata field "
                         f"'{at}.sample_rate_hz' (Hz, > 0)", low=1e-9, high=MAX_SAMPLE_RATE_HZ)
        if not isinstance(e["temperature"], bool):
            raise bad(f"{at}.temperature", f"{e['temperature']!r} is not true or false")
        if not isinstance(e["meta"], dict):
            raise bad(f"{at}.meta", "expected a mapping")
        for group in GROUPS:
            names = e[group]
            if not isinstance(names, list):
                raise bad(f"{at}.{group}", f"expected a list of channel names, got {names!r}")
            for name in names:
                check_name(name, AXIS if group == "outputs" else SIGNAL,
                           f"{path}: '{METADATA_KEY}' metadata field '{at}.{group}'")
        units = e["units"]
        if not isinstance(units, dict):
            raise bad(f"{at}.units", f"expected a mapping channel -> unit, got {units!r}")
        for name, unit in units.items():
            check_name(name, SIGNAL, f"{path}: '{METADATA_KEY}' metadata field '{at}.units'")
            check_name(unit, UNIT, f"{path}: '{METADATA_KEY}' metadata field '{at}.units.{name}'")
    return list(info["runs"])
