"""``python -m sm_bt.cli``: the ``sm-bt`` console script."""

import sys

from sm_bt.cli import main

sys.exit(main())
