"""`python -m vnl` runs the CLI."""

import sys

from vnl.cli import main

sys.exit(main())
