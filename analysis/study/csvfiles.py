"""CSV files as people make them (spreadsheets, text editors), read strictly."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from analysis.errors import InputError
from sim.errors import InputFileError
from sim.files import DATA_MAX_BYTES, read_input
from sim.text import control_problem


def read_csv(path: str | Path, columns: tuple[str, ...], required: tuple[str, ...]) -> list[tuple[int, dict]]:
    """(line, row) pairs of a CSV as people save them: UTF-8 with or without a BOM, CRLF or LF,
    ',' ';' or tab separated, header names in any case and spacing. Unknown or missing columns
    and undecodable bytes, and control characters in a cell, are one-line errors naming the
    file, the line and the column."""
    path = Path(path)
    try:
        raw = read_input(path, DATA_MAX_BYTES)
    except InputFileError as exc:
        raise InputError(str(exc)) from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise InputError(f"{path}: line {line}: not UTF-8 text (byte 0x{raw[exc.start]:02x}); save it as UTF-8 CSV") from None
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise InputError(f"{path}: empty; the first line must name the columns ({', '.join(columns)})")
    head = lines[0]
    delimiter = max((";", ",", "\t"), key=head.count) if any(d in head for d in ";,\t") else ","
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=delimiter)
    header = [c.strip().lower() for c in next(reader)]
    unknown = [c for c in header if c not in columns]
    if unknown:
        raise InputError(f"{path}: unknown column {unknown[0]!r}; allowed: {', '.join(columns)}")
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(f"{path}: no {missing[0]!r} column; the columns are {', '.join(columns)} ({', '.join(required)} required)")
    if len(set(header)) != len(header):
        raise InputError(f"{path}: a column is named twice")
    rows = []
    for cells in reader:
        line = reader.line_num
        if not any(c.strip() for c in cells):
            continue  # blank lines, e.g. at the end of a spreadsheet's file
        if len(cells) > len(header) and any(c.strip() for c in cells[len(header):]):  # empty trailing cells are fine
            raise InputError(f"{path}: line {line}: {len(cells)} cells, the header has {len(header)}")
        row = {k: (cells[i].strip() if i < len(cells) else "") for i, k in enumerate(header)}
        for k, v in row.items():
            if (problem := control_problem(v)) is not None:  # lengths: checked by what reads the cell
                raise InputError(f"{path}: line {line}: {k}: {problem}")
        rows.append((line, row))
    return rows
