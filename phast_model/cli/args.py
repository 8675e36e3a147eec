"""Argument parsing the command lines share."""

from __future__ import annotations

import json
from typing import Any


def json_object(text: str, flag: str) -> dict[str, Any]:
    """``text`` parsed as a JSON object; ValueError naming ``flag`` when it is not valid JSON or not an object."""
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{flag} is not valid JSON ({exc.msg}): {text!r}") from None
    if not isinstance(obj, dict):
        raise ValueError(f"{flag} must be a JSON object, got {type(obj).__name__}: {text!r}")
    return obj
