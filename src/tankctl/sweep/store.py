"""The sweep's results on disk: ``DIR/cases.parquet``, one row per case and variant.

The file is rewritten whole (to ``cases.parquet.tmp``, then renamed over the old one) after
every batch of completed cases, so it is always a complete Parquet file: a sweep killed at any
point leaves the rows of every batch written before, and the next run with the same output
skips them (``--fresh`` discards them). Rows are kept in case order, variants in the plan's
order, so the same sweep gives the same file however its cases were scheduled.

The file's schema metadata holds the sweep's fingerprint: a SHA-256 of the spec (as validated),
the scenario file and its site file. Resuming into an output of a different sweep is refused.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from tankctl.sweep.cases import Plan
from tankctl.sweep.spec import Parameter
from tanklab.config import ConfigError
from tanklab.scenario import load_scenario

__all__ = ["CASES_FILE", "FINGERPRINT_KEY", "ResultStore", "fingerprint", "schema"]

CASES_FILE = "cases.parquet"
FINGERPRINT_KEY = b"tanklab.sweep.fingerprint"


def fingerprint(plan: Plan) -> str:
    """SHA-256 (hex) of the validated spec, the scenario file and its site file."""
    _, site_path = load_scenario(plan.scenario_path)
    h = hashlib.sha256()
    h.update(json.dumps(plan.spec.model_dump(mode="json"), sort_keys=True).encode())
    for path in (plan.scenario_path, site_path):
        h.update(b"\0")
        h.update(Path(path).read_bytes())
    return h.hexdigest()


def _param_type(p: Parameter) -> pa.DataType:
    if not p.is_grid:
        return pa.float64()
    values = p.grid()
    if all(isinstance(v, bool) for v in values):
        return pa.bool_()
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        return pa.float64()
    return pa.string()


def schema(plan: Plan, fp: str) -> pa.Schema:
    """The results' columns: case, variant, parameters, seed, metrics, status, error, worker, wall_s."""
    fields = [pa.field("case", pa.int64()), pa.field("variant", pa.string())]
    fields += [pa.field(p.name, _param_type(p)) for p in plan.spec.parameters]
    fields.append(pa.field("seed", pa.int64()))
    fields += [pa.field(c, pa.float64()) for c in plan.metric_columns]
    fields += [
        pa.field("status", pa.string()),
        pa.field("error", pa.string()),
        pa.field("worker", pa.string()),
        pa.field("wall_s", pa.float64()),
    ]
    return pa.schema(fields, metadata={FINGERPRINT_KEY: fp.encode()})


def _cell(value: Any, kind: pa.DataType) -> Any:
    """A row value as its column's type (a string column holds every grid value as text)."""
    if value is None:
        return None
    if pa.types.is_string(kind):
        return str(value)
    return value


class ResultStore:
    """The rows of one sweep's output directory, loaded (resume) and written per batch."""

    def __init__(self, directory: Path, plan: Plan, fp: str, *, fresh: bool = False) -> None:
        self.directory = Path(directory)
        self.path = self.directory / CASES_FILE
        self.schema = schema(plan, fp)
        self._variant_order = {v: i for i, v in enumerate(plan.variants)}
        self.rows: dict[tuple[int, str], dict[str, Any]] = {}
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ConfigError(f"--output: cannot create {directory}: {e.strerror or e}") from e
        if fresh:
            self.path.unlink(missing_ok=True)
        elif self.path.exists():
            self._load(fp)

    def _load(self, fp: str) -> None:
        try:
            table = pq.read_table(self.path)
        except (OSError, pa.ArrowException) as e:
            raise ConfigError(f"{self.path}: not a readable results file ({e}); --fresh discards it") from e
        found = (table.schema.metadata or {}).get(FINGERPRINT_KEY, b"").decode()
        if found != fp or table.schema.names != self.schema.names:
            raise ConfigError(
                f"{self.path}: holds another sweep (a different spec, scenario or site); --fresh discards it"
            )
        for row in table.to_pylist():
            self.rows[(int(row["case"]), str(row["variant"]))] = row

    @property
    def done(self) -> set[tuple[int, str]]:
        """(case, variant) pairs already in the output."""
        return set(self.rows)

    def add(self, rows: Iterable[dict[str, Any]]) -> None:
        """Add completed rows and rewrite the file (atomically: a kill leaves the old or the new)."""
        for row in rows:
            self.rows[(int(row["case"]), str(row["variant"]))] = row
        self.write()

    def sorted_rows(self) -> list[dict[str, Any]]:
        """Every row, in case order then the plan's variant order."""
        keys = sorted(
            self.rows, key=lambda k: (k[0], self._variant_order.get(k[1], len(self._variant_order)))
        )
        return [self.rows[k] for k in keys]

    def write(self) -> None:
        """Write every row to ``cases.parquet`` (through a temporary file and a rename)."""
        rows = self.sorted_rows()
        columns = {
            f.name: pa.array([_cell(r.get(f.name), f.type) for r in rows], type=f.type) for f in self.schema
        }
        table = pa.Table.from_pydict(columns, schema=self.schema)
        tmp = self.path.with_name(self.path.name + ".tmp")
        pq.write_table(table, tmp)
        os.replace(tmp, self.path)
