"""Progress bars (roger_experiments.progress): plain lines off a terminal, a rich live bar
on one, nested bars sharing the display, the final line given by the owner."""
from __future__ import annotations

import io

from roger_experiments.progress import ProgressBar, counters_info


class FakeTerminal(io.StringIO):
    """A stream that says it is a terminal (rich then draws a live bar)."""

    def isatty(self) -> bool:
        return True


def test_plain_lines_every_tenth_and_the_final_line_is_the_owners():
    out = io.StringIO()
    bar = ProgressBar(200, "run w, qlearning", enabled=True, stream=out)
    assert not bar.live
    for done in range(201):
        bar.update(done, f"shifts {done // 3}")
    bar.close(199, "shifts 70 new 3 ids 9")  # e.g. what metrics.json says
    lines = out.getvalue().splitlines()
    assert len(lines) == 12, lines  # 0 %, each tenth, then the final line
    assert lines[0] == "  run w, qlearning: 0/200 cycles shifts 0"
    assert lines[-2] == "  run w, qlearning: 200/200 cycles shifts 66"
    assert lines[-1] == "  run w, qlearning: 199/200 cycles shifts 70 new 3 ids 9"
    bar.update(5, "after close")
    bar.close()
    assert out.getvalue().splitlines() == lines


def test_plain_lines_come_at_least_every_30_s_while_steps_are_done():
    out, now = io.StringIO(), [0.0]
    bar = ProgressBar(2000, "run w, until complete", stream=out, clock=lambda: now[0])
    bar.update(0)
    for done in range(1, 150):
        now[0] += 0.5  # 150 cycles in 75 s: never a tenth of the budget
        bar.update(done)
    bar.close(149, "complete")
    lines = out.getvalue().splitlines()
    assert [ln.split(": ")[1].split("/")[0] for ln in lines] == ["0", "60", "120", "149"]
    assert lines[-1].endswith("149/2000 cycles complete")
    # No new step: no line, however long it took.
    out2 = io.StringIO()
    still = ProgressBar(2000, "stalled", stream=out2, clock=lambda: now[0])
    still.update(5)
    now[0] += 100.0
    still.update(5)
    assert len(out2.getvalue().splitlines()) == 1


def test_few_steps_print_every_step_once():
    out = io.StringIO()
    with ProgressBar(4, "compare", "runs", stream=out) as bar:
        for k in range(4):
            bar.update(k, f"running {k}")
            bar.update(k, f"running {k}")  # the same again: no second line
        bar.update(4, "last")
    lines = out.getvalue().splitlines()
    assert lines == [f"  compare: {k}/4 runs running {k}" for k in range(4)] + [
        "  compare: 4/4 runs last"]


def test_quiet_shows_nothing():
    out = FakeTerminal()
    with ProgressBar(10, "run", enabled=False, stream=out) as bar:
        bar.update(5, "x")
    assert out.getvalue() == "" and not bar.live


def test_nested_bars_on_a_terminal_share_one_display():
    out = FakeTerminal()
    outer = ProgressBar(2, "compare", "runs", stream=out)
    assert outer.live
    for k in range(2):
        outer.update(k, f"running {k}")
        # rich allows one live display at a time: a second one would raise LiveError.
        with ProgressBar(8, f"run {k}", stream=out) as inner:
            assert inner.live
            for c in range(9):
                inner.update(c, counters_info({"attention_shifts": c}))
            inner.close(8, "final of run")
        outer.update(k + 1, f"done {k}")
    outer.close()
    text = out.getvalue()
    # Each inner bar left its final line; the outer bar's last state stays drawn.
    assert "  run 0: 8/8 cycles final of run" in text
    assert "  run 1: 8/8 cycles final of run" in text
    assert "2/2" in text and "done 1" in text
    # The display is released: a new bar starts a new one.
    again = ProgressBar(1, "again", stream=out)
    assert again.live
    again.close(1)


def test_counters_info_reads_live_counters_and_metrics_alike():
    assert counters_info({"attention_shifts": 3, "new_objects": 2,
                          "positive_identifications": 1, "cycles": 9}) == \
        "shifts 3 new 2 ids 1"
    assert counters_info({}) == "shifts 0 new 0 ids 0"
