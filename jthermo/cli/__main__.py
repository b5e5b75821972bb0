"""`python -m jthermo.cli`: the `jthermo` command."""

from . import main
from .common import exit_now

exit_now(main())
