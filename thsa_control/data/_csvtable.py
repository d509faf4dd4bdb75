"""One-pass, chunked, vectorised reading of a numeric CSV table (for ``rigdata``).

The file is streamed through :mod:`csv` in chunks of about ``CHUNK_CELLS``
cells; each chunk is converted to float64 by numpy in one call, and only a
column that holds empty or non-numeric cells in that chunk is parsed cell by
cell (vectorised over the column).  Time and memory grow linearly with rows x
columns: the result holds one float64 per cell, the positions of empty and
non-numeric cells, the text of the first few bad cells (for messages), and the
full text of a column only when it turns out not to be numeric (a second pass
over the file for those columns alone).

It imports numpy and the standard library only.
"""

from __future__ import annotations

import csv
import itertools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Table", "TableError", "read_table", "column_texts", "parse_cells", "CHUNK_CELLS", "TEXT_KEPT"]

#: Cells converted per numpy call (bounds the transient memory of a chunk).
CHUNK_CELLS = 1 << 20
#: Texts of bad cells kept per column and kind (messages list at most 10 rows).
TEXT_KEPT = 12


class TableError(Exception):
    """The file cannot be read as CSV at all (message only; rigdata adds file and row)."""

    def __init__(self, message: str, row: int | None = None):
        self.row = row
        super().__init__(message)


@dataclass
class Table:
    """A CSV table read column-wise.

    ``values[:, j]`` is column ``j`` as float64 (NaN where empty, not a number
    or in a ragged row); ``empty[j]`` / ``invalid[j]`` are sorted 0-based row
    indices; ``texts[j]`` maps a row index to the stripped text of a bad or
    non-finite cell (the first ``TEXT_KEPT`` of each kind); ``ragged`` lists
    rows whose field count differs from the header's, with their counts.
    """

    path: Path
    header: list[str]
    values: np.ndarray
    empty: list[np.ndarray]
    invalid: list[np.ndarray]
    texts: list[dict[int, str]]
    ragged: dict[int, int] = field(default_factory=dict)
    n_ragged: int = 0
    ragged_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    @property
    def n_rows(self) -> int:
        return self.values.shape[0]


def parse_cells(cells) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Strings -> (values, stripped strings, empty mask, not-a-number mask)."""
    text = np.char.strip(np.asarray(cells, dtype=str))
    empty = text == ""
    invalid = np.zeros(text.shape, dtype=bool)
    values = np.full(text.shape, np.nan)
    filled = ~empty
    try:
        values[filled] = text[filled].astype(np.float64)
    except ValueError:
        for i in np.flatnonzero(filled):
            try:
                values[i] = float(text[i])
            except ValueError:
                invalid[i] = True
    invalid |= filled & (np.char.find(text, "_") >= 0)  # float() accepts 1_000; we do not
    values[invalid] = np.nan
    return values, text, empty, invalid


#: Bytes of text read per chunk.
CHUNK_BYTES = 8 << 20


def _blank(line: str) -> bool:
    return line in ("\n", "\r\n", "\r", "")


def _line_chunks(f):
    """Chunks of complete CSV records (quotes balanced) as lists of lines; trailing blank lines dropped."""
    pending: list[str] = []
    while True:
        lines = f.readlines(CHUNK_BYTES)
        if not lines:
            return  # blank lines still pending are the file's trailing blank lines
        text_quotes = "".join(lines).count('"')
        while text_quotes % 2:  # inside a quoted field: read on to the end of the record
            more = f.readline()
            if not more:
                break
            lines.append(more)
            text_quotes += more.count('"')
        lines = pending + lines
        k = len(lines)
        while k and _blank(lines[k - 1]):
            k -= 1
        pending = lines[k:]
        if k:
            yield lines[:k]


def _parse_rows(lines: list[str]) -> list[list[str]]:
    return list(csv.reader(lines))


def _header(f) -> list[str] | None:
    line = f.readline()
    if not line:
        return None
    while line.count('"') % 2:
        more = f.readline()
        if not more:
            break
        line += more
    if _blank(line):
        # a blank first line: the header is empty unless the file holds nothing else
        pos = f.tell()
        rest = f.read(1 << 16)
        if not rest.strip("\r\n"):
            return None
        f.seek(pos)
        return []
    row = next(csv.reader([line]), [])
    return [c.strip() for c in row]


def read_table(path: Path) -> Table | None:
    """Read ``path``; None for an empty file.  Raises OSError, UnicodeDecodeError, TableError.

    The full text of a non-numeric column is read by a second pass, :func:`column_texts`.
    """
    with open(path, encoding="utf-8-sig", newline="") as f:
        try:
            header = _header(f)
        except csv.Error as exc:
            raise TableError(f"not a readable CSV file: {exc}", 0) from None
        if header is None:
            return None
        width = len(header)
        blocks: list[np.ndarray] = []
        empty: list[list[np.ndarray]] = [[] for _ in range(width)]
        invalid: list[list[np.ndarray]] = [[] for _ in range(width)]
        texts: list[dict[int, str]] = [{} for _ in range(width)]
        ragged: dict[int, int] = {}
        ragged_rows: list[np.ndarray] = []
        n_ragged = 0
        start = 0
        for lines in _line_chunks(f):
            block = _fast(lines, width, start, texts)
            if block is None:
                try:
                    chunk = _parse_rows(lines)
                except csv.Error as exc:
                    raise TableError(f"not a readable CSV file: {exc}", start + 1) from None
                n = len(chunk)
                widths = np.fromiter(map(len, chunk), dtype=np.int64, count=n)
                bad_width = np.flatnonzero(widths != width)
                if bad_width.size:
                    n_ragged += bad_width.size
                    ragged_rows.append(bad_width + start)
                    for i in bad_width[:TEXT_KEPT]:
                        if len(ragged) < TEXT_KEPT:
                            ragged[int(i) + start] = int(widths[i])
                    chunk = [r if len(r) == width else (r + [""] * width)[:width] for r in chunk]
                block = _convert(chunk, n, width, start, empty, invalid, texts)
                if bad_width.size:
                    block[bad_width, :] = np.nan
            blocks.append(block)
            start += block.shape[0]
    values = np.concatenate(blocks, axis=0) if blocks else np.zeros((0, width))
    rr = np.concatenate(ragged_rows) if ragged_rows else np.zeros(0, dtype=int)

    def cat(parts):
        return np.concatenate(parts) if parts else np.zeros(0, dtype=int)

    emp = [cat(p) for p in empty]
    inv = [cat(p) for p in invalid]
    if rr.size:  # a ragged row is reported once, not per cell
        emp = [np.setdiff1d(e, rr, assume_unique=True) for e in emp]
        inv = [np.setdiff1d(v, rr, assume_unique=True) for v in inv]
    return Table(Path(path), header, values, emp, inv, texts, ragged, n_ragged, rr)


def _fast(lines: list[str], width: int, start: int, texts) -> np.ndarray | None:
    """numpy's C parser on a chunk without quotes, underscores or blank lines; None when it does not apply."""
    if width == 0:
        return None
    text = "".join(lines)
    if '"' in text or "_" in text:
        return None
    try:
        block = np.loadtxt(lines, delimiter=",", dtype=np.float64, comments=None, ndmin=2)
    except ValueError:
        return None
    if block.shape != (len(lines), width):  # loadtxt skips blank lines; those are ragged rows here
        return None
    bad = ~np.isfinite(block)
    if bad.any():
        for i, j in zip(*np.nonzero(bad)):
            if len(texts[j]) < 2 * TEXT_KEPT:
                texts[j][int(i) + start] = lines[i].rstrip("\r\n").split(",")[j].strip()
    return block


def _convert(chunk, n, width, start, empty, invalid, texts) -> np.ndarray:
    """One chunk of rows -> float block; records bad cells per column."""
    flat = "".join(itertools.chain.from_iterable(chunk))
    if "_" not in flat:
        try:
            block = np.array(chunk, dtype=np.float64).reshape(n, width)
        except ValueError:
            block = None
        if block is not None:
            bad = ~np.isfinite(block)
            if bad.any():
                for i, j in zip(*np.nonzero(bad)):
                    if len(texts[j]) < 2 * TEXT_KEPT:
                        texts[j][int(i) + start] = chunk[i][j].strip()
            return block
    block = np.empty((n, width))
    for j, col in enumerate(zip(*chunk)):
        try:
            if "_" in "".join(col):
                raise ValueError
            block[:, j] = np.array(col, dtype=np.float64)
        except ValueError:
            values, text, emp, inv = parse_cells(col)
            block[:, j] = values
            if emp.any():
                empty[j].append(np.flatnonzero(emp) + start)
            if inv.any():
                invalid[j].append(np.flatnonzero(inv) + start)
            for i in np.flatnonzero(inv | (~emp & ~np.isfinite(values))):
                if len(texts[j]) >= 2 * TEXT_KEPT:
                    break
                texts[j][int(i) + start] = str(text[i])
            continue
        bad = ~np.isfinite(block[:, j])
        for i in np.flatnonzero(bad)[: 2 * TEXT_KEPT - len(texts[j])]:
            texts[j][int(i) + start] = col[i].strip()
    return block


def column_texts(path: Path, columns: list[int]) -> dict[int, np.ndarray]:
    """Second pass: the full stripped text of the given columns (non-numeric extra columns)."""
    out: dict[int, list[np.ndarray]] = {j: [] for j in columns}
    with open(path, encoding="utf-8-sig", newline="") as f:
        _header(f)
        for lines in _line_chunks(f):
            chunk = _parse_rows(lines)
            for j in columns:
                out[j].append(np.char.strip(np.asarray([r[j] if j < len(r) else "" for r in chunk], dtype=str)))
    return {j: (np.concatenate(v) if v else np.zeros(0, dtype=str)) for j, v in out.items()}
