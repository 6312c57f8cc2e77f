"""Physical models and their derivations, in CasADi only (no torch): each module is a short,
sectioned script in the style of the CasADi examples that builds named ``casadi.Function`` objects
(model, derivation, linearisation, maps to and from canonical forms, generated C) and checks itself
when run as ``python -m symbolic.<module>``. ``symbolic.leg`` derives the robot leg of paper
Sec. IV, a spring-loaded inverted pendulum, from its Lagrangian to the controllable canonical forms
of its stable and unstable subsystems and back to the physical parameters ``k, d, m``; the
``aeid_struct`` library imports these maps where a physical structure needs them.
"""
