"""`python -m studyctl.cli`: the same as the `studyctl` command."""

import sys

from studyctl.cli import main

if __name__ == "__main__":  # pragma: no cover (multiprocessing's spawn imports this module as __mp_main__)
    sys.exit(main())
