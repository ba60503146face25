"""`python -m app ...` is `rvis ...` (the tests run the command line this way)."""

import sys

from app.commands.cli import main

sys.exit(main())
