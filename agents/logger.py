"""Training logs: a compact table on stdout, a CSV file for plots, TensorBoard event files."""
from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any


class Logger:
    """Collects scalars with `record`, writes them all with `dump(step)`.

    Keys are "group/name" (rollout/ep_len_mean, train/kl ...). The CSV grows a column when a new
    key appears (the file is rewritten once with the wider header), so reward terms an env only
    reports later are not lost.
    """

    def __init__(self, log_dir: str | os.PathLike | None = None, stdout: bool = True,
                 tensorboard: bool = True, csv_name: str = "progress.csv"):
        self.values: dict[str, float] = {}
        self.last: dict[str, float] = {}  # the latest dumped row
        self.stdout = stdout
        self.dir = Path(log_dir) if log_dir is not None else None
        self._tb = None
        self._fields: list[str] = []
        if self.dir is not None:
            self.dir.mkdir(parents=True, exist_ok=True)
            self.csv_path = self.dir / csv_name
            if self.csv_path.exists():  # resuming: keep the earlier rows and columns
                with open(self.csv_path, newline="") as f:
                    self._fields = next(csv.reader(f), [])
            if tensorboard:
                from torch.utils.tensorboard import SummaryWriter

                self._tb = SummaryWriter(str(self.dir / "tb"))

    def record(self, key: str, value: Any) -> None:
        self.values[key] = float(value)

    def dump(self, step: int) -> dict[str, float]:
        row = {"time/total_timesteps": float(step), **self.values}
        self.values, self.last = {}, row
        if self.stdout:
            print(format_row(row), flush=True)
        if self.dir is not None:
            self._write_csv(row)
        if self._tb is not None:
            for k, v in row.items():
                if k != "time/total_timesteps" and math.isfinite(v):
                    self._tb.add_scalar(k, v, step)
            self._tb.flush()
        return row

    def _write_csv(self, row: dict[str, float]) -> None:
        new = [k for k in row if k not in self._fields]
        if new:
            old_rows = []
            if self.csv_path.exists():
                with open(self.csv_path, newline="") as f:
                    old_rows = list(csv.DictReader(f))
            self._fields += new
            with open(self.csv_path, "w", newline="") as f:
                w = csv.DictWriter(f, self._fields)
                w.writeheader()
                w.writerows(old_rows)
        with open(self.csv_path, "a", newline="") as f:
            csv.DictWriter(f, self._fields).writerow(row)

    def close(self) -> None:
        if self._tb is not None:
            self._tb.close()
            self._tb = None


def format_row(row: dict[str, float]) -> str:
    width = max(len(k) for k in row)
    lines = ["-" * (width + 16)]
    for k in sorted(row):
        v = row[k]
        s = f"{v:.0f}" if float(v).is_integer() and abs(v) >= 1 else f"{v:.4g}"
        lines.append(f"| {k:<{width}} | {s:>10} |")
    lines.append(lines[0])
    return "\n".join(lines)
