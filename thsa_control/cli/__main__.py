"""``python -m thsa_control.cli``: the ``thsa`` command."""

import sys

from . import main

sys.exit(main())
