"""droid.brain.runtime.program's shell helpers: close_all (every resource closed, first error raised after) and
ErrorLine (a device error said once per change)."""
import pytest

from droid.brain.runtime.program import ErrorLine, close_all


class Res:
    def __init__(self, log, name, fail=False):
        self.log, self.name, self.fail = log, name, fail

    def close(self):
        self.log.append(self.name)
        if self.fail:
            raise OSError(f"{self.name} failed")


def test_close_all_closes_in_order_skips_none_and_calls_callables():
    log = []
    close_all(Res(log, "a"), None, lambda: log.append("term"), Res(log, "b"))
    assert log == ["a", "term", "b"]


def test_close_all_closes_the_rest_then_raises_the_first_error():
    log = []
    with pytest.raises(OSError, match="a failed"):
        close_all(Res(log, "a", fail=True), Res(log, "b", fail=True), Res(log, "c"))
    assert log == ["a", "b", "c"]


def test_error_line_says_each_new_error_once(capsys):
    e = ErrorLine("droid-x", "serial /dev/ttyS0: ")
    for err in ["", "gone", "gone", "", "", "gone", "busy"]:
        e.update(err)
    assert capsys.readouterr().err.splitlines() == ["droid-x: serial /dev/ttyS0: gone"] * 2 + [
        "droid-x: serial /dev/ttyS0: busy"]
