"""The tail the benchmarks share: print the table, and record it with ``--record MACHINE``.

A benchmark adds the option with :func:`add_record_option` and ends with
:func:`report_table`, which prints the table (columns padded to their widest cell) and, when
a machine was named, records it as ``bench/results/<name>.json`` with
:func:`bench.validation_page.write_result` (``python bench/validation_page.py`` then
puts it on docs/validation.md).
"""

from __future__ import annotations

import argparse
import datetime
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def add_record_option(parser: argparse.ArgumentParser, name: str) -> None:
    """``--record MACHINE``: write ``bench/results/<name>.json``, naming the machine."""
    parser.add_argument("--record", metavar="MACHINE", default=None,
                        help=f"write bench/results/{name}.json, naming the machine "
                             "(e.g. '2-core shared VM (CPU)')")


def print_table(columns: list[str], rows: list[list[str]]) -> None:
    """Print ``columns`` and ``rows`` with each column padded to its widest cell."""
    width = [max(len(str(row[i])) for row in [columns, *rows]) for i in range(len(columns))]
    for row in [columns, *rows]:
        print("  ".join(str(c).ljust(w) for c, w in zip(row, width, strict=True)).rstrip())


def report_table(name: str, columns: list[str], rows: list[list[str]], *, record: str | None,
           title: str, section: str, order: int, command: str, notes: str = "") -> None:
    """Print the table; with ``record`` (the machine), record it as
    ``bench/results/<name>.json`` (today's date)."""
    print_table(columns, rows)
    if record:
        sys.path.insert(0, str(ROOT))
        from bench.validation_page import write_result

        write_result(name, title=title, section=section, order=order, command=command,
                     date=datetime.date.today().isoformat(), machine=record, columns=columns,
                     rows=rows, notes=notes)
