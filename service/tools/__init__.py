"""Tools around the service, never loaded by ``oslim serve``: the closed-loop ``sim``, ``replay``,
``report`` (a picture of a recorded run), the Zenoh probe, the benchmarks and the progress bars
of the long ones. They may import ``sim_bridge``."""
