"""The README's Python example runs as written."""

import re

import pytest
from repo import REPO

README = REPO / "README.md"


@pytest.mark.skipif(not README.is_file(), reason="README is not shipped with an installed package")
def test_readme_python_example_runs():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "README has a python example"
    namespace: dict = {}  # blocks build on each other, as a reader runs them
    for code in blocks:
        exec(compile(code, str(README), "exec"), namespace)
