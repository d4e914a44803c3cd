"""The campaign report: HTML page and the diagnosis plots."""
