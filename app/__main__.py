"""`python -m app ...` is `rvis ...` (the tests run the command line this way)."""

import sys

from app.commands.cli import main

if __name__ == "__main__":  # not when multiprocessing imports it as __mp_main__
    sys.exit(main())
