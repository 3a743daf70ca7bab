"""JSON-ready copies of results: numpy scalars as Python numbers, NaN and infinities as null
(JSON has neither), paths as strings, tuples as lists, keys as strings; read-only mappings
(a result's, analysis/statistics/result_records.py) as dicts."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path


def jsonable(obj):
    if hasattr(obj, "as_dict") and callable(obj.as_dict):  # a typed record says how it is written (analysis/statistics/result_records.py)
        obj = obj.as_dict()
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):  # numpy scalars
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
