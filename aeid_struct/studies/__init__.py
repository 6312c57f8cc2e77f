"""Studies and benchmarks built on the library: the paper's robot-leg study, partial knowledge,
the wear scenario of online identification, their figures, and the benchmarks. The library never
imports this package.

Each study is a namespace of its own (``studies.leg_paper``, ``studies.knowledge``,
``studies.wear``, ``studies.figures``, ``studies.bench``, ``studies.bench_online``,
``studies.generic_bench`` (with ``studies.channels_bench``), ``studies.mechanism_bench``,
``studies.onepass_bench`` with its ``studies.onepass_tables``):
their names overlap (each study has its ``evaluate``), so they are not merged into one.
"""

from aeid_struct.studies import bench as bench
from aeid_struct.studies import bench_online as bench_online
from aeid_struct.studies import channels_bench as channels_bench
from aeid_struct.studies import figures as figures
from aeid_struct.studies import generic_bench as generic_bench
from aeid_struct.studies import knowledge as knowledge
from aeid_struct.studies import leg_paper as leg_paper
from aeid_struct.studies import mechanism_bench as mechanism_bench
from aeid_struct.studies import onepass_bench as onepass_bench
from aeid_struct.studies import onepass_tables as onepass_tables
from aeid_struct.studies import wear as wear
