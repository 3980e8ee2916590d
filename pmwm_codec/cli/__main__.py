"""``python -m pmwm_codec.cli``: the ``pmw`` command."""

import sys

from . import main

sys.exit(main())
