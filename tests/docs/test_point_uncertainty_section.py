"""docs/uncertainty.md, section 5 "Per point", runs as written and prints
the figures it quotes."""

from __future__ import annotations

import contextlib
import io
import re

import numpy as np
from repo import REPO

DOC = REPO / "docs" / "uncertainty.md"


def test_section_5_example_runs_and_prints_what_it_says():
    text = DOC.read_text(encoding="utf-8")
    section = text[text.index("## 5. Per point"):]
    (block,) = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    out = io.StringIO()
    scope: dict = {}
    with contextlib.redirect_stdout(out):
        exec(compile(block, str(DOC), "exec"), scope)
    printed = out.getvalue()
    assert np.allclose(scope["pts"].u[0] * 1e3, [10.9, 12.1, 10.5], atol=0.05), printed
    assert np.allclose(scope["sphere"].centre.u * 1e3, [10.7, 11.6, 6.8], atol=0.05), printed
    assert np.all(np.sqrt(np.diag(scope["sphere"].centre.shrunk)) * 1e3 < 0.4)
    for name in ("map", "temperature", "scanner_scale", "scanner_noise", "pose"):
        assert name in printed
