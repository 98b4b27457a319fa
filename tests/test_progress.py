"""The stderr progress bar (tqdm): per-item lines, aggregated advance(), silence when disabled."""
import io

from stablelego_jax.progress import Progress


def test_done_writes_one_line_per_item():
    s = io.StringIO()
    p = Progress(2, stream=s)
    p.start("a")
    p.done("a ok")
    p.done("b ok")
    p.close()
    lines = [ln.strip("\r") for ln in s.getvalue().replace("\r", "\n").splitlines() if ln.strip()]
    assert "[1/2] a ok" in lines and "[2/2] b ok" in lines
    assert lines[-1].startswith("done: 2/2")


def test_advance_counts_and_reports_rate():
    s = io.StringIO()
    p = Progress(100, stream=s, unit="layouts")
    for _ in range(10):
        p.advance(10)
    p.bar.refresh()
    out = s.getvalue()
    assert p.count == 100 and "100/100" in out and "layouts/s" in out
    # off a terminal the bar is redrawn at most every 10 s, not once per call
    assert out.count("/100") <= 3
    p.close()


def test_disabled_counts_silently():
    s = io.StringIO()
    p = Progress(5, stream=s, enabled=False)
    p.advance(5)
    p.close()
    assert p.count == 5 and s.getvalue() == ""
