"""``python -m cmmpose.schemas [FOLDER]``: write the document schemas
(default ``docs/schemas`` of the working folder)."""

from __future__ import annotations

import logging
import sys

from . import write_schemas


def main(argv=None) -> int:
    """Write the schemas into the folder ``argv[0]`` (default ``docs/schemas``)."""
    argv = sys.argv[1:] if argv is None else argv
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    write_schemas(argv[0] if argv else "docs/schemas")
    return 0


if __name__ == "__main__":
    sys.exit(main())
