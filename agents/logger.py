"""Training logs: a compact table on stdout, a CSV file for plots, TensorBoard event files.

A resumed run continues its logs from the checkpoint's step: `Logger(..., resume_step=N)` drops
the CSV rows a killed run wrote after its last checkpoint and tells TensorBoard to hide that
run's events past N, so curves never zig-zag back in time. The CSV holds one row per step: a
second dump at the step of the last row (the final evaluation after training's last row) is
merged into that row.
"""
from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any

STEP_KEY = "time/total_timesteps"


class Logger:
    """Collects scalars with `record`, writes them all with `dump(step)`.

    Keys are "group/name" (rollout/ep_len_mean, train/kl ...). The CSV grows a column when a new
    key appears (the file is rewritten once with the wider header), so reward terms an env only
    reports later are not lost. Every rewrite of the CSV goes through a temporary file and a
    rename, so a kill mid-rewrite leaves the old file, not half of one.

    resume_step: the step count of the checkpoint a resumed run starts from; rows logged after
    it are dropped (`dropped_rows` counts them) and TensorBoard purges events past it.
    """

    def __init__(self, log_dir: str | os.PathLike | None = None, stdout: bool = True,
                 tensorboard: bool = True, csv_name: str = "progress.csv", resume_step: int | None = None):
        self.values: dict[str, float] = {}
        self.last: dict[str, float] = {}  # the latest dumped row
        self.stdout = stdout
        self.dir = Path(log_dir) if log_dir is not None else None
        self.dropped_rows = 0
        self._tb = None
        self._tb_dir = None
        self._fields: list[str] = []
        self._last_row: dict[str, Any] | None = None  # the CSV's last row, to merge a same-step dump into
        # SummaryWriter hides earlier events whose step is >= purge_step; the checkpoint's own step stays.
        self._purge_step = None if resume_step is None else int(resume_step) + 1
        if self.dir is not None:
            self.dir.mkdir(parents=True, exist_ok=True)
            self.csv_path = self.dir / csv_name
            if self.csv_path.exists():  # resuming: keep the earlier rows and columns
                self._continue_csv(resume_step)
            if tensorboard:
                # Made on the first dump, so a run that fails before logging anything leaves no
                # event file behind (its run directory stays empty and reusable).
                from torch.utils.tensorboard import SummaryWriter  # noqa: F401  (fail early if missing)

                self._tb_dir = self.dir / "tb"

    def _continue_csv(self, resume_step: int | None) -> None:
        fields, rows = _read_csv(self.csv_path)
        kept = rows
        if resume_step is not None:
            # Rows past the checkpoint come from a run killed before its next checkpoint; the
            # resumed run logs those steps again. A row without a readable step is a line cut
            # short by the kill.
            kept = [r for r in rows if _step(r) is not None and _step(r) <= resume_step]
        self.dropped_rows = len(rows) - len(kept)
        self._fields = fields
        # A kill mid-append can leave a last line without its newline; the next append would glue onto it.
        if kept is not rows or not _ends_with_newline(self.csv_path):
            _write_csv_atomic(self.csv_path, fields, kept)
        self._last_row = kept[-1] if kept else None

    def record(self, key: str, value: Any) -> None:
        self.values[key] = float(value)

    def dump(self, step: int) -> dict[str, float]:
        row = {STEP_KEY: float(step), **self.values}
        self.values, self.last = {}, row
        if self.stdout:
            print(format_row(row), flush=True)
        if self.dir is not None:
            self._write_csv(row)
        if self._tb_dir is not None:
            tb = self._writer()
            for k, v in row.items():
                if k != STEP_KEY and math.isfinite(v):
                    tb.add_scalar(k, v, step)
            tb.flush()
        return row

    def _writer(self):
        if self._tb is None:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(str(self._tb_dir), purge_step=self._purge_step)
        return self._tb

    def _write_csv(self, row: dict[str, float]) -> None:
        new = [k for k in row if k not in self._fields]
        self._fields += new
        if self._last_row is not None and _step(self._last_row) == row[STEP_KEY]:
            # One row per step: the values join the step's existing row (new values win).
            fields, rows = _read_csv(self.csv_path)
            rows[-1] = {**rows[-1], **row} if rows else row
            _write_csv_atomic(self.csv_path, self._fields, rows)
            self._last_row = rows[-1]
            return
        if new and self.csv_path.exists():
            _, rows = _read_csv(self.csv_path)
            _write_csv_atomic(self.csv_path, self._fields, rows)
        write_header = not self.csv_path.exists()
        with open(self.csv_path, "a", newline="") as f:
            w = csv.DictWriter(f, self._fields)
            if write_header:
                w.writeheader()
            w.writerow(row)
        self._last_row = row

    def close(self) -> None:
        if self._tb is not None:
            self._tb.close()
            self._tb = None


def _read_csv(path: Path) -> tuple[list[str], list[dict[str, Any]]]:
    """(header, rows); cells past the header (a damaged line) are left out."""
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        rows = [{k: v for k, v in r.items() if k is not None} for r in reader]
        return list(reader.fieldnames or []), rows


def _write_csv_atomic(path: Path, fields: list[str], rows: list[dict[str, Any]]) -> None:
    # One fixed temporary name: a leftover from a kill is simply overwritten by the next rewrite.
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fields)
        w.writeheader()
        w.writerows(rows)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _step(row: dict[str, Any]) -> float | None:
    try:
        return float(row.get(STEP_KEY))
    except (TypeError, ValueError):
        return None


def _ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as f:
        f.seek(0, os.SEEK_END)
        if f.tell() == 0:
            return True
        f.seek(-1, os.SEEK_END)
        return f.read(1) == b"\n"


def format_row(row: dict[str, float]) -> str:
    width = max(len(k) for k in row)
    lines = ["-" * (width + 16)]
    for k in sorted(row):
        v = row[k]
        s = f"{v:.0f}" if float(v).is_integer() and abs(v) >= 1 else f"{v:.4g}"
        lines.append(f"| {k:<{width}} | {s:>10} |")
    lines.append(lines[0])
    return "\n".join(lines)
