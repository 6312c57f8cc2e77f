"""Fleets: identify a data set of records that does not fit one process, with Dask.

Layer: above ``loading`` (the identifiers it reads by name), below ``studies`` and the CLI
(``aeid-struct identify-many``). Dask and pyarrow are the optional ``fleet`` extra
(``pip install "aeid-struct[fleet]"``), imported when a fleet is identified.

Modules: ``sources`` (record files cut into chunks), ``work`` (one chunk identified and written
as one Parquet part; the table's schema), ``many`` (:func:`identify_many`: the chunks on a
Dask cluster, resumable).
"""

from aeid_struct.fleet.many import FleetRun as FleetRun
from aeid_struct.fleet.many import identify_many as identify_many
from aeid_struct.fleet.sources import FORMATS as FORMATS
from aeid_struct.fleet.sources import Chunk as Chunk
from aeid_struct.fleet.sources import chunks as chunks
from aeid_struct.fleet.work import SCHEMA as SCHEMA
from aeid_struct.fleet.work import identify_chunk as identify_chunk

__all__ = ["FORMATS", "SCHEMA", "Chunk", "FleetRun", "chunks", "identify_chunk",
           "identify_many"]
