"""The stderr progress bar: per-item lines and aggregated advance()."""
import io

from stablelego_jax.progress import Progress


def test_done_writes_one_line_per_item():
    s = io.StringIO()
    p = Progress(2, stream=s)
    p.start("a")
    p.done("a ok")
    p.done("b ok")
    p.close()
    lines = s.getvalue().splitlines()
    assert lines[0].endswith("1/2 a ok") and lines[1].endswith("2/2 b ok")
    assert lines[2].startswith("done: 2/2")


def test_advance_aggregates_and_reports_rate_at_the_end():
    s = io.StringIO()
    p = Progress(100, stream=s, unit="layouts")
    for _ in range(10):
        p.advance(10)
    lines = s.getvalue().splitlines()
    # off a terminal: the first update and the last, not one line per call
    assert len(lines) == 2
    assert "100/100" in lines[-1] and "layouts/s" in lines[-1]
    assert p.count == 100


def test_disabled_counts_silently():
    s = io.StringIO()
    p = Progress(5, stream=s, enabled=False)
    p.advance(5)
    p.close()
    assert p.count == 5 and s.getvalue() == ""
