"""``python -m polyhull``: the command line (guarded: process pools re-import this module)."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
