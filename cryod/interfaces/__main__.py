"""``python -m cryod.interfaces [--after SEQ]``: the interfaces process, its settings on standard input."""

import sys

from cryod.interfaces.process import main

sys.exit(main(sys.argv[1:]))
