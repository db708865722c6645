"""interfaces.records: run-folder tables and logs, read back with the standard library's own readers."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from interfaces.records import CsvLog, JsonLinesLog, fmt, write_json

CELLS = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\r\x00"), max_size=12)


@settings(max_examples=50)
@given(st.lists(st.fixed_dictionaries({}, optional={"a": CELLS, "b": CELLS, "c": CELLS}), max_size=5))
def test_csv_rows_read_back_with_csv_dictreader_while_the_file_is_still_open(tmp_path_factory, rows):
    path = tmp_path_factory.mktemp("csv") / "table.csv"
    log = CsvLog(path, ("a", "b", "c"))
    for row in rows:
        log.write(row)
    # Nothing waits in a buffer: a reader sees every row before close (an interrupted run keeps them).
    with path.open(newline="") as handle:
        read = list(csv.DictReader(handle))
    log.close()
    assert read == [{column: row.get(column, "") for column in ("a", "b", "c")} for row in rows]
    assert path.read_text().splitlines()[0] == "a,b,c"


def test_fmt_leaves_missing_figures_empty():
    assert fmt(1.23456789, ".6g") == "1.23457" and fmt(np.float32(0.5), ".3f") == "0.500"
    assert fmt(math.nan, ".6g") == "" and fmt(None, ".6g") == ""
    assert fmt(math.inf, ".6g") == "inf"


def test_json_lines_and_json_files_take_numpy_values(tmp_path):
    log = JsonLinesLog(tmp_path / "events.jsonl")
    log.write({"time": np.float64(1.5), "seq": np.int64(3), "position": np.array([1.0, 2.0, 3.0])})
    assert json.loads((tmp_path / "events.jsonl").read_text()) == {"time": 1.5, "seq": 3, "position": [1.0, 2.0, 3.0]}
    log.close()
    write_json(tmp_path / "summary.json", {"b": np.arange(2), "a": 1}, sort_keys=True)
    assert json.loads((tmp_path / "summary.json").read_text()) == {"a": 1, "b": [0, 1]}
    assert not (tmp_path / "summary.json.tmp").exists()


def test_a_record_offered_after_close_is_counted_and_the_file_is_left_as_closed(tmp_path):
    """A subscriber callback that fires after the run closed its logs must not raise into the caller's
    thread (it would print a traceback from the transport's thread) nor reopen the file."""
    table = CsvLog(tmp_path / "t.csv", ("time",))
    table.write({"time": 1})
    table.close()
    table.write({"time": 2})
    events = JsonLinesLog(tmp_path / "e.jsonl")
    events.write({"n": 1})
    events.close()
    events.write({"n": 2})
    events.write({"n": 3})
    assert (table.late_rows, events.late_records) == (1, 2)
    assert list(csv.DictReader((tmp_path / "t.csv").open())) == [{"time": "1"}]
    assert [json.loads(line) for line in (tmp_path / "e.jsonl").read_text().splitlines()] == [{"n": 1}]
