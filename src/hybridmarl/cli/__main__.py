"""``python -m hybridmarl.cli``: the ``hybridmarl`` command."""

import sys

from hybridmarl.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
