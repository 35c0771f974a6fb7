"""hil.protocols: role interfaces (actuator, force sensor) and device adapters over real transports."""
