"""Studies and benchmarks built on the library (the paper's robot-leg study, partial
knowledge, benchmarks). The library never imports this package.
"""

