"""`Compiled`: a jitted function compiled ahead of time once per argument signature.

Benchmarks and solvers call one function on many problems padded to a few shapes: compiling each
signature once, explicitly, keeps compilation out of the measured solve times and reports it apart.
"""

from __future__ import annotations

import time

import jax


class Compiled:
    def __init__(self, fn):
        self.fn, self.cache = fn, {}

    def get(self, *args):
        """(executable, seconds spent compiling now: 0 when this signature was seen). Arguments may be
        arrays or shape structs; the executable's `out_info` gives its output shapes."""
        leaves, tree = jax.tree.flatten(args)
        key = (tree, tuple((tuple(a.shape), str(a.dtype)) for a in leaves))
        if key in self.cache:
            return self.cache[key], 0.0
        t0 = time.perf_counter()
        self.cache[key] = self.fn.lower(*args).compile()
        return self.cache[key], time.perf_counter() - t0


def run(executable, *args):
    """Call an executable from `Compiled.get` with its arguments placed as it was compiled for. An
    executable compiled ahead of time refuses arrays sharded otherwise (e.g. one function's output,
    split over the devices, passed to another compiled apart); placing them is a no-op when they
    already match."""
    return executable(*jax.device_put(args, executable.input_shardings[0]))
