"""The ``aeid-struct`` command line.
"""

from aeid_struct.cli.main import EXIT_INPUT as EXIT_INPUT
from aeid_struct.cli.main import EXIT_OUTSIDE as EXIT_OUTSIDE
from aeid_struct.cli.main import RECORD_LAYOUTS as RECORD_LAYOUTS
from aeid_struct.cli.main import UsageExit as UsageExit
from aeid_struct.cli.main import build_parser as build_parser
from aeid_struct.cli.main import main as main
from aeid_struct.cli.main import shipped_names as shipped_names

__all__ = [
    "EXIT_INPUT",
    "EXIT_OUTSIDE",
    "RECORD_LAYOUTS",
    "UsageExit",
    "build_parser",
    "main",
    "shipped_names",
]
