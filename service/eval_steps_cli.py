"""``firetrack eval steps``: detected against true step counts (registered on the eval app)."""
from __future__ import annotations

from service.eval_cli import app  # noqa: F401  (commands are added below)
