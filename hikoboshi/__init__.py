"""Hikoboshi's command line: the composition root that wires planner, spacecraft, telemetry
and server together (the only package allowed to import them all)."""
