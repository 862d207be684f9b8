"""A fleet prior read back from its file (:func:`prior_from_dict`, the inverse of
:meth:`thermonet.scoring.prior.FleetPrior.to_dict`), checked whole: nothing read from a file
is trusted, and every error names the file and the key.

**Its digest** (:func:`prior_digest`): ``thermonet prior`` writes the SHA-256 of the file's
canonical content (``json.dumps(sort_keys=True)`` of every key but ``sha256`` itself) as
``sha256``; read back, a digest that does not match is refused (a prior edited by hand: a
widened range, another unit count, would be trusted by every unit calibrated from it), and a
prior without one (written before it was recorded) is read with a warning
(:func:`check_digest`).  A number is a JSON number: ``"0.11"`` is refused, naming its key."""

from __future__ import annotations

import hashlib
import json
import math
from typing import Any

import numpy as np

from ..core.errors import InputError
from .prior import MAX_CLUSTERS, MAX_DEGREE, MIN_UNITS, PRIOR_SCHEMA, AxisPrior, FleetPrior
from .prior_map import map_from_dict, numbers_only
from .prior_points import TEST_KINDS

__all__ = ["prior_from_dict", "prior_digest", "check_digest", "DIGEST_KEY"]

#: The key of a prior file's content digest.
DIGEST_KEY = "sha256"


def prior_digest(data: dict[str, Any]) -> str:
    """The SHA-256 of a prior's canonical content: every key but :data:`DIGEST_KEY`, as
    ``json.dumps(sort_keys=True)`` writes it."""
    body = {k: v for k, v in data.items() if k != DIGEST_KEY}
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode("utf-8")).hexdigest()


def check_digest(data: Any, source: str) -> str | None:
    """Refuse a prior whose content does not match its digest; a warning (one line) for one
    with no digest, None for one that matches."""
    if not isinstance(data, dict):
        return None          # prior_from_dict says what it is not
    got = data.get(DIGEST_KEY)
    if got is None:
        return (f"{source}: no sha256 of its content (a prior written before it was "
                "recorded): read unchecked; write it again with `thermonet prior` to seal it")
    if not isinstance(got, str) or got != prior_digest(data):
        raise InputError(f"{source}: its content does not match its sha256 (edited by hand?): "
                         "write it again with `thermonet prior`")
    return None


def _need(cond: bool, source: str, key: str, what: str) -> None:
    if not cond:
        raise InputError(f"{source}: key '{key}': {what}")


def _finite_array(v: Any, shape: tuple[int, ...], source: str, key: str) -> np.ndarray:
    if not numbers_only(v):
        raise InputError(f"{source}: key '{key}': not an array of numbers (a value is "
                         f"{_first_non_number(v)!r})")
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{source}: key '{key}': not an array of numbers") from None
    _need(a.shape == shape, source, key, f"expected shape {shape}, got {a.shape}")
    _need(bool(np.isfinite(a).all()), source, key, "holds a value that is not finite")
    return a


def _first_non_number(v: Any) -> Any:
    if isinstance(v, list):
        return next((_first_non_number(x) for x in v if not numbers_only(x)), v)
    return v


def _axis_from_dict(name: str, v: Any, degree: int, source: str) -> AxisPrior:
    key = f"axes.{name}"
    _need(isinstance(v, dict), source, key, "expected a mapping")
    w = np.asarray(v.get("weights", []), dtype=np.float64) if isinstance(
        v.get("weights"), list) else np.zeros(0)
    k = w.size
    _need(1 <= k <= MAX_CLUSTERS, source, f"{key}.weights",
          f"expected 1 to {MAX_CLUSTERS} cluster weights")
    w = _finite_array(v["weights"], (k,), source, f"{key}.weights")
    _need(bool((w > 0).all()) and abs(w.sum() - 1) < 1e-6, source, f"{key}.weights",
          "weights must be positive and sum to 1")
    means = _finite_array(v.get("means"), (k, degree), source, f"{key}.means")
    covs = _finite_array(v.get("covs"), (k, degree, degree), source, f"{key}.covs")
    for c in covs:
        _need(bool(np.allclose(c, c.T, rtol=1e-9, atol=0)), source, f"{key}.covs",
              "a covariance is not symmetric")
        _need(bool(np.linalg.eigvalsh(c).min() > 0), source, f"{key}.covs",
              "a covariance is not positive definite")
    out = []
    for sub in ("misfit_var", "sampling_var"):
        x = v.get(sub)
        _need(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
              and x >= 0, source, f"{key}.{sub}", f"expected a finite number ≥ 0, got {x!r}")
        out.append(float(x))
    return AxisPrior(name, w, means, covs, out[0], out[1])


def prior_from_dict(data: Any, source: str) -> FleetPrior:
    _need(isinstance(data, dict), source, "(top)", "expected a JSON object")
    _need(data.get("kind") == "fleet-prior", source, "kind",
          "this is not a thermonet fleet prior (kind must be 'fleet-prior')")
    _need(data.get("schema") == PRIOR_SCHEMA, source, "schema",
          f"schema {data.get('schema')!r} is not {PRIOR_SCHEMA}")
    deg = data.get("degree")
    _need(isinstance(deg, int) and not isinstance(deg, bool) and 1 <= deg <= MAX_DEGREE,
          source, "degree", f"expected 1 to {MAX_DEGREE}, got {deg!r}")
    nums = {}
    for key in ("t_ref_c", "scale_c", "bin_c"):
        x = data.get(key)
        _need(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x),
              source, key, f"expected a finite number, got {x!r}")
        nums[key] = float(x)
    _need(nums["scale_c"] > 0 and nums["bin_c"] > 0, source, "scale_c",
          "scale_c and bin_c must be positive")
    rng = _finite_array(data.get("range_c"), (2,), source, "range_c")
    _need(rng[1] > rng[0], source, "range_c", "the range's high end is not above its low end")
    axes_raw = data.get("axes")
    _need(isinstance(axes_raw, dict) and bool(axes_raw), source, "axes",
          "expected a mapping axis -> population")
    axes = [_axis_from_dict(str(n), v, deg, source) for n, v in axes_raw.items()]
    n = data.get("n_units")
    _need(isinstance(n, int) and not isinstance(n, bool) and n >= MIN_UNITS, source, "n_units",
          f"expected an integer ≥ {MIN_UNITS}, got {n!r}")
    for ap in axes:
        ap.n_units = n
    maps = {}
    for key in ("units_of_measure", "targets"):
        m = data.get(key)
        _need(isinstance(m, dict) and set(m) == set(axes_raw) and
              all(isinstance(x, str) for x in m.values()), source, key,
              "expected one string per axis of 'axes'")
        maps[key] = dict(m)
    ids = data.get("unit_ids")
    _need(isinstance(ids, list) and all(isinstance(u, str) for u in ids), source, "unit_ids",
          "expected a list of unit ids")
    _need(len(ids) == n, source, "n_units", f"{n}, and 'unit_ids' lists {len(ids)} units: "
          "a prior's unit count is the units it lists")
    exc = data.get("excluded", {})
    _need(isinstance(exc, dict), source, "excluded", "expected a mapping unit -> reason")
    kinds = data.get("test_kinds", {})
    bad = [f"{k!r}: {v!r}" for k, v in kinds.items() if k not in TEST_KINDS or not isinstance(
        v, int) or isinstance(v, bool) or v < 1] if isinstance(kinds, dict) else [repr(kinds)]
    _need(not bad, source, "test_kinds", f"{bad[0] if bad else ''} is not a test kind ("
          f"{', '.join(TEST_KINDS)}) with a count of units ≥ 1")
    test_map = None if data.get("short_test") is None else map_from_dict(
        data["short_test"], source, list(axes_raw), deg)
    return FleetPrior(axes, deg, nums["t_ref_c"], nums["scale_c"], (float(rng[0]),
                      float(rng[1])), maps["units_of_measure"], maps["targets"], n,
                      list(ids), {str(k): str(v) for k, v in exc.items()},
                      str(data.get("source", "")), nums["bin_c"], dict(kinds), test_map)
