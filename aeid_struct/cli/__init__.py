"""The ``aeid-struct`` command line (``aeid-struct --help`` lists the subcommands).

``main`` is the entry point (``python -m aeid_struct.cli`` runs it too); importing this package
and building the parser import neither torch nor CasADi.
"""

from aeid_struct.cli.errors import EXIT_INPUT as EXIT_INPUT
from aeid_struct.cli.errors import EXIT_OUTSIDE as EXIT_OUTSIDE
from aeid_struct.cli.errors import UsageExit as UsageExit
from aeid_struct.cli.identify import generic_names as generic_names
from aeid_struct.cli.identify import shipped_names as shipped_names
from aeid_struct.cli.main import main as main
from aeid_struct.cli.parser import build_parser as build_parser
from aeid_struct.cli.records_io import RECORD_LAYOUTS as RECORD_LAYOUTS

__all__ = [
    "EXIT_INPUT",
    "EXIT_OUTSIDE",
    "RECORD_LAYOUTS",
    "UsageExit",
    "build_parser",
    "generic_names",
    "main",
    "shipped_names",
]
