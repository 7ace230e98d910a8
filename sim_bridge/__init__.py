"""Everything that stands in for the world: flow fields, a filament plume, a detector, a vehicle.

``scenarios`` names the papers' worlds, ``world`` steps them in simulated time, and ``stub``
puts the result behind MAVLink as an ArduPilot-like vehicle (``oslim stub``).
"""
