"""Cells a campaign runs on: the real cell from a hardware file, the digital twin's cell."""
