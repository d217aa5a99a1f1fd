"""``python -m dpr.cli``: the `dpr` command."""

import sys

from dpr.cli.main import main

sys.exit(main())
