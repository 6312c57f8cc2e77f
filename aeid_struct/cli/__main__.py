"""``python -m aeid_struct.cli``: the same as the ``aeid-struct`` command."""

import sys

from aeid_struct.cli import main

sys.exit(main())
