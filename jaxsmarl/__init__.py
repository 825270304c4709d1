"""Safe multi-agent reinforcement learning in JAX: the algorithms (:mod:`jaxsmarl.algos`) and their parts.

The Stackelberg solvers are exported lazily, so that importing a JAX-free module of the package (such as
:mod:`jaxsmarl.options`) does not start JAX.
"""

__all__ = ["stackelberg_equilibrium", "stackelberg_values"]


def __getattr__(name):
    if name in __all__:
        from jaxsmarl import stackelberg

        return getattr(stackelberg, name)
    raise AttributeError(f"module 'jaxsmarl' has no attribute {name!r}")
