"""Tools around the service, never loaded by ``oslim serve``: the closed-loop ``sim``, ``replay``,
the Zenoh probe and the benchmarks. They may import ``sim_bridge``."""
