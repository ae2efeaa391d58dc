"""``python -m litege_core.cli``: the ``litege`` command."""

import sys

from litege_core.cli import main

sys.exit(main())
