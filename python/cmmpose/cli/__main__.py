"""``python -m cmmpose.cli``."""

from . import main

main()
