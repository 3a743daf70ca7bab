"""A study's pseudonymous tables as files (CSV, spreadsheet-safe, or Parquet through the optional pyarrow)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from analysis.errors import InputError, StoreError
from analysis.reports.formatting import spreadsheet_frame
from studyctl.outputs import Staged
from studyctl.session.traces import traces_frame
from studyctl.store import EXPORT_TABLES, Store
from studyctl.store.tables import table_rows


def export(db: str | Path, out_dir: str | Path, fmt: str = "csv", force: bool = False) -> Staged:
    """Every pseudonymous table, one file each, and every trial's per-tick trace (traces.csv or
    .parquet). The identities table is never exported. Everything is read (and every trace
    checked against its SHA-256) and converted before anything is written, the files are written
    to a temporary folder beside `out_dir` and moved in together (all or none); a file of the same
    name in `out_dir` is refused unless `force`. Returns the `Staged` folder (`.written`,
    `.replaced`)."""
    if fmt not in ("csv", "parquet"):
        raise InputError(f"--format: {fmt!r} is not csv or parquet")
    out_dir = Path(out_dir)
    tables = (*EXPORT_TABLES, "traces")
    # with force, an earlier export in either format goes whole; other files in the folder stay
    target = Staged(out_dir, force, folder=True, expect=[f"{t}.{fmt}" for t in tables], inputs={"--db": db},
                    own=[f"{t}.{f}" for t in tables for f in ("csv", "parquet")])
    if fmt == "parquet":
        _pyarrow()  # an optional extra: checked before anything is read or written
    with Store(db, mode="read") as store:
        # the columns from the schema, so an empty table still exports its header
        frames = {table: pd.DataFrame(table_rows(store, table), columns=list(store.db[table].columns_dict))
                  for table in EXPORT_TABLES}
        frames["traces"] = traces_frame(store)
    if fmt == "csv":  # text cells a spreadsheet would run as formulas are shown instead (docs/study.md)
        converted = {table: spreadsheet_frame(df).to_csv(index=False) for table, df in frames.items()}
    else:
        converted = {table: parquet_table(df) for table, df in frames.items()}
    with target as tmp:
        for table, data in converted.items():
            path = tmp / f"{table}.{fmt}"
            if fmt == "csv":
                path.write_text(data, encoding="utf-8")
            else:
                _pyarrow().parquet.write_table(data, path)
    return target


def parquet_table(df):
    """`df` as an Arrow table. A column holding text in some rows and numbers in others (the
    answers of a study that asks a text question) is written as text, a number as its digits
    (1 as "1"); the question's kind says how to read it (docs/study.md)."""
    df = df.copy()
    for col in [c for c in df.columns if df[c].dtype.kind == "O"]:
        kinds = {type(v) for v in df[col] if v is not None and v == v}
        if len(kinds) > 1 and not kinds <= {int, float}:
            df[col] = [None if v is None or v != v else str(v) for v in df[col]]
    return _pyarrow().Table.from_pandas(df, preserve_index=False)


def _pyarrow():
    """pyarrow with its parquet module (the parquet extra), or a StoreError saying how to install
    it: absent, or installed and failing to import (a missing shared library, a build for another
    NumPy), which raises ImportError or OSError from inside it."""
    try:
        import pyarrow.parquet  # optional: the parquet extra, only for --format parquet
    except ModuleNotFoundError as exc:
        if exc.name != "pyarrow":
            raise StoreError(_failed_import("pyarrow", exc)) from None
        raise StoreError("export --format parquet needs the parquet extra: pip install 'brainsim-study[parquet]'") from None
    except (ImportError, OSError) as exc:
        raise StoreError(_failed_import("pyarrow", exc)) from None
    return pyarrow


def _failed_import(name: str, exc: BaseException) -> str:
    reason = " ".join(str(exc).split())[:200] or type(exc).__name__  # one line, however long the loader's message
    return f"export --format parquet needs {name}, which failed to import: {reason}; pip install 'brainsim-study[parquet]'"
