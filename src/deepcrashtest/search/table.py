"""The search's results table: a dict of NumPy column arrays, and its CSV text (NumPy only, light to import:
the forked output helper writes results.csv without loading the simulator)."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.fileio import atomic_write_text

#: A table of results: column name -> (N,) array, in column order. A plain dict of NumPy arrays (pandas took
#: ~0.7 s of CPU to import for it, a third of a 2,000-variant search); functions that read a table take any
#: mapping of columns (a pandas DataFrame too).
Table = dict[str, np.ndarray]


def column(table: Mapping[str, Any], name: str) -> np.ndarray:
    """Column ``name`` of a table (a dict of arrays or a pandas DataFrame) as a NumPy array."""
    return np.asarray(table[name])


def select(table: Mapping[str, Any], rows: np.ndarray) -> Table:
    """The rows ``rows`` (a boolean mask or indices) of every column."""
    return {k: column(table, k)[rows] for k in table}


def write_csv(table: Mapping[str, Any], path: Path, force: bool) -> Path:
    return atomic_write_text(path, csv_text(table), force=force)


def csv_text(table: Mapping[str, Any], float_format: str = "%.6g") -> str:
    """pandas' ``to_csv(index=False, float_format=float_format)`` of the table, the same text, ~20x faster.

    Columns are formatted whole (floats with ``float_format``, NaN empty; booleans ``True``/``False``;
    integers as numbers); a table with other columns, or text that would need quoting, goes to pandas.
    """
    cols: list[list[Any]] = []
    fmts: list[str] = []  # each column's conversion in the row format
    names = [str(c) for c in table]
    one_spec = _ONE_FLOAT_SPEC.fullmatch(float_format) is not None
    for name in table:
        v = column(table, name)
        kind = v.dtype.kind
        if kind == "f":
            values = v.tolist()
            if one_spec and not np.isnan(v).any():  # formatted by the row format below, as ``float_format % x``
                cols.append(values)
                fmts.append(float_format)
            else:
                cols.append(["" if x != x else float_format % x for x in values])
                fmts.append("%s")
        elif kind in "biu":
            cols.append(v.tolist())  # Python bools and ints: "%s" writes str(x)
            fmts.append("%s")
        elif kind in "OU" and all(type(x) is str and not _NEEDS_QUOTES.intersection(x) for x in v.tolist()):
            cols.append(v.tolist())
            fmts.append("%s")
        else:
            return _pandas_csv(table, float_format)
    if any(_NEEDS_QUOTES.intersection(c) for c in names):
        return _pandas_csv(table, float_format)
    row = ",".join(fmts)  # one formatting call per row instead of one per cell (~4x less CPU)
    lines = [",".join(names), *(row % values for values in zip(*cols, strict=True))] if cols else [",".join(names)]
    return "\n".join(lines) + "\n"


def _pandas_csv(table: Mapping[str, Any], float_format: str) -> str:
    import pandas as pd

    return pd.DataFrame({k: column(table, k) for k in table}).to_csv(index=False, float_format=float_format)


_NEEDS_QUOTES = frozenset(',"\n\r')
#: A ``float_format`` of one conversion that writes no comma (``%.6g``, ``%.3f``, ...): usable inside a row format.
_ONE_FLOAT_SPEC = re.compile(r"%[-+ #0]*\d*(\.\d+)?[eEfFgG]")
