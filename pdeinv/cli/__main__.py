"""``python -m pdeinv.cli``, the same as ``python -m pdeinv`` and ``pdeinv``."""

import sys

from . import main

sys.exit(main())
