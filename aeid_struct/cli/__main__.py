"""``python -m aeid_struct.cli``: the same as the ``aeid-struct`` command."""

import sys

from aeid_struct.cli import main

if __name__ == "__main__":      # importing the module (a package walk) runs nothing
    sys.exit(main())
