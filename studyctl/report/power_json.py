"""The JSON document of ``studyctl power --json``: settings, the power table, the target sizes, the files."""

from __future__ import annotations

from typing import Any


def _records(frame: Any) -> list[dict[str, Any]]:
    f = frame.astype(object).where(frame.notna(), None)
    return f.to_dict(orient="records")


def power_json(run: Any) -> dict[str, Any]:
    """A :class:`~studyctl.workflows.power.PowerRun` as plain JSON-ready data (NaN → null)."""
    return {
        "format": "studyctl-power/1",
        "sizes": list(run.table.sizes),
        "replicates": run.table.replicates,
        "ran": run.ran,
        "reused": run.reused,
        "seconds": run.seconds,
        "backend": run.backend,
        "sim_rate_hz": run.sim_rate_hz,
        "loop_rates_hz": run.loop_rates_hz,
        "target": None if run.target is None else run.target.target,
        "smallest_sizes": None if run.target is None else run.target.to_records(),
        "power": _records(run.table.to_frame()),
        "design": "exact" if run.pool is None else "two-stage",
        "pool": run.pool,
        "power_error": None if run.error is None else run.error.summary(),
        "power_error_rows": None if run.error is None else _records(run.error.to_frame()),
        "files": {k: str(v) for k, v in run.files.items()},
    }
