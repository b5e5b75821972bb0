"""`python -m jthermo.cli`: the `jthermo` command."""

import sys

from . import main

sys.exit(main())
