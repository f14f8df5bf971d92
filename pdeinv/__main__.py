"""``python -m pdeinv …``: the command line, so ``torchrun --nproc_per_node=P -m pdeinv train …`` works."""

import sys

from .cli import main

sys.exit(main())
