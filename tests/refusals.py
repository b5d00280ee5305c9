"""The check the tests of bad input files share: a file is refused with one BadInput line."""
from __future__ import annotations

from pathlib import Path

import pytest

from droid.cli import BadInput


def refused(path: Path, text: str, load) -> str:
    """``text`` written to ``path``, then ``load(path)``: it must raise BadInput of one line,
    which is returned (the caller checks what it names)."""
    path.write_text(text)
    with pytest.raises(BadInput) as exc:
        load(path)
    msg = str(exc.value)
    assert "\n" not in msg, msg
    return msg
