"""interfaces.records.AggregatingLog: repeated records cost a bounded number of lines, none is lost from the counts."""

import math

from hypothesis import given, settings, strategies as st

from interfaces.records import AggregatingLog


class ListLog:
    def __init__(self):
        self.lines = []

    def write(self, record):
        self.lines.append(dict(record))


events = st.lists(st.tuples(st.sampled_from(["a", "b", "c", "d"]), st.floats(0.0, 0.2)), max_size=400)


@settings(max_examples=200, deadline=None)
@given(events=events, verbatim=st.integers(0, 5), window=st.floats(0.05, 3.0))
def test_every_record_is_written_or_counted_and_lines_stay_bounded(events, verbatim, window):
    sink = ListLog()
    log = AggregatingLog(sink, verbatim=verbatim, window=window)
    now = 0.0
    for key, step in events:
        now += step
        log.write(key, {"kind": "reject", "key": key, "time": now}, now)
    log.flush()
    for key in "abcd":
        sent = sum(1 for k, _ in events if k == key)
        verbatim_lines = [line for line in sink.lines if line.get("kind") == "reject" and line["key"] == key]
        counted = sum(line["count"] for line in sink.lines if line.get("kind") == "suppressed" and line["key"] == key)
        assert len(verbatim_lines) == min(sent, verbatim)
        assert len(verbatim_lines) + counted == sent  # nothing lost
        # at most one count line per key per window, plus the last one flushed at the end
        count_lines = [line for line in sink.lines if line.get("kind") == "suppressed" and line["key"] == key]
        assert len(count_lines) <= math.floor(now / window) + 2
        for line in count_lines:
            assert line["first"] <= line["last"]


def test_a_flood_of_a_million_rejects_in_ten_seconds_writes_a_few_dozen_lines():
    sink = ListLog()
    log = AggregatingLog(sink, verbatim=20, window=1.0)
    for i in range(1_000_000):
        log.write("stale_seq", {"kind": "reject", "i": i}, i * 1e-5)
    log.close()
    assert 20 < len(sink.lines) <= 20 + 11
    assert log.suppressed["stale_seq"] == 1_000_000 - 20


def test_keys_beyond_the_limit_are_counted_as_other():
    sink = ListLog()
    log = AggregatingLog(sink, verbatim=1, window=1.0, max_keys=3)
    for i in range(100):
        log.write(f"k{i}", {"i": i}, 0.0)
    log.flush()
    assert set(log.written) == {"k0", "k1", "k2", "other"}
    assert len(sink.lines) == 5  # three first records, one 'other' verbatim, one count line for 'other'
    assert sink.lines[-1] == {"kind": "suppressed", "key": "other", "count": 96, "first": 0.0, "last": 0.0}
