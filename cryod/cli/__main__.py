"""``python -m cryod.cli``: the same as the ``cryod`` command."""

import sys

from cryod.cli import main

sys.exit(main())
