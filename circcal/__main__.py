"""``python -m circcal``: the ``circcal`` command (:func:`circcal.cli.main`), for an environment whose scripts folder
is not on the PATH."""

import sys

from circcal.cli import main

if __name__ == "__main__":
    sys.exit(main())
