"""Shipped configuration: robots, tools, cells, hardware and KR C2 files (package data)."""
