"""A written report's summary.json read back (``read_summary``) and the SHA-256 of a report file
(``file_sha256``, which summary.json records of pairs.csv): what ``PairResults.from_csv`` and the
commands that read reports check against."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any


def file_sha256(path: Path) -> str:
    """The SHA-256 of the file at ``path``, hex."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def read_summary(report_dir: str | Path) -> dict[str, Any]:
    """A report's summary.json, naming the file when it is truncated or not a summary."""
    path = Path(report_dir) / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except ValueError as error:
        raise ValueError(
            f"{path} is corrupt (truncated?): {error}; run test again to rewrite it"
        ) from None
    if not isinstance(summary, dict) or not isinstance(summary.get("rows"), list):
        raise ValueError(f"{path} is not a voe_report summary (no rows); run test again")
    return summary
