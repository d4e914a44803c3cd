"""Deterministic mocks: the digital twin and one server per device protocol (loopback only)."""
