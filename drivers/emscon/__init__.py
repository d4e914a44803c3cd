"""Leica emScon TPI (binary C variant): codec (pure) and client (interfaces.Tracker)."""
