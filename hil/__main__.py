"""``python -m hil``: the ``hil`` command."""

import sys

from hil.cli import main

sys.exit(main())
