"""Numeric text tables as recorders write them: CSV with a header row, or headerless and
whitespace- (or comma-, semicolon-, tab-) separated columns of numbers.

A column is named by its header or by its number (0 = first). Every problem is one
:class:`~vbfe.common.errors.EstimateError` line naming the file and what to do.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vbfe.common.errors import EstimateError

DELIMITERS = ",;\t"


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _read_text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise EstimateError(f"cannot read {path}: {exc.strerror}") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = ""
    if not text.strip() or "\x00" in text:
        raise EstimateError(
            f"{path} is not a text table of numbers (empty or binary); give "
            "a CSV or whitespace-separated text file"
        )
    return text


def _split(text: str) -> list[list[str]]:
    """Rows of fields: split on the first line's delimiter, else on whitespace."""
    lines = [line for line in text.splitlines() if line.strip()]
    delimiter = next((d for d in DELIMITERS if d in lines[0]), None)
    if delimiter is None:
        return [line.split() for line in lines]
    return [
        [field.strip() for field in row]
        for row in csv.reader(io.StringIO("\n".join(lines)), delimiter=delimiter)
    ]


def read_table(path: str | Path, columns: Sequence[str]) -> dict[str, np.ndarray]:
    """The ``columns`` (header names, or numbers for any table) as float arrays.

    The first row is a header unless all its fields are numbers. Empty fields and ``nan`` read
    as NaN; any other text where a number belongs is refused with its row and column.
    """
    path = Path(path)
    rows = _split(_read_text(path))
    has_header = not all(_is_number(field) for field in rows[0])
    header = rows[0] if has_header else []
    body = rows[1:] if has_header else rows
    index = {}
    for column in columns:
        if column in header:
            index[column] = header.index(column)
        elif column.isdigit():
            index[column] = int(column)
        elif has_header:
            raise EstimateError(
                f"{path} has no column {column!r}; its columns are {header} "
                "(or give column numbers, 0 = first)"
            )
        else:
            raise EstimateError(
                f"{path} has no header row; name its columns by number (0 = first), not {column!r}"
            )
    if not body:
        raise EstimateError(f"{path} holds no rows of numbers")
    width = min(len(row) for row in body)
    wanted = max(index.values())
    if wanted >= width:
        short = next(i for i, row in enumerate(body) if len(row) <= wanted)
        raise EstimateError(
            f"{path}: row {short + has_header + 1} has {len(body[short])} "
            f"column(s); column {wanted} (0 = first) is asked for"
        )
    out = {}
    for column, k in index.items():
        values = np.empty(len(body))
        for i, row in enumerate(body):
            text = row[k]
            try:
                values[i] = float(text) if text else np.nan
            except ValueError:
                raise EstimateError(
                    f"{path}: row {i + has_header + 1}, column {column!r} holds "
                    f"{text[:20]!r}, not a number"
                ) from None
        out[column] = values
    return out
