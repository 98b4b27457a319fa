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


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_end_bars_ends_the_bar_line_before_a_message():
    """Ctrl-C's line must not be glued to a half-drawn bar: off a terminal
    the bar's last drawing gets its newline, on one the bar is cleared."""
    from stablelego_jax.progress import end_bars

    log, quiet = io.StringIO(), io.StringIO()
    bars = [Progress(10, stream=log), Progress(10, stream=quiet, enabled=False)]
    for b in bars:
        b.advance(3)
        b.bar.refresh()
    assert not log.getvalue().endswith("\n") and "3/10" in log.getvalue()
    end_bars()
    assert log.getvalue().endswith("\n") and log.getvalue().count("\n") == 1
    assert quiet.getvalue() == ""  # a disabled bar drew nothing and ends nothing
    end_bars()  # once only: nothing more is written
    assert log.getvalue().count("\n") == 1
    for b in bars:
        b.close()
    tty = _Tty()
    bar = Progress(10, stream=tty)
    bar.advance(3)
    bar.bar.refresh()
    assert "3/10" in tty.getvalue().split("\r")[-1]
    end_bars()
    assert tty.getvalue().split("\r")[-1].strip() == ""  # the bar's line is blank again
    bar.close()
