"""The detector's compiled loops: `jit` (``njit``: the ahead-of-time build, numba's JIT, or plain Python),
`jitcache` (numba's disk cache kept safe across modules) and `build` (the ahead-of-time build tool run
by `make setup`; nothing at run time imports it)."""
