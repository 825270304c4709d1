"""Algorithm registrations for the command line and the run driver: one module per algorithm family.

Each module calls :func:`train.config.register` with its :class:`train.config.AlgoSpec` s; every module in this
package is imported by :mod:`train.config`, so adding an algorithm means adding one file here. Modules must not
import JAX at import time: their keys come from the JAX-free config dataclasses of :mod:`jaxsmarl.algos`
(``*_config.py``), and ``make_agent`` imports the learner when a run builds it.
"""
