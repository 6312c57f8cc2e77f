"""Physical models and their derivations, in CasADi only (no torch): each module is a short,
sectioned script in the style of the CasADi examples that builds named ``casadi.Function`` objects
and checks itself when run as ``python -m symbolic.<module>``.

``symbolic.slip`` derives the robot leg of paper Sec. IV, a spring-loaded inverted pendulum, from
its Lagrangian to the linearisation of Eq. 16 and its two SISO subsystems; ``symbolic.leg`` maps
its physical parameters ``k, d, m`` to the controllable canonical forms of those subsystems and
back (and re-exports the model); ``symbolic.realisation`` is the CCF of any SISO realisation
(paper Eq. 5), the library's one model -> CCF conversion; ``symbolic.codegen`` writes and compiles
C code; ``symbolic.named`` lets a model file name a map instead of holding its code.

``symbolic.mechanism`` is the same pipeline for any machine: a ``Mechanism`` built from a
Lagrangian derives its equations of motion, equilibrium, linearisation (``A, B, C, D`` of the
parameters by name), per-channel canonical maps and C code; ``symbolic.identifiability`` says
which parameters the chosen channels determine; ``symbolic.mechanisms`` holds worked ones (the
leg, a two-mass system, a lever, a drive train, a cart-pole). The ``aeid_struct`` library imports
these maps where a physical structure needs them.
"""

from symbolic.identifiability import IdentifiabilityReport as IdentifiabilityReport
from symbolic.identifiability import identifiability as identifiability
from symbolic.mechanism import Mechanism as Mechanism

__all__ = ["IdentifiabilityReport", "Mechanism", "identifiability"]
