"""The numerical core: grid, mapping (with the transport operator A(t)), planning, mission, tick
aggregation and configuration. numpy, scipy and pydantic only: no sockets, no clocks, no asyncio
(``lint-imports`` holds this), so the same code runs on the vehicle, in benchmarks and in replay."""
