"""The results table of a study: one CSV, a row per run, appended and flushed as runs finish.

The file is the study's memory: a re-run of the same command reads it and skips the run ids it
holds (ok and failed rows alike; `--retry-failed` re-runs failed ones), except a run cut by a
signal that an older cosim kept as a row (exit reason 'interrupted'): it is flown again. Each
row is written with one `write` + flush + fsync, so an interruption loses at most the row being
written; a torn last line is dropped when the table is opened again. When a run reports a metric
no earlier row had, the header grows: the file is rewritten to a temporary file and moved into
place. At the end `finish()` sorts the rows by run id (the last row of a run id wins) and orders
the metric columns by name, so the file is the same bytes whatever the executor and the
finishing order.

Values: floats as `repr` (round-trips bit for bit), booleans True/False, None as empty; text
keeps to one line (line breaks become ' / ').
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path
from typing import Any

from cosim.studies import deps
from cosim.studies.jobs import HEAD, TAIL


def fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(float(v))        # a numpy float's repr is 'np.float64(...)' (numpy 2)
    return " / ".join(str(v).splitlines())       # one physical line per row


class ResultsTable:
    def __init__(self, path: Path, param_keys: list[str]) -> None:
        self.path = Path(path)
        # a swept `seed` is the seed column
        self.fixed = [*HEAD, *(k for k in param_keys if k not in (*HEAD, *TAIL)), *TAIL]
        self.columns = list(self.fixed)
        self.rows: list[dict[str, str]] = []
        if self.path.is_file():
            self._load()

    # ------------------------------------------------------------------ reading
    def _load(self) -> None:
        try:
            text = self.path.read_text()
        except UnicodeDecodeError as exc:
            raise ValueError(f"{self.path}: not UTF-8 text ({exc.reason})") from None
        complete = text if text.endswith("\n") else text[: text.rfind("\n") + 1]
        reader = csv.reader(io.StringIO(complete))
        header = next(reader, None)
        if header is None:
            return
        if header[: len(self.fixed)] != self.fixed:
            raise ValueError(f"{self.path} has the columns {header[:len(self.fixed)]}, "
                             f"this study has {self.fixed}")
        self.columns = header
        try:       # rows of another length or without a run number are junk: not this study's
            self.rows = [dict(zip(header, r, strict=True)) for r in reader
                         if len(r) == len(header) and _run_number(r[0])]
        except csv.Error as exc:         # e.g. a field longer than the csv module reads
            raise ValueError(f"{self.path}: not a results table ({exc})") from None
        if complete != text:  # a torn last row: rewrite without it
            self._rewrite()

    def finished(self, *, retry_failed: bool = False) -> set[int]:
        """Run ids with a row (without the failed ones if `retry_failed`), not counting a run
        cut by a signal (no result: flown again)."""
        cut = deps.cut_exit()
        last = {int(r["run_id"]): r for r in self.rows}
        return {i for i, r in last.items() if r.get("exit_reason") != cut
                and not (retry_failed and r["status"] == "failed")}

    # ------------------------------------------------------------------ writing
    def append(self, row: dict[str, Any]) -> None:
        srow = {k: fmt(v) for k, v in row.items()}
        new = [k for k in srow if k not in self.columns]
        self.rows.append(srow)
        if new or not self.path.is_file():
            self.columns += sorted(new)
            self._rewrite()
            return
        with open(self.path, "a", newline="") as f:
            f.write(_line([srow.get(c, "") for c in self.columns]))
            f.flush()
            os.fsync(f.fileno())

    def finish(self) -> list[dict[str, str]]:
        """Sort by run id (last row per id wins), metric columns by name; rewrite."""
        last = {int(r["run_id"]): r for r in self.rows}
        self.rows = [last[i] for i in sorted(last)]
        self.columns = self.fixed + sorted(c for c in self.columns if c not in self.fixed)
        self.rows = [{c: r.get(c, "") for c in self.columns} for r in self.rows]
        self._rewrite()
        return self.rows

    def _rewrite(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            with open(tmp, "w", newline="") as f:
                f.write(_line(self.columns))
                for r in self.rows:
                    f.write(_line([r.get(c, "") for c in self.columns]))
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except OSError:                 # disk full: the table on disk stays as it was
            tmp.unlink(missing_ok=True)
            raise


def _run_number(text: str) -> bool:
    return text.isascii() and text.isdigit()


def _line(values: list[str]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(values)
    return buf.getvalue()
