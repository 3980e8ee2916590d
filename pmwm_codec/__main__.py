"""``python -m pmwm_codec``: the ``pmw`` command (see :mod:`pmwm_codec.cli`)."""

import sys

from .cli import main

sys.exit(main())
