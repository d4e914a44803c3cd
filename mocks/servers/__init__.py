"""One deterministic server per device protocol, named after the driver it answers (loopback only)."""
