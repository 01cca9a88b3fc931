"""The end of a benchmark's run: its JSON report written, its Markdown table printed."""
from __future__ import annotations

from pathlib import Path

from morphable.io.atomic import write_json

__all__ = ["write_report"]


def write_report(path, report: dict, table: str) -> Path:
    """Write ``report`` as JSON to ``path`` atomically (its folder made if missing), then print
    ``table`` and where the report went. Returns ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, report)
    print(table)
    print(f"\nwrote {path}")
    return path
