"""Reading the text files of the real-data loaders (plain or gzip-compressed).

One home for what every loader in :mod:`slamlib.datasets` needs before it
parses a line: open the file, decompress it when it is a gzip archive, decode
it, and turn a truncated or corrupt archive or undecodable bytes into a
``ValueError`` that names the file; and, once the rows are parsed, the
file-level checks every log shares (:func:`fail_rows`, :func:`check_time_order`),
whose messages name the file and the line.
"""

from __future__ import annotations

import gzip
import zlib

import numpy as np


def open_text(path, *, encoding="ascii", compressed=None, corrupt="truncated or corrupt gzip file",
              undecodable="not a text file"):
    """The text of a plain or gzip-compressed file (universal newlines).

    Parameters
    ----------
    path : str or Path
        The file; it is named as given in every error message.
    encoding : str, optional
        The text encoding (``"ascii"`` for the data sets' logs).
    compressed : bool or None, optional
        Whether the file is a gzip archive; ``None`` decides by a ``.gz`` suffix.
    corrupt, undecodable : str, optional
        The loader's wording for a truncated or corrupt archive and for bytes
        that do not decode; the message is ``"{path}: {wording} (...)"``.

    Returns
    -------
    text : str
        The whole file, with ``\\r\\n`` and ``\\r`` read as ``\\n``.

    Raises
    ------
    ValueError
        For a truncated or corrupt gzip archive (or a ``.gz`` file that is not
        one), or a byte that is not valid in `encoding`; the message names the
        file and, for a decoding error, the byte's offset.
    """
    if compressed is None:
        compressed = str(path).endswith(".gz")
    opener = gzip.open if compressed else open
    try:
        with opener(path, "rt", encoding=encoding) as fh:
            return fh.read()
    except (EOFError, zlib.error, gzip.BadGzipFile) as exc:
        raise ValueError(f"{path}: {corrupt} ({type(exc).__name__}: {exc})") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: {undecodable} (byte {exc.start} is not {exc.encoding.upper()})") from None


def fail_rows(path, bad, lines, what):
    """Raise ``ValueError("{path}, line {n}: {what}")`` for the first row where `bad` holds.

    ``lines[k]`` is the file's line number of row ``k``.
    """
    bad = np.asarray(bad)
    if bad.any():
        raise ValueError(f"{path}, line {lines[int(np.argmax(bad))]}: {what}")


def check_time_order(path, times, lines, *, wording="time runs backwards", unit=""):
    """Time stamps in file order must not decrease (equal times are allowed).

    ``lines[k]`` is the file's line number of ``times[k]``; the message names
    the line where time first goes back, both times (with `unit`) and the line
    before, in the loader's `wording`.
    """
    back = np.flatnonzero(np.diff(times) < 0)
    if back.size:
        k = int(back[0]) + 1
        raise ValueError(f"{path}, line {lines[k]}: {wording} ({float(times[k])!r}{unit} after "
                         f"{float(times[k - 1])!r}{unit} on line {lines[k - 1]})")
