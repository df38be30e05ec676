"""Settings records: frozen dataclasses whose fields carry units; one way to override them."""
from __future__ import annotations

import dataclasses


def settings_with(settings, params: dict[str, str | float]) -> object:
    """Settings with some fields replaced from ``name=value`` pairs (``--param`` on the CLI).

    Unknown names and values of the wrong type give a ValueError that lists the valid names.
    """
    fields = {f.name: f for f in dataclasses.fields(settings)}
    changes = {}
    for key, raw in params.items():
        if key not in fields:
            raise ValueError(f"unknown parameter {key!r} for {type(settings).__qualname__}; valid: {', '.join(fields)}")
        kind = type(getattr(settings, key))
        try:
            if kind is bool:
                changes[key] = raw if isinstance(raw, bool) else str(raw).lower() in ("1", "true", "yes", "on")
            else:
                changes[key] = kind(raw)
        except (TypeError, ValueError):
            raise ValueError(f"parameter {key}={raw!r} is not a valid {kind.__name__}") from None
    return dataclasses.replace(settings, **changes)
