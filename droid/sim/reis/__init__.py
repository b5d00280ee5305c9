"""The Reis arm's twin: register map, plant, world device, lockstep cell (thesis §2.3, §4.1)."""
