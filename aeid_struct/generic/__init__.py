"""Generic identifiers: one trained network per order that reads a window of any SISO system's
record in normalised time (``dt = 1``) and gives its poles; the rest of the model comes from least
squares (docs/architecture.md, "Any system, any record").

Layer: above ``identification`` (files, estimates), below ``training``. Modules: ``poles`` (raw
outputs -> stable factors -> denominator), ``model`` (``GenericConfig``, ``GenericIdentifier``),
``files`` (the ``.aeid`` format ``aeid-struct/generic/1``, the shipped names).
"""

from aeid_struct.generic.files import FORMAT as FORMAT
from aeid_struct.generic.files import GENERIC as GENERIC
from aeid_struct.generic.files import load_generic as load_generic
from aeid_struct.generic.files import read_generic as read_generic
from aeid_struct.generic.files import save_generic as save_generic
from aeid_struct.generic.model import ORDERS as ORDERS
from aeid_struct.generic.model import GenericConfig as GenericConfig
from aeid_struct.generic.model import GenericIdentifier as GenericIdentifier
from aeid_struct.generic.model import normalise_windows as normalise_windows
from aeid_struct.generic.model import spectra as spectra
from aeid_struct.generic.poles import denominator as denominator
from aeid_struct.generic.poles import factors as factors
from aeid_struct.generic.poles import poles_of as poles_of
from aeid_struct.generic.poles import raw_of as raw_of

__all__ = [
    "FORMAT",
    "GENERIC",
    "ORDERS",
    "GenericConfig",
    "GenericIdentifier",
    "denominator",
    "factors",
    "load_generic",
    "normalise_windows",
    "poles_of",
    "raw_of",
    "read_generic",
    "save_generic",
    "spectra",
]
