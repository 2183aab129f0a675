"""`python -m vnl.cli ...`, the same as `vnl ...`."""

import sys

from vnl.cli import main

sys.exit(main())
