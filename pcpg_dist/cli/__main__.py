"""``python -m pcpg_dist.cli``: the same as ``pcpg``."""

import sys

from pcpg_dist.cli import main

sys.exit(main())
