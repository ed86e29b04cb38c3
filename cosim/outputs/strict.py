"""Strict JSON for the files other tools read (summary.json, a study's report.json).

Python's `json` writes NaN and Infinity, which are not JSON (RFC 8259 has no such numbers) and
which strict parsers (jq, JavaScript's JSON.parse, Go) refuse; and a numpy bool given to
`default=str` becomes the string "True". Here a number that is not finite becomes null (a
missing number), numpy scalars and arrays become Python numbers, booleans and lists, and the
dump refuses anything left that is not JSON (allow_nan=False).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np


def strict(o: Any) -> Any:
    """`o` with JSON's types only: non-finite floats -> None, numpy -> Python, tuples ->
    lists, paths -> strings."""
    if isinstance(o, bool | np.bool_):
        return bool(o)
    if isinstance(o, int | np.integer):
        return int(o)
    if isinstance(o, float | np.floating):
        return float(o) if math.isfinite(o) else None
    if isinstance(o, dict):
        return {str(k): strict(v) for k, v in o.items()}
    if isinstance(o, list | tuple | np.ndarray):
        return [strict(v) for v in o]
    if o is None or isinstance(o, str):
        return o
    if isinstance(o, Path):
        return str(o)
    return str(o)


def dumps(o: Any, **kw: Any) -> str:
    return json.dumps(strict(o), allow_nan=False, **kw)
