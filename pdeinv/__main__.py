"""``python -m pdeinv …``: the command line, so ``torchrun --nproc_per_node=P -m pdeinv train …`` works."""

import sys

try:
    from .cli import main
except KeyboardInterrupt:  # Ctrl-C while the command line is imported: quietly, as later
    sys.exit(130)

sys.exit(main())
